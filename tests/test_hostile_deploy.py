"""Hostile deployments (marker ``security``): an operator's wrong command line or file, and the
transport a single service is started with. Loopback only: an endpoint off loopback is only ever
refused before anything opens, never opened."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support import cli_in_process

from fedtrack.services.base import service_kwargs, service_parser

pytestmark = pytest.mark.security
OFF_LOOPBACK = "tcp/192.0.2.1:7447"  # TEST-NET-1: never a target; the check refuses it before any session


@pytest.mark.parametrize("mode, flag", [("router", "--listen"), ("client", "--connect"), ("client", "--listen")])
def test_serve_refuses_a_plain_endpoint_off_loopback_unless_insecure(mode: str, flag: str) -> None:
    """``launch`` refuses a plain endpoint off loopback unless ``[zenoh]`` opts out, but ``serve`` took
    one as given: ``fedtrack serve router --listen tcp/0.0.0.0:7447`` opened an unauthenticated bus to
    the network with no word. ``serve`` now refuses it (exit 2, naming the option and the endpoint)
    unless ``--insecure`` says so, or the endpoint is ``tls/`` with ``--zenoh-config``."""
    parser = service_parser("recorder", "test")
    with pytest.raises(SystemExit) as stop:
        service_kwargs(parser, parser.parse_args([flag, OFF_LOOPBACK]), mode)
    assert stop.value.code == 2
    kwargs = service_kwargs(parser, parser.parse_args([flag, OFF_LOOPBACK, "--insecure"]), mode)
    assert OFF_LOOPBACK in (*kwargs["options"].connect, *kwargs["options"].listen)
    for loopback in ("tcp/127.0.0.1:7447", "tcp/localhost:7447", "tcp/[::1]:7447"):
        service_kwargs(parser, parser.parse_args([flag, loopback]), mode)


def test_serve_router_off_loopback_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """The command line itself: exit 2 and one error line naming the option, before any session
    (the router's listen address is not this machine's: nothing is bound or sent)."""
    run = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "router", "--listen", OFF_LOOPBACK],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path, check=False)
    errors = [line for line in run.stderr.splitlines() if "error" in line]
    assert run.returncode == 2 and len(errors) == 1, run.stderr
    assert f"--listen: {OFF_LOOPBACK} is off loopback" in errors[0] and "--insecure" in errors[0]
    assert "Traceback" not in run.stderr


def test_serve_router_off_loopback_needs_access_control_in_its_config(tmp_path: Path) -> None:
    """``serve router --listen tls/... --zenoh-config F`` off loopback took F when it made TLS mutual,
    whatever else it said: without F's access control every certificate of the CA (a sensor's) could
    publish on every key, the fused tracks included. A router's file must now also enable access
    control with default deny (``launch`` writes it so), else exit 2 naming the option; ``--insecure``
    opts out as for a plain endpoint."""
    import json

    from fedtrack.deploy.security import ZenohSettings, write_configs
    from fedtrack.keys import Keys

    paths = write_configs(ZenohSettings(tls_dir="c"), tmp_path, Keys("x"), ["router", "sensor-1"], tmp_path / "o")
    config = json.loads(paths["router"].read_text())
    open_acl = tmp_path / "no-acl.json5"
    open_acl.write_text(json.dumps({k: v for k, v in config.items() if k != "access_control"}))
    allow_all = tmp_path / "allow.json5"
    allow_all.write_text(json.dumps({**config, "access_control": {**config["access_control"],
                                                                  "default_permission": "allow"}}))
    parser = service_parser("router", "test")
    endpoint = "tls/192.0.2.1:7447"
    for bad in (open_acl, allow_all):
        with pytest.raises(SystemExit) as stop:
            service_kwargs(parser, parser.parse_args(["--listen", endpoint, "--zenoh-config", str(bad)]), "router")
        assert stop.value.code == 2
        service_kwargs(parser, parser.parse_args(["--listen", endpoint, "--zenoh-config", str(bad), "--insecure"]),
                       "router")
    kwargs = service_kwargs(parser, parser.parse_args(["--listen", endpoint, "--zenoh-config", str(paths["router"])]),
                            "router")
    assert kwargs["options"].listen == (endpoint,)
    service_kwargs(parser, parser.parse_args(["--listen", "tls/127.0.0.1:7447", "--zenoh-config", str(open_acl)]),
                   "router")  # loopback: nothing off the machine reaches it
    client = service_parser("recorder", "test")  # a client connects to a router that enforces it
    service_kwargs(client, client.parse_args(["--connect", endpoint, "--zenoh-config", str(paths["sensor-1"])]),
                   "client")


def broken_certificates(tls_dir: Path, how: str) -> Path:
    """A certificate directory for identities ``router`` and ``sensor-1`` with sensor-1's made ``how``
    wrong; returns the file at fault."""
    from fedtrack.deploy.certificates import make_certificates

    make_certificates(tls_dir, ["router", "sensor-1", "launcher"])
    cert = tls_dir / "sensor-1.pem"
    if how == "expired":  # valid until 3 minutes ago
        cert.unlink()
        make_certificates(tls_dir, ["sensor-1"], days=-0.002)
    elif how == "other_ca":  # the CA was made again: sensor-1's is signed by the old one
        for name in ("ca.pem", "ca.key", "router.pem", "router.key", "launcher.pem", "launcher.key"):
            (tls_dir / name).unlink()
        make_certificates(tls_dir, ["router", "launcher"])
    elif how == "no_key":
        (tls_dir / "sensor-1.key").unlink()
    elif how == "other_key":  # the key of another identity
        (tls_dir / "sensor-1.key").write_bytes((tls_dir / "router.key").read_bytes())
    elif how == "garbage":
        cert.write_text("not a certificate\n")
    return tls_dir / "sensor-1.key" if how in ("no_key", "other_key") else cert


@pytest.mark.parametrize("how, says", [("expired", "expired on"), ("other_ca", "not signed by"),
                                       ("no_key", "missing"), ("other_key", "does not match"),
                                       ("garbage", "not a PEM certificate")])
def test_a_broken_certificate_is_named_before_anything_starts(tmp_path: Path, how: str, says: str) -> None:
    """An expired certificate, one of another CA, a missing or foreign key: ``launch`` started the
    router and the services, each failed its TLS handshake, and ten seconds later the launcher
    stopped everything with exit 1 and Zenoh's ``Timeout!`` (no word of the certificate). The
    certificates are now checked before anything starts: one line naming the file (exit 2)."""
    from fedtrack.config import ConfigError
    from fedtrack.deploy.security import ZenohSettings, write_configs
    from fedtrack.keys import Keys

    at_fault = broken_certificates(tmp_path / "certs", how)
    with pytest.raises(ConfigError, match=says) as error:
        write_configs(ZenohSettings(tls_dir="certs"), tmp_path, Keys("x"), ["router", "sensor-1"], tmp_path / "out")
    assert str(at_fault) in str(error.value) and "zenoh.tls_dir" in str(error.value)


def test_launch_with_an_expired_certificate_is_one_line_and_starts_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Launched in this process (support.cli_in_process: starting a process fails the test)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    broken_certificates(tmp_path / "certs", "expired")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[zenoh]\ntls_dir = "certs"\n[deployment]\nrouter_listen = "tls/127.0.0.1:{port}"\n'
                   'duration_s = 3.0\n[[sensor]]\nid = "1"\n')
    done = cli_in_process(["launch", str(cfg), "--out", str(tmp_path / "o")], capsys, monkeypatch)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert f"{cfg}: zenoh.tls_dir: {tmp_path / 'certs' / 'sensor-1.pem'}: expired on" in done.stderr
    assert not list((tmp_path / "o").glob("logs/*"))  # no service was started


SQUARE = "[[0, 0], [100, 0], [100, 100], [0, 100]]"


@pytest.mark.parametrize("polygons, says", [
    ([("bow", "[[0, 0], [100, 100], [100, 0], [0, 100]]")], "regions.polygon.bow.points: edges 1 and 3 cross"),
    ([("flat", "[[0, 0], [50, 50], [100, 100]]")], "regions.polygon.flat.points: encloses no area"),
    ([("dot", "[[5, 5], [5, 5], [5, 5], [5, 5]]")], "regions.polygon.dot.points: encloses no area"),
    ([("a", SQUARE), ("b", "[[10, 10], [50, 10], [50, 50]]")], "regions.polygon.b.points: overlaps region a"),
    ([("a", SQUARE), ("b", "[[50, 50], [150, 50], [150, 150], [50, 150]]")], "regions.polygon.b.points: overlaps region a"),
    ([("a", SQUARE), ("b", SQUARE)], "regions.polygon.b.points: overlaps region a"),
    ([("far", "[[0, 0], [1e300, 0], [0, 1e300]]")], "regions.polygon.far.points: coordinates beyond"),
])
def test_regions_an_operator_got_wrong_are_named(tmp_path: Path, polygons: list[tuple[str, str]], says: str) -> None:
    """A self-intersecting polygon, one enclosing no area, two that overlap (a region inside another
    never owned a track: the first containing region takes it) or coordinates whose squares
    overflow: ``[regions]`` took them all, and the centres ran with regions that own nothing or
    distances of inf. Each is now one error naming the polygon's key (exit 2 at every command)."""
    from fedtrack.config import ConfigError
    from fedtrack.local_filters.regions import load_regions

    path = tmp_path / "regions.toml"
    path.write_text("[regions]\nmargin = 10.0\n" + "".join(
        f'[[regions.polygon]]\nid = "{rid}"\npoints = {points}\n' for rid, points in polygons))
    with pytest.raises(ConfigError) as error:
        load_regions(path)
    assert str(error.value).startswith(f"{path}: {says}")


def test_regions_sharing_borders_are_fine_and_a_grid_beyond_the_wire_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    from fedtrack.config import ConfigError
    from fedtrack.local_filters.regions import load_regions

    path = tmp_path / "regions.toml"
    path.write_text('[regions]\nmargin = 10.0\n[[regions.polygon]]\nid = "ell"\n'
                    'points = [[0, 0], [10, 0], [10, 2], [2, 2], [2, 10], [0, 10]]\n'
                    '[[regions.polygon]]\nid = "rest"\npoints = [[2, 2], [10, 2], [10, 10], [2, 10]]\n'
                    '[[regions.polygon]]\nid = "east"\npoints = [[10, 0], [20, 0], [20, 10], [10, 10]]\n')
    regions = load_regions(path)
    assert regions is not None and regions.ids == ("ell", "rest", "east")
    path.write_text("[regions]\nmargin = 10.0\ngrid = {origin = [-1e308, 0], cell = [1e308, 1], nx = 2, ny = 1}\n")
    with pytest.raises(ConfigError, match="regions.grid: the grid reaches beyond"):
        load_regions(path)
    run = cli_in_process(["replay", "--algorithm", "mtt-decentralized", "--regions", "config", "--config", str(path),
                          "--measurements", "/dev/null", "--out", str(tmp_path / "p.jsonl")], capsys, monkeypatch)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert not (tmp_path / "p.jsonl").exists()
