"""A new user's deployment paths, followed as README.md and docs/deploy.md write them (loopback only)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support import free_port
from test_docs_contract import _options, _parsers

from fedtrack import cli
from fedtrack.deploy.launcher import LaunchError, prepare_launcher
from fedtrack.deploy.settings import load_settings


def test_launch_of_a_host_whose_router_is_not_up_is_one_line(tmp_path: Path) -> None:
    """A sensor host of deploy/multihost/ launched while host A's router is down (or its address is
    wrong): after ready_timeout_s a Python traceback (SessionError from the launcher's monitor), exit 1.
    Now a LaunchError, which ``launch`` prints as one line (exit 1), naming the timeout and the endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "b.toml"
    cfg.write_text(f'[deployment]\nready_timeout_s = 0.5\nconnect = ["{endpoint}"]\n'
                   'services = ["sensor", "local-filter"]\n[[sensor]]\nid = "1"\n')
    (tmp_path / "o").mkdir()
    launcher = prepare_launcher(load_settings(cfg), cfg, tmp_path / "o", quiet=True)
    with pytest.raises(LaunchError) as error:
        launcher.run()
    message = str(error.value)
    assert message.startswith("no router reached within ready_timeout_s = 0.5 s: ") and "\n" not in message
    assert endpoint in message and ".rs:" not in message
    assert all(sp.proc is None for sp in launcher.plan)  # nothing was started


@pytest.mark.parametrize("role", cli.SERVICES)
def test_every_serve_option_says_its_default(role: str) -> None:
    """``serve sensor --scenario`` said '(overrides config)', ``--seed``, ``--speed``, ``serve local-filter
    --mode``, ``serve fusion-center --deadline`` and every role's ``--config`` / ``--zenoh-config`` gave no
    default (test_cli_roughedges checks only options whose argparse default is set; these take theirs
    from the config): each now names it, e.g. 'default: deployment.scenario of --config, else 1'."""
    for parser in _parsers(["serve", role]):
        formatter = parser._get_formatter()
        for action in _options(parser):
            if action.option_strings and not action.required and action.nargs != 0:
                assert "default" in formatter._expand_help(action), f"{parser.prog} {action.option_strings}"


@pytest.mark.parametrize("standby", [False, True])
def test_a_centre_of_another_host_ending_is_no_failover_without_standbys(tmp_path: Path, standby: bool) -> None:
    """deploy/multihost-regions/ run as its README says (C's centre stopped before A, on loopback with
    mutual TLS): host A's summary listed 'failover of x1y0: primary lost at t = 75.01 s, standby took
    over after - s' though no standby was configured. A primary token's end is a failover only with
    ``[multitarget] standby = true``."""
    from types import SimpleNamespace

    import zenoh

    from fedtrack.deploy.launcher import Launcher
    from fedtrack.deploy.plan import failover_scopes

    cfg = tmp_path / "a.toml"
    cfg.write_text(f'[deployment]\npacing = "realtime"\n[multitarget]\nstandby = {str(standby).lower()}\n')
    settings = load_settings(cfg)
    launcher = Launcher(settings, [], quiet=True, scopes=failover_scopes(settings, cfg))
    for kind in (zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE):
        launcher._on_primary_token(SimpleNamespace(key_expr=launcher.keys.primary("all", "abc"), kind=kind))
    assert [f.scope for f in launcher.watch.failovers] == (["all"] if standby else [])


def test_serve_router_on_a_port_in_use_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """``launch`` names a router port already taken (exit 2), ``serve router`` logged Zenoh's 'Address
    already in use' and exited 1."""
    import socket

    from fedtrack.services.router import main as router

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        endpoint = f"tcp/127.0.0.1:{held.getsockname()[1]}"
        with pytest.raises(SystemExit) as stop:
            router(["--listen", endpoint])
    assert stop.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (f"fedtrack serve router: error: --listen: port "
                                                        f"{endpoint.rsplit(':', 1)[1]} is already in use ({endpoint})")


def test_serve_router_on_an_address_of_another_host_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    """``serve router --listen`` on an address this host does not have (a multi-host file's router address on
    the wrong machine) says so; before (tour58) it said the port was already in use."""
    from fedtrack.services.router import main as router

    endpoint = "tcp/192.0.2.1:7447"  # TEST-NET-1: on no host
    with pytest.raises(SystemExit) as stop:
        router(["--listen", endpoint, "--insecure"])
    assert stop.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (f"fedtrack serve router: error: --listen: address 192.0.2.1 "
                                                        f"is not an address of this host ({endpoint})")


def test_serve_sensor_with_an_id_its_config_does_not_list_is_refused(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack serve sensor --config deploy/local.toml`` without ``--id`` (id ``sensor``) or with a
    mistyped one published a sensor with the default R under a key no local filter listens to."""
    from fedtrack.sensors.service import main as sensor

    cfg = tmp_path / "c.toml"
    cfg.write_text('[[sensor]]\nid = "1"\n[[sensor]]\nid = "2"\n')
    for argv in (["--config", str(cfg)], ["--config", str(cfg), "--id", "3"]):
        with pytest.raises(SystemExit) as stop:
            sensor(argv)
        assert stop.value.code == 2
        name = argv[-1] if "--id" in argv else "sensor"
        assert capsys.readouterr().err.splitlines()[-1] == (f"fedtrack serve sensor: error: --id {name}: not a "
                                                            f"[[sensor]] id of {cfg} (1, 2)")


def test_the_readme_deployment_table_lists_every_key() -> None:
    """The README's ``[deployment]`` table lacked ``router_connect`` and ``local_regions`` (docs/deploy.md
    had them, and lacked others): a reader of either missed keys the multi-host examples use."""
    import dataclasses
    import re

    from fedtrack.deployment import DeploymentConfig

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    table = readme.split("### `[deployment]`: a networked deployment", 1)[1].split("\n\n### ", 1)[0]
    listed = {k for row in re.findall(r"^\| (`[^|]+`) \|", table, re.M) for k in re.findall(r"`(\w+)`", row)}
    assert {f.name for f in dataclasses.fields(DeploymentConfig)} <= listed


def test_the_progress_line_rates_are_recent(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``launch deploy/join-leave.toml``'s progress line averaged each sensor's scans over the whole run: 's1:1/s'
    from the kill of s1 at 60 s to the end at 89 s, and 's3:0/s' all the while s3 (joined at 30 s, 1.3 s
    period) published. The rate is now over the last RATE_WINDOW_S."""
    from types import SimpleNamespace

    import numpy as np

    from fedtrack.deploy.launcher import Launcher
    from fedtrack.deploy.monitor import RATE_WINDOW_S
    from fedtrack.wire import Measurement, encode

    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\npacing = "realtime"\n[multitarget]\n')
    launcher = Launcher(load_settings(cfg), [], quiet=True)
    clock = [1000.0]
    monkeypatch.setattr("fedtrack.deploy.monitor.time.monotonic", lambda: clock[0])
    for k in range(90):  # s1 once a second until it dies at 60 s; s3 every other second from 30 s on
        clock[0] = 1000.0 + k
        for sid in ("s1",) * (k < 60) + ("s3",) * (k >= 30 and k % 2 == 0):
            payload = encode(Measurement(sensor=sid, seq=k, t=float(k), kind="position", z=np.zeros(2), R=np.eye(2)))
            launcher._on_meas(SimpleNamespace(key_expr=launcher.keys.sensor_meas(sid),
                                               payload=SimpleNamespace(to_bytes=lambda p=payload: p)))
    # quiet (no progress line): only the window's arrivals are held (before: every one of the run, 60 of s1)
    assert {s: len(q) for s, q in launcher._arrivals.items()} == {"s1": 6, "s3": 3}  # each one's last 5 s
    clock[0] = 1000.0 + 89.5
    assert RATE_WINDOW_S == 5.0 and launcher._status_line(1000.0) == "pictures 0  sensors s1:0.0/s s3:0.4/s"


def test_demo_names_its_router_so_a_subscriber_can_join(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack demo`` runs on a free port: the examples (docs/wire.md) need its endpoint, which nothing
    it printed gave. Its first line now names the router and the deployment."""
    from fedtrack.deploy import demo

    def no_run(*args: object, **kwargs: object) -> None:
        raise LaunchError("not run here")

    monkeypatch.setattr(demo, "run_deployment", no_run)
    assert demo.main(["--out", str(tmp_path / "d"), "--port", "17999"]) == 1
    first = capsys.readouterr().err.splitlines()[0]
    assert ", router tls/127.0.0.1:17999 (deployment demo); output in " in first, first


@pytest.mark.parametrize("existed", [False, True])
def test_a_launch_refused_at_start_leaves_no_output_behind(tmp_path: Path, existed: bool) -> None:
    """A multi-target launch whose certificates cannot be made (``tls_dir`` under a folder that does
    not exist) is refused in one line, exit 2; before 2026-11-27 its output folder was left with the
    simulated scenario and config.toml in it. An output folder that was there before stays."""
    from fedtrack.config import ConfigError
    from fedtrack.deploy.launcher import main

    out = tmp_path / "out"
    if existed:
        out.mkdir()
    cfg = tmp_path / "mt.toml"
    cfg.write_text(f'[zenoh]\ntls_dir = "{tmp_path}/missing/certs"\n[deployment]\n'
                   f'router_listen = "tls/127.0.0.1:{free_port()}"\nout = "{out}"\n'
                   "[multitarget]\ntargets = 2\nduration = 3.0\n")
    with pytest.raises(ConfigError, match="zenoh.tls_dir"):
        main([str(cfg)])
    assert out.is_dir() == existed  # made by the run: removed; there before: kept
    assert not (tmp_path / "missing").exists()
