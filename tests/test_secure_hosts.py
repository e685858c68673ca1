"""Mutual TLS across hosts as docs/deploy.md says to set it up (marker ``security``): one CA on one
host, each host given ``ca.pem`` and its own identities' certificates, a router per host joined by
``router_connect``; and the certificate command's inputs. Loopback only; routers in process."""

from __future__ import annotations

import json
import shutil
import threading
from pathlib import Path

import pytest
from support import free_port

from fedtrack.config import ConfigError
from fedtrack.deploy.certificates import make_certificates
from fedtrack.deploy.security import ZenohSettings, main, write_configs
from fedtrack.deploy.settings import check_launchable, load_settings
from fedtrack.keys import Keys
from fedtrack.zsession import SessionOptions, close_session, open_session

pytestmark = pytest.mark.security


def host_dir(ca_dir: Path, dest: Path, identities: list[str]) -> Path:
    """What the docs tell an operator to copy to a host: ``ca.pem`` and its identities' files."""
    dest.mkdir()
    for name in ["ca.pem", *(f"{i}.{ext}" for i in identities for ext in ("pem", "key"))]:
        shutil.copy(ca_dir / name, dest / name)
    return dest


def test_a_host_given_only_its_certificates_launches_and_a_missing_one_is_named(tmp_path: Path) -> None:
    """Before: every launch read ``ca.key`` and made or checked every identity of the deployment, so a
    sensor host given only its own certificates failed ('[Errno 2] ... ca.key') and one given the
    CA's key made the other hosts' certificates."""
    make_certificates(tmp_path / "ca", ["router", "fusion", "recorder", "launcher", "sensor-1", "sensor-2"])
    b = host_dir(tmp_path / "ca", tmp_path / "b", ["launcher", "sensor-1"])
    paths = write_configs(ZenohSettings(tls_dir="b"), tmp_path, Keys("x"), ["sensor-1"], tmp_path / "out",
                          ["fusion", "recorder", "router", "sensor-1", "sensor-2"])
    assert sorted(paths) == ["launcher", "sensor-1"] and sorted(p.name for p in b.iterdir()) == [
        "ca.pem", "launcher.key", "launcher.pem", "sensor-1.key", "sensor-1.pem"]
    with pytest.raises(ConfigError) as error:
        write_configs(ZenohSettings(tls_dir="b"), tmp_path, Keys("x"), ["sensor-2"], tmp_path / "out")
    assert str(error.value).startswith(f"zenoh.tls_dir: {b / 'sensor-2.pem'}: missing, and {b / 'ca.key'} is not "
                                       "there to sign it")


def test_a_host_without_a_router_is_not_asked_for_a_tls_router_listen(tmp_path: Path) -> None:
    """deploy/multihost/host-b.toml with ``tls_dir`` and ``tls/`` endpoints, as its comment says: refused
    ('endpoint tcp/127.0.0.1:7447 is not tls/...: set deployment.router_listen') for the default
    ``router_listen`` of a router this host does not run."""
    cfg = tmp_path / "b.toml"
    cfg.write_text('[zenoh]\ntls_dir = "certs"\n[deployment]\nconnect = ["tls/127.0.0.1:7447"]\n'
                   'services = ["sensor", "local-filter"]\n[[sensor]]\nid = "1"\n')
    check_launchable(load_settings(cfg), cfg)
    cfg.write_text(cfg.read_text().replace('connect = ["tls/', 'connect = ["tcp/'))
    with pytest.raises(ConfigError, match="deployment.connect to tls/"):
        check_launchable(load_settings(cfg), cfg)


def test_routers_of_two_hosts_join_under_mutual_tls(tmp_path: Path) -> None:
    """Host B's router joins host A's (``router_connect``), each with the files ``launch`` writes. Before:
    B's router had no certificate to present when connecting (no link), and A's access control let
    the identity ``router`` publish only its own health: sensor 1's measurement never reached A."""
    make_certificates(tmp_path / "ca", ["router", "fusion", "launcher", "sensor-1"])
    everyone = ["fusion", "recorder", "router", "sensor-1"]
    hosts = {h: write_configs(ZenohSettings(tls_dir=f"{h}-certs"), tmp_path, Keys("x"), ids, tmp_path / h, everyone)
             for h, ids in (("a", ["router", "fusion"]), ("b", ["router", "sensor-1"]))
             if host_dir(tmp_path / "ca", tmp_path / f"{h}-certs", [*ids, "launcher"])}
    port_a, port_b = free_port(), free_port()
    a_ep, b_ep = f"tls/127.0.0.1:{port_a}", f"tls/127.0.0.1:{port_b}"
    sessions = []
    try:
        for opts in (SessionOptions(mode="router", connect=(), listen=(a_ep,), config_file=str(hosts["a"]["router"])),
                     SessionOptions(mode="router", connect=(a_ep,), listen=(b_ep,), connect_timeout_s=5.0,
                                    config_file=str(hosts["b"]["router"])),
                     SessionOptions(connect=(a_ep,), connect_timeout_s=5.0, config_file=str(hosts["a"]["fusion"])),
                     SessionOptions(connect=(b_ep,), connect_timeout_s=5.0, config_file=str(hosts["b"]["sensor-1"]))):
            sessions.append(open_session(opts))
        got = threading.Event()
        key = Keys("x").sensor_meas("1")
        sub = sessions[2].declare_subscriber(key, lambda sample: got.set())
        for _ in range(40):  # until the subscription has crossed both routers
            sessions[3].put(key, b"scan")
            if got.wait(0.1):
                break
        sub.undeclare()
    finally:
        for session in reversed(sessions):
            close_session(session)
    assert got.is_set()


@pytest.mark.parametrize("args, says", [
    (["--days", "0"], "--days: must be at least 1 day, got 0"),  # made a certificate expired at once
    (["--days", "-1"], "--days: must be at least 1 day, got -1"),  # a ValueError traceback
    (["--san", "host-a"], "--san: 'host-a' is neither IP:ADDRESS nor DNS:NAME"),  # named FEDTRACK_CERT_SAN
    (["sensor1"], "unknown identity 'sensor1'"),  # made a certificate no deployment uses
])
def test_the_certificate_command_refuses_bad_input_and_writes_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str) -> None:
    """Before, the CA was made first and the run then failed (a folder with a CA and no certificate)."""
    assert main([str(tmp_path / "c"), "router", *args]) == 2
    assert capsys.readouterr().err == f"fedtrack.deploy.security: {says}" + (
        " (router, fusion, recorder, launcher, sensor-<id> or region-<rid>)\n" if "identity" in says else "\n")
    assert not (tmp_path / "c").exists()


def test_a_validity_past_the_last_date_x509_can_write_is_refused(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--days 100000000`` (273,000 years) was an OverflowError traceback after the CA was made (tour60): now exit
    2 naming the most days a certificate made today can have (to 9999-12-31), nothing written."""
    assert main([str(tmp_path / "c"), "router", "--days", "100000000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fedtrack.deploy.security: --days: must be at most ") and err.endswith(
        " days (a certificate ends by 9999-12-31, the last date X.509 can write), got 100000000\n"), err
    assert not (tmp_path / "c").exists()


def test_the_certificate_command_creates_no_folder_above_its_own(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Before: ``... security /no/such/dir/certs router`` made /no, /no/such and /no/such/dir (and a
    ``[zenoh] tls_dir`` with a typo in its path did the same at ``launch``)."""
    assert main([str(tmp_path / "no" / "certs"), "router"]) == 2
    assert "the folder" in capsys.readouterr().err and not (tmp_path / "no").exists()
    with pytest.raises(ConfigError, match="does not create folders"):
        write_configs(ZenohSettings(tls_dir="no/certs"), tmp_path, Keys("x"), ["router"], tmp_path / "out")
    assert not (tmp_path / "no").exists()


def test_wait_ready_reaches_a_mutual_tls_router(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The multi-host steps run ``wait_ready`` on a sensor host before its launch; it had no way to present
    a certificate, so against a ``tls_dir`` deployment it could only time out. ``--tls-dir`` uses the
    host's ``launcher`` certificate."""
    from fedtrack.deploy.wait_ready import main as wait_ready

    make_certificates(tmp_path / "ca", ["router", "fusion", "launcher"])
    paths = write_configs(ZenohSettings(tls_dir="ca"), tmp_path, Keys("x"), ["router", "fusion"], tmp_path / "a")
    host_dir(tmp_path / "ca", tmp_path / "b", ["launcher"])
    endpoint = f"tls/127.0.0.1:{free_port()}"
    router = open_session(SessionOptions(mode="router", connect=(), listen=(endpoint,),
                                         config_file=str(paths["router"])))
    centre = None
    try:
        centre = open_session(SessionOptions(connect=(endpoint,), config_file=str(paths["fusion"])))
        token = centre.liveliness().declare_token(Keys("x").alive("fusion-center", "fusion"))
        base = ["--connect", endpoint, "--deployment", "x", "fusion-center/fusion"]
        assert wait_ready([*base, "--tls-dir", str(tmp_path / "b"), "--timeout", "10"]) == 0
        with pytest.raises(SystemExit) as stop:  # no certificate: no session (it waited out --timeout)
            wait_ready([*base, "--timeout", "1"])
        assert stop.value.code == 2
        token.undeclare()
    finally:
        if centre is not None:
            close_session(centre)
        close_session(router)
    err = capsys.readouterr().err
    assert "wait_ready: up: fusion-center/fusion" in err and ".rs:" not in err


def test_serve_off_loopback_needs_a_zenoh_config_that_makes_tls_mutual(tmp_path: Path) -> None:
    """``serve router --listen tls/... --zenoh-config F`` was taken as authenticated whatever F said: with
    F a server-only TLS file (certificate, no ``enable_mtls``) a client holding no certificate connected
    through the same router on loopback and published a fused track its subscribers received. Now
    refused off loopback unless F makes the links mutual (exit 2 naming the option and the file)."""
    from fedtrack.services.base import service_kwargs, service_parser

    make_certificates(tmp_path / "c", ["router"])
    paths = write_configs(ZenohSettings(tls_dir="c"), tmp_path, Keys("x"), ["router"], tmp_path / "o")
    server_only = tmp_path / "server-only.json5"
    server_only.write_text(json.dumps({"transport": {"link": {"tls": {
        "root_ca_certificate": str(tmp_path / "c" / "ca.pem"), "listen_certificate": str(tmp_path / "c" / "router.pem"),
        "listen_private_key": str(tmp_path / "c" / "router.key")}}}}))
    parser = service_parser("router", "test")
    off = "tls/192.0.2.1:7447"  # TEST-NET-1: refused or accepted before any session, never opened
    with pytest.raises(SystemExit) as stop:
        service_kwargs(parser, parser.parse_args(["--listen", off, "--zenoh-config", str(server_only)]), "router")
    assert stop.value.code == 2
    kwargs = service_kwargs(parser, parser.parse_args(["--listen", off, "--zenoh-config", str(paths["router"])]),
                            "router")
    assert kwargs["options"].listen == (off,)
    service_kwargs(parser, parser.parse_args(["--listen", off, "--zenoh-config", str(server_only), "--insecure"]),
                   "router")


def test_a_broken_zenoh_config_file_is_named_before_anything_starts(tmp_path: Path) -> None:
    """``[zenoh] config`` naming a file that is not JSON5: the launch started the router, which exited
    with it, and ended in exit 1 ('router exited with code 2 before listening'); now a ConfigError
    naming ``zenoh.config`` and the file (exit 2) before any process."""
    (tmp_path / "bad.json5").write_text("{ this is : not json")
    with pytest.raises(ConfigError) as error:
        write_configs(ZenohSettings(config="bad.json5"), tmp_path, Keys("x"), ["router"], tmp_path / "out")
    assert str(error.value).startswith(f"zenoh.config: zenoh config {tmp_path / 'bad.json5'}: ")


def test_a_tls_endpoint_without_certificates_is_named_at_start() -> None:
    """``serve recorder --connect tls/127.0.0.1:P`` without ``--zenoh-config`` (loopback, so not refused as
    unauthenticated) waited out its connect timeout and logged Zenoh's 'Timeout!'; it has no certificate
    to present, so it is now a usage error naming the option."""
    from fedtrack.services.base import service_kwargs, service_parser

    parser = service_parser("recorder", "test")
    with pytest.raises(SystemExit) as stop:
        service_kwargs(parser, parser.parse_args(["--connect", "tls/127.0.0.1:7448"]))
    assert stop.value.code == 2


def test_a_router_address_its_certificate_does_not_name_is_refused_at_start(tmp_path: Path) -> None:
    """``router_listen = "tls/127.0.0.2:P"`` (a host's address: ``10.47.0.1`` in deploy/multihost/) with
    certificates made without ``--san IP:127.0.0.2``: every client refused the router's certificate and the
    launch waited out ready_timeout_s ('no router reached', 10.9 s at 8 s; the router was up). Now one
    line naming the certificate, the field and the ``--san`` to make it with; with it, the launch ran
    101 of 101 scans."""
    from fedtrack.deploy.launcher import prepare_launcher

    make_certificates(tmp_path / "certs", ["router"])
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[zenoh]\ntls_dir = "certs"\n[deployment]\nrouter_listen = "tls/127.0.0.2:{free_port()}"\n'
                   '[[sensor]]\nid = "1"\n')
    (tmp_path / "o").mkdir()
    with pytest.raises(ConfigError) as error:
        prepare_launcher(load_settings(cfg), cfg, tmp_path / "o", quiet=True)
    assert f"zenoh.tls_dir: {tmp_path / 'certs' / 'router.pem'}: its names (127.0.0.1, localhost) do not include " \
           "127.0.0.2 of deployment.router_listen" in str(error.value) and "--san IP:127.0.0.2" in str(error.value)
    for name in ("router.pem", "router.key"):
        (tmp_path / "certs" / name).unlink()
    make_certificates(tmp_path / "certs", ["router"], extra_san="IP:127.0.0.2")
    prepare_launcher(load_settings(cfg), cfg, tmp_path / "o", quiet=True)
