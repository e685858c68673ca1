"""Authenticated transport (deploy/secure): mutual TLS and the router's access control.

Certificates are made in tmp_path (fedtrack.deploy.security, the cryptography package); loopback only.
"""

from __future__ import annotations

import json
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import zenoh
from support import Deployment, cli_in_process, secure_router, wait_until

from fedtrack.config import ConfigError
from fedtrack.deploy.access_control import access_control, identity
from fedtrack.deploy.certificates import make_certificates
from fedtrack.deploy.security import ZenohSettings, on_loopback
from fedtrack.deploy.settings import check_launchable, load_settings
from fedtrack.fusion_center.replay import replay_fusion
from fedtrack.keys import Keys
from fedtrack.local_filters.regions import load_regions
from fedtrack.recording import Recording
from fedtrack.wire import FusedTrack, LocalEstimate, Measurement, Reset, decode, encode
from fedtrack.zsession import SessionError, SessionOptions, close_session, open_session

pytestmark = pytest.mark.security
MARK = 4242.4242  # the first coordinate of every forged message's state or measurement
MARK_BYTES = np.array([MARK]).tobytes()  # arrays travel as little-endian float64 bytes


def client_config(path: Path, ca: Path, cert: Path | None) -> str:
    tls = {"root_ca_certificate": str(ca), "enable_mtls": True}
    if cert is not None:
        tls.update(connect_certificate=str(cert), connect_private_key=str(cert.with_suffix(".key")))
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return str(path)


def test_identities_and_rules() -> None:
    assert [identity(r, i) for r, i in (("sensor", "3"), ("local-filter", "3"), ("mtt-local", "3"),
                                         ("fusion-center", "fusion"), ("mtt-centre", "centre"), ("recorder", "recorder"))
            ] == ["sensor-3", "sensor-3", "sensor-3", "fusion", "fusion", "recorder"]
    acl = access_control(Keys("d"), ["fusion", "sensor-1"])
    own = {r["id"]: r["key_exprs"] for r in acl["rules"]}
    assert "fedtrack/d/sensor/1/meas" in own["own-sensor-1"] and "fedtrack/d/local/1/estimate" in own["own-sensor-1"]
    assert not any("fusion" in k or "sensor/2" in k for k in own["own-sensor-1"])
    assert "fedtrack/d/local/1/tracks" in own["own-sensor-1"] and "fedtrack/d/health/mtt-local/1" in own["own-sensor-1"]
    assert "fedtrack/d/fusion/**" in own["own-fusion"] and acl["default_permission"] == "deny"
    assert "fedtrack/d/alive/mtt-centre/centre" in own["own-fusion"]
    # serve picture (``fusion``) reads the region pictures with history: their caches
    assert own["query-fusion"] == ["fedtrack/d/**", "fedtrack/d/local/*/estimate/@adv/**",
                                   "fedtrack/d/region/*/picture/@adv/**"]
    assert "fedtrack/d/fusion/reset/1" in own["read-sensor-1"] and "fedtrack/d/fusion/state" in own["query-sensor-1"]
    assert not any("sensor/2" in k or "reset/2" in k or k.endswith("**") for k in own["read-sensor-1"][:7])
    assert identity("mtt-centre", "x0y0-standby", "x0y0") == "region-x0y0"


def test_a_region_identity_hands_over_on_its_own_key_only() -> None:
    """Every ``region-<rid>`` might put on every ``region/*/handover``, so any region could send hand-overs
    naming another as their ``source`` (tests/test_hostile_regions.py). The generated access control now lets
    ``region-<rid>`` (its standbys too) put hand-overs to any region on ``region/*/handover/<rid>`` only, and
    read those to it and its own (a standby watches its primary's)."""
    keys = Keys("d")
    acl = access_control(keys, ["region-x0y0", "region-x1y0"])
    rules = {r["id"]: [zenoh.KeyExpr(k) for k in r["key_exprs"]] for r in acl["rules"]}

    def allows(rule: str, key: str) -> bool:
        return any(k.intersects(zenoh.KeyExpr(key)) for k in rules[rule])
    assert allows("own-region-x0y0", keys.region_handover("x1y0", "x0y0"))
    assert not allows("own-region-x0y0", keys.region_handover("x0y0", "x1y0"))
    assert not allows("own-region-x0y0", keys.region_handover("x1y0", "x1y0"))
    assert not allows("own-region-x1y0", keys.region_handover("x0y0", "x0y0"))
    assert allows("read-region-x0y0", keys.region_handover("x0y0", "x1y0"))
    assert allows("read-region-x0y0", keys.region_handover("x1y0", "x0y0"))
    assert identity("mtt-centre", "x0y0-standby", "x0y0") == "region-x0y0"


def refused_beside_north(tmp_path: Path, rid: str, says: str) -> None:
    """A ``[regions]`` of two polygons, ``north`` and ``rid``, is refused, the error saying ``says``."""
    config = tmp_path / "regions.toml"
    polygon = '[[regions.polygon]]\nid = "{}"\npoints = [[{x}, 0.0], [{w}, 0.0], [{w}, 10.0]]\n'
    config.write_text("[regions]\nmargin = 1.0\n" + polygon.format("north", x=0.0, w=10.0)
                      + polygon.format(rid, x=20.0, w=30.0))
    with pytest.raises(ConfigError, match=says):
        load_regions(config)


def test_a_region_identity_speaks_for_its_own_centres_only_whatever_the_ids(tmp_path: Path) -> None:
    """``region-<rid>`` might publish the Health and declare the token of every ``mtt-centre/<rid>-...`` (its
    standbys): with polygon regions ``north`` and ``north-east``, ``region-north`` could forge the Health of
    region north-east's centre (its counters in the summary, a final ``stopped`` that makes a SIGKILL at
    the stop no failure) and its ``alive`` token (the launcher's readiness wait). It now may the ids of its
    own centre and its standby (``<rid>-standby``) only, and a ``[regions]`` whose ids would make one
    region's standby another region is refused."""
    keys = Keys("d")
    acl = access_control(keys, ["region-north", "region-north-east"])
    own = {r["id"]: [zenoh.KeyExpr(k) for k in r["key_exprs"]] for r in acl["rules"]}

    def allows(ident: str, key: str) -> bool:
        return any(k.intersects(zenoh.KeyExpr(key)) for k in own[f"own-{ident}"])
    for centre in ("north", "north-standby"):
        assert allows("region-north", keys.health("mtt-centre", centre))
        assert allows("region-north", keys.alive("mtt-centre", centre))
    for centre in ("north-east", "north-east-standby"):
        assert not allows("region-north", keys.health("mtt-centre", centre))
        assert not allows("region-north", keys.alive("mtt-centre", centre))
        assert allows("region-north-east", keys.health("mtt-centre", centre))
    refused_beside_north(tmp_path, "north-standby", "'north-standby' is the id of the standby of region 'north'")


def collector() -> tuple[list[str], threading.Event, threading.Event, Callable[[Any], None]]:
    """The keys of the samples received (a ``probe`` payload sets ``probed`` instead, an ``end`` one sets ``done``
    too), the two events, and the subscriber's callback."""
    seen: list[str] = []
    done, probed = threading.Event(), threading.Event()

    def on_sample(sample: Any) -> None:
        body = sample.payload.to_bytes()
        if body == b"probe":
            probed.set()
            return
        seen.append(str(sample.key_expr))
        if body == b"end":
            done.set()
    return seen, done, probed, on_sample


def test_the_fusion_identity_speaks_for_its_own_services_only(tmp_path: Path) -> None:
    """``fusion`` (the fusion center, the whole area's centre, ``serve picture``) might publish every
    ``health/{fusion-center,mtt-centre,picture}/*`` and declare every such ``alive`` token: a compromised merger's
    certificate forged region x0y0's centre's Health (its counters in the launcher's summary, a final ``stopped``
    that makes a SIGKILL at its stop no failure) and its token (the launcher's readiness wait). Over a loopback
    router with the generated access control and real certificates, the launcher's monitor now gets ``fusion``'s
    own services' Health and tokens only (the ids the launcher gives them), and a ``[regions]`` id that is the whole
    area's centre's is refused."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "region-x0y0", "launcher"]) as client:
        watcher, forger = client("launcher"), client("fusion")
        seen, done, probed, on_sample = collector()
        sub = watcher.declare_subscriber(keys.health(), on_sample)
        tokens: list[str] = []
        liveliness = watcher.liveliness().declare_subscriber("fedtrack/x/alive/**",
                                                             lambda s: tokens.append(str(s.key_expr)), history=True)
        assert wait_until(lambda: forger.put(keys.health("picture", "picture"), b"probe") or probed.is_set(), 30.0)
        allowed = [keys.health("fusion-center", "fusion"), keys.health("mtt-centre", "centre"),
                   keys.health("mtt-centre", "centre-standby")]
        denied = [keys.health("mtt-centre", "x0y0"), keys.health("mtt-centre", "x0y0-standby"),
                  keys.health("picture", "x0y0"), keys.health("fusion-center", "x0y0")]
        for key in denied + allowed:
            forger.put(key, b"x")
        forged_tokens = [forger.liveliness().declare_token(key) for key in (  # the last: after the others
            keys.alive("mtt-centre", "x0y0"), keys.alive("mtt-centre", "x0y0-standby"), keys.alive("picture", "x0y0"),
            keys.alive("mtt-centre", "centre"), keys.alive("picture", "picture"))]
        forger.put(keys.health("picture", "picture"), b"end")  # after the others on the same link
        assert done.wait(30.0), seen
        assert wait_until(lambda: keys.alive("picture", "picture") in tokens, 30.0), tokens
        assert sorted(seen[:-1]) == sorted(allowed)
        assert tokens == [keys.alive("mtt-centre", "centre"), keys.alive("picture", "picture")]
        for t in forged_tokens:
            t.undeclare()
        sub.undeclare()
        liveliness.undeclare()
    refused_beside_north(tmp_path, "centre", "'centre' is the id of the whole area's centre")


def test_a_region_centres_identity_publishes_its_own_regions_outputs_only(tmp_path: Path) -> None:
    """Every region centre ran as ``fusion``, which might publish every region's picture, answers and
    primary token: a compromised centre of one region could speak for all. Each region's centres
    (primary and standbys) are now ``region-<rid>``: the router drops what one sends on another
    region's keys (and on hand-over keys other than its own, ``region/*/handover/<rid>``: it hands
    tracks to any neighbour, as itself)."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "region-x0y0", "region-x1y0"]) as client:
        watcher, west = client("fusion"), client("region-x0y0")
        seen, done, probed, on_sample = collector()
        sub = watcher.declare_subscriber("fedtrack/x/**", on_sample)
        tokens: list[str] = []
        liveliness = watcher.liveliness().declare_subscriber("fedtrack/x/alive/**",
                                                             lambda s: tokens.append(str(s.key_expr)), history=True)
        # until the router routes west's puts to the watcher
        assert wait_until(lambda: west.put(keys.region_picture("x0y0"), b"probe") or probed.is_set(), 30.0)
        allowed = [keys.region_picture("x0y0"), keys.region_resets("x0y0", "s1"),
                   keys.region_handover("x1y0", "x0y0"), keys.health("mtt-centre", "x0y0"),
                   keys.health("mtt-centre", "x0y0-standby")]
        denied = [keys.region_picture("x1y0"), keys.region_resets("x1y0", "s1"), keys.health("mtt-centre", "x1y0"),
                  keys.fusion_track(), keys.mtt_picture(), keys.region_handover("x0y0", "x1y0")]
        for key in denied + allowed:
            west.put(key, b"x")
        west_tokens = [west.liveliness().declare_token(key) for key in (  # the last: after the others
            keys.primary("x0y0", "1"), keys.primary("x1y0", "1"), keys.primary("all", "1"),
            keys.region_centre("x0y0", "z"), keys.region_centre("x1y0", "z"), keys.primary("x0y0", "2"))]
        west.put(keys.region_picture("x0y0"), b"end")  # after the others on the same link
        assert done.wait(30.0), seen
        assert wait_until(lambda: keys.primary("x0y0", "2") in tokens, 30.0), tokens
        assert sorted(seen[:-1]) == sorted(allowed)
        assert tokens == [keys.primary("x0y0", "1"), keys.region_centre("x0y0", "z"), keys.primary("x0y0", "2")]
        for t in west_tokens:
            t.undeclare()
        sub.undeclare()
        liveliness.undeclare()


def test_only_the_identities_that_recover_a_key_may_query_its_cache(tmp_path: Path) -> None:
    """Every identity could query every advanced publisher's cache (``.../@adv/**``): sensor 1's
    certificate, asking ``fedtrack/<dep>/**/@adv/**`` again and again, had every publisher send its
    whole cache each time (up to 64 MiB a key; against one publisher of 64 samples of 1 MB the honest
    stream on its session went from p50 0.3 to 38.7 ms). Now the recorder queries every cache, the
    fusion centre the estimates', a sensor's local filter its measurements' and resets' (what they
    subscribe to with history or recovery), and nobody else any."""
    import zenoh.ext

    keys = Keys("x")
    everyone = ["fusion", "recorder", "sensor-1", "sensor-2"]
    with secure_router(tmp_path, keys, everyone) as client:
        fusion, recorder, s1, s2, filter1 = map(client, [*everyone, "sensor-1"])  # filter1: sensor 1's local filter
        publishers = [zenoh.ext.declare_advanced_publisher(session, key, cache=zenoh.ext.CacheConfig(max_samples=4),
                                                           sample_miss_detection=zenoh.ext.MissDetectionConfig())
                      for session, key in ((fusion, keys.mtt_picture()), (fusion, keys.fusion_reset("1")),
                                           (s2, keys.local_estimate("2")), (s1, keys.sensor_meas("1")))]
        for pub in publishers:
            pub.put(b"cached")

        def cached(session: Any, key: str) -> set[str]:
            replies = session.get(f"{key}/@adv/**", timeout=1.0, accept_replies=zenoh.ReplyKeyExpr.ANY,
                                  consolidation=zenoh.ConsolidationMode.NONE)
            return {str(r.ok.key_expr) for r in replies if r.ok is not None}

        every = {keys.mtt_picture(), keys.fusion_reset("1"), keys.local_estimate("2"), keys.sensor_meas("1")}
        assert wait_until(lambda: cached(recorder, "fedtrack/x/**") == every, 30.0)
        assert cached(filter1, "fedtrack/x/**") == set()  # the flood: every cache at once
        assert cached(filter1, keys.mtt_picture()) == cached(filter1, keys.local_estimate("2")) == set()
        assert cached(filter1, keys.fusion_reset("1")) == {keys.fusion_reset("1")}  # its recovery
        assert cached(filter1, keys.sensor_meas("1")) == {keys.sensor_meas("1")}
        assert cached(fusion, keys.local_estimate()) == {keys.local_estimate("2")}  # the centre's recovery
        assert cached(s2, keys.fusion_reset("1")) == cached(s2, keys.sensor_meas("1")) == set()


def test_certificates_made_once_with_private_keys(tmp_path: Path) -> None:
    from cryptography import x509

    made = make_certificates(tmp_path / "c", ["router", "sensor-1"], extra_san="IP:10.47.0.1,DNS:host-a")
    assert [p.name for p in made] == ["ca.pem", "router.pem", "sensor-1.pem"]
    assert make_certificates(tmp_path / "c", ["router", "sensor-1", "fusion"]) == [tmp_path / "c" / "fusion.pem"]
    for name in ("ca.key", "router.key", "sensor-1.key", "fusion.key"):
        assert stat.S_IMODE((tmp_path / "c" / name).stat().st_mode) == 0o600
    cert = x509.load_pem_x509_certificate((tmp_path / "c" / "router.pem").read_bytes())
    ca = x509.load_pem_x509_certificate((tmp_path / "c" / "ca.pem").read_bytes())
    cert.verify_directly_issued_by(ca)
    assert cert.subject.rfc4514_string() == "CN=router"
    sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {str(v) for v in sans.get_values_for_type(x509.IPAddress)} == {"127.0.0.1", "10.47.0.1"}
    assert set(sans.get_values_for_type(x509.DNSName)) == {"localhost", "host-a"}
    for bad in (["a/b"], [""]):
        with pytest.raises(ConfigError):
            make_certificates(tmp_path / "c", bad)
    with pytest.raises(ConfigError):
        make_certificates(tmp_path / "c", ["x"], extra_san="URI:nope")
    done = subprocess.run([sys.executable, "-m", "fedtrack.deploy.security", str(tmp_path / "c"), "recorder"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0 and done.stdout.strip() == f"made {tmp_path / 'c' / 'recorder.pem'}"


def test_each_identity_reads_only_what_its_roles_read(tmp_path: Path) -> None:
    """Every identity could subscribe to every key and query every queryable: one whose session stopped
    reading its link held up each publisher of the deployment (docs/deploy.md, "Slow readers"). Now sensor
    2's identity reads its own resets, the fused tracks (lockstep pacing) and ``fusion/state``, not sensor
    1's measurements or resets (a subscription to everything is refused whole); the launcher's monitor the
    tracks and measurements, not the estimates; ``fusion`` (the centres) every key."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "sensor-1", "sensor-2", "launcher"]) as client:
        centre, s1, s2, monitor = map(client, ["fusion", "sensor-1", "sensor-2", "launcher"])
        got: dict[tuple[str, str], set[str]] = {}

        def watch(name: str, session: Any, key: str) -> None:
            got[(name, key)] = set()
            session.declare_subscriber(key, lambda s: got[(name, key)].add(str(s.key_expr)))

        every = f"fedtrack/{keys.deployment}/**"  # on a session of its own: a session hands a sample that
        watch("sensor-2", client("sensor-2"), every)  # one of its subscriptions was sent to all that match it
        watch("launcher", client("launcher"), every)
        for key in (keys.fusion_reset("2"), keys.fusion_track(), keys.fusion_reset("1"), keys.sensor_meas("1")):
            watch("sensor-2", s2, key)
        for key in (keys.sensor_meas(), keys.fusion_track(), keys.local_estimate()):
            watch("launcher", monitor, key)
        watch("fusion", centre, every)
        centre.declare_queryable(keys.fusion_state(), lambda q: q.reply(keys.fusion_state(), b"state"))
        published = [(s1, keys.sensor_meas("1")), (s1, keys.local_estimate("1")), (centre, keys.fusion_track()),
                     (centre, keys.fusion_reset("1")), (centre, keys.fusion_reset("2"))]
        allowed = [("sensor-2", keys.fusion_reset("2")), ("sensor-2", keys.fusion_track()),
                   ("launcher", keys.sensor_meas()), ("launcher", keys.fusion_track())]

        def delivered() -> bool:
            for session, key in published:
                session.put(key, b"x")
            return len(got[("fusion", every)]) == len(published) and all(got[a] for a in allowed)
        assert wait_until(delivered, 30.0), got
        for _ in range(3):
            delivered()
        time.sleep(0.3)
        assert got.pop(("fusion", every)) == {k for _, k in published}
        assert got == {("sensor-2", every): set(), ("sensor-2", keys.fusion_reset("2")): {keys.fusion_reset("2")},
                       ("sensor-2", keys.fusion_track()): {keys.fusion_track()}, ("sensor-2", keys.fusion_reset("1")):
                       set(), ("sensor-2", keys.sensor_meas("1")): set(), ("launcher", every): set(),
                       ("launcher", keys.sensor_meas()): {keys.sensor_meas("1")},
                       ("launcher", keys.fusion_track()): {keys.fusion_track()},
                       ("launcher", keys.local_estimate()): set()}
        assert [r.ok.payload.to_bytes() for r in s2.get(keys.fusion_state(), timeout=2.0) if r.ok] == [b"state"]
        assert [r for r in monitor.get(keys.fusion_state(), timeout=1.0) if r.ok] == []


@pytest.mark.parametrize("table, field", [
    ('router_listen = "tcp/10.47.0.1:7447"', "deployment.router_listen"),
    ('router_listen = "tcp/0.0.0.0:7447"', "deployment.router_listen"),
    ('router_listen = ""\nconnect = ["tcp/127.0.0.1:7447", "tcp/host-a:7447"]', "deployment.connect"),
])
def test_launch_refuses_plain_endpoints_off_loopback(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch, table: str, field: str) -> None:
    """Authenticated by default: off loopback, plain TCP needs ``[zenoh] insecure = true`` (exit 2,
    one line naming the file and the field, before anything starts); with it the check passes.
    Launched in this process (support.cli_in_process: starting a process fails the test)."""
    cfg = tmp_path / "c.toml"
    body = f'[deployment]\n{table}\n[[sensor]]\nid = "1"\n'
    cfg.write_text(body)
    done = cli_in_process(["launch", str(cfg), "--out", str(tmp_path / "o")], capsys, monkeypatch)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert done.stderr.startswith(f"fedtrack: error: {cfg}: {field}: ") and "off loopback" in done.stderr and "insecure" in done.stderr
    assert not (tmp_path / "o").exists()
    cfg.write_text("[zenoh]\ninsecure = true\n" + body)
    check_launchable(load_settings(cfg), cfg)


def test_loopback_needs_no_opt_out(tmp_path: Path) -> None:
    assert all(on_loopback(ep) for ep in ("tcp/127.0.0.1:1", "tcp/127.3.0.1:1", "tcp/[::1]:1", "tls/localhost:1"))
    assert not any(on_loopback(ep) for ep in ("tcp/10.0.0.1:1", "tcp/0.0.0.0:1", "tcp/[::]:1", "tcp/example:1"))
    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\nrouter_listen = "tcp/127.0.0.1:7447"\n[[sensor]]\nid = "1"\n')
    check_launchable(load_settings(cfg), cfg)
    with pytest.raises(ConfigError, match="insecure"):
        ZenohSettings(tls_dir="c", insecure=True).validate()


def test_launch_takes_a_zenoh_config_that_makes_tls_mutual_off_loopback(tmp_path: Path) -> None:
    """``[zenoh] config`` off loopback asked for ``insecure = true`` whatever the file said, though
    ``serve`` reads the file and takes one that makes TLS mutual: a deployment authenticated by its own
    Zenoh file had to be declared insecure, and its services were then given ``--insecure``. Now the
    launch reads the file as ``serve`` does: mutual TLS with ``tls/`` endpoints passes; a server-only
    file or a plain endpoint is refused naming the field. Where the launch's router listens off loopback,
    ``serve router`` also asks the file for access control with default deny: a file without it was
    taken by the launch, whose router then exited 2 at its start; now the launch refuses it first."""
    tls = {"root_ca_certificate": "ca.pem", "enable_mtls": True, "connect_certificate": "c.pem",
           "connect_private_key": "c.key"}
    deny = {"enabled": True, "default_permission": "deny"}
    (tmp_path / "mutual.json5").write_text(json.dumps({"transport": {"link": {"tls": tls}}, "access_control": deny}))
    (tmp_path / "open.json5").write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    (tmp_path / "server-only.json5").write_text(json.dumps({"transport": {"link": {"tls": {
        "listen_certificate": "r.pem", "listen_private_key": "r.key"}}}}))
    cfg = tmp_path / "c.toml"

    def launchable(config: str, endpoint: str, services: str = "") -> None:
        cfg.write_text(f'[zenoh]\nconfig = "{config}"\n[deployment]\nrouter_listen = "{endpoint}"\n{services}'
                       '[[sensor]]\nid = "1"\n')
        check_launchable(load_settings(cfg), cfg)

    launchable("mutual.json5", "tls/10.47.0.1:7447")
    launchable("open.json5", "tls/10.47.0.1:7447", 'services = ["sensor", "local-filter"]\n')  # no router here
    for config, endpoint in (("server-only.json5", "tls/10.47.0.1:7447"), ("mutual.json5", "tcp/10.47.0.1:7447")):
        with pytest.raises(ConfigError, match=r"deployment.router_listen: .* off loopback and not tls/ with a "
                                              r"\[zenoh\] config that makes TLS mutual"):
            launchable(config, endpoint)
    with pytest.raises(ConfigError, match=r"deployment.router_listen: .* has no access control with default deny"):
        launchable("open.json5", "tls/10.47.0.1:7447")
    with pytest.raises(ConfigError, match=r"zenoh.config: .*missing.json5 does not exist"):
        launchable("missing.json5", "tls/10.47.0.1:7447")


def test_launch_refuses_tcp_endpoints_with_tls_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[zenoh]\ntls_dir = "certs"\n[deployment]\nrouter_listen = "tcp/127.0.0.1:1"\n'
                   '[[sensor]]\nid = "1"\n')
    monkeypatch.chdir(tmp_path)  # launch's default --out
    done = cli_in_process(["launch", str(cfg)], capsys, monkeypatch)
    assert done.returncode == 2 and "zenoh.tls_dir: endpoint tcp/127.0.0.1:1 is not tls/" in done.stderr
    assert str(cfg) in done.stderr and "Traceback" not in done.stderr
    with pytest.raises(ConfigError):
        from fedtrack.deploy.security import ZenohSettings
        ZenohSettings(config="a.json5", tls_dir="b").validate()


def test_mutual_tls_and_access_control(tmp_path: Path) -> None:
    """No certificate or a foreign CA: no session. Sensor 1's identity forging sensor 2's
    measurements and estimates, resets and tracks: denied at the router, so the centre, the
    recorder and every subscriber never see them, and the tracks equal the replay of the
    genuine measurements."""
    certs = tmp_path / "certs"
    dep = Deployment(tmp_path, tls_dir=certs)  # makes the certificates
    ca = certs / "ca.pem"
    rogue_dir = tmp_path / "rogue"
    make_certificates(rogue_dir, ["sensor-1"])
    forger = None
    try:
        dep.start(sensors=False)
        for name, cert, ca_file in (("none", None, ca), ("foreign", rogue_dir / "sensor-1.pem", rogue_dir / "ca.pem")):
            with pytest.raises(SessionError):
                open_session(SessionOptions(connect=(dep.endpoint,), connect_timeout_s=1.0,
                                            config_file=client_config(tmp_path / f"{name}.json5", ca_file, cert)))
        forger = open_session(SessionOptions(connect=(dep.endpoint,), connect_timeout_s=5.0,
                                             config_file=client_config(tmp_path / "s1.json5", ca,
                                                                       certs / "sensor-1.pem")))
        seen: list[str] = []
        spy = dep.session.declare_subscriber(f"fedtrack/{dep.keys.deployment}/**",
                                             lambda s: seen.append(str(s.key_expr)) if MARK_BYTES in
                                             s.payload.to_bytes() else None)
        forged = forgeries(dep.keys)
        stop = threading.Event()

        def flood() -> None:
            while not stop.is_set():
                for key, payload in forged:
                    forger.put(key, payload)
                stop.wait(0.005)
        thread = threading.Thread(target=flood, daemon=True)
        thread.start()
        dep.start_sensors()
        assert dep.wait_sensors_done(90.0)
        stop.set()
        thread.join(5)
        spy.undeclare()
        for name in ("recorder/recorder", "fusion-center/fusion", "local-filter/1", "local-filter/2"):
            assert dep.stop(name) == 0  # each sends its final Health
    finally:
        if forger is not None:
            close_session(forger)
        dep.close()
    assert seen == []
    centre = dep.health["fusion-center/fusion"]
    assert centre["received"] == 202 and centre["scans_fused"] == 101, centre
    for sid in ("1", "2"):
        assert dep.health[f"local-filter/{sid}"]["received"] == 101 + 101, dep.health  # meas + resets
    rec = Recording(tmp_path / "recording.db", readonly=True)
    assert rec.count(Measurement) == 202 and rec.count(LocalEstimate) == 202 and rec.count(FusedTrack) == 101
    assert all(m.z[0] != MARK for m in rec.messages(Measurement, "id"))
    rec.export(tmp_path / "m.jsonl")
    rec.close()
    replay_fusion("fvdie", tmp_path / "m.jsonl", dep.config, tmp_path / "replay.jsonl")
    replayed = [json.loads(line) for line in (tmp_path / "replay.jsonl").read_text().splitlines()]
    live = sorted((t for t, _ in dep.tracks), key=lambda t: t.seq)
    assert len(live) == len(replayed) == 101
    for tr, rp in zip(live, replayed):
        np.testing.assert_allclose(tr.x, rp["x"], rtol=1e-9, atol=1e-6)


def forgeries(keys: Keys) -> list[tuple[str, bytes]]:
    """Plausible messages sensor 1's identity has no right to publish (all carrying MARK)."""
    x, P = np.array([MARK, 10.0, 2000.0, 5.0]), np.eye(4) * 100.0
    out: list[tuple[str, bytes]] = []
    for seq in range(0, 101, 10):
        out.append((keys.sensor_meas("2"), encode(Measurement(sensor="2", seq=seq, t=float(seq), kind="position",
                                                             z=np.array([MARK, 5e4]), R=np.eye(2)))))
        out.append((keys.local_estimate("2"), encode(LocalEstimate(
            sensor="2", seq=seq, t=float(seq), model="cv", x=x, P=P, x_prior=x, P_prior=P, stamp_ns=1))))
        for sid in ("1", "2"):
            out.append((keys.fusion_reset(sid), encode(Reset(sensor=sid, seq=seq, t=float(seq), model="cv", x=x,
                                                             P=P, beta=0.5))))
        out.append((keys.fusion_track(), encode(FusedTrack(seq=seq, t=float(seq), model="cv", x=x, P=P,
                                                           maneuver=False, degraded=False, sensors=("1",),
                                                           stamp_ns=1))))
    return out


def test_forged_payloads_carry_the_mark() -> None:
    forged = forgeries(Keys("d"))
    assert len(forged) == 5 * 11 and all(MARK_BYTES in p for _, p in forged)
    assert decode(forged[0][1], Measurement).z[0] == MARK
