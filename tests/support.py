"""Helpers shared by the process tests (loopback only, bounded waits)."""

from __future__ import annotations

import contextlib
import io
import json
import math
import multiprocessing
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, NamedTuple

import pytest
import zenoh

from fedtrack.deploy.demo import free_port
from fedtrack.local_filters.mtt.scan import parse_scan, scan_to_measurement
from fedtrack.wire import Measurement

WAIT_S = 10.0

__all__ = ["WAIT_S", "CliOutcome", "Deployment", "SecureBus", "cli_in_process", "cli_in_subprocess", "feed",
           "free_port", "in_parallel", "numbered_measurements", "replay_evaluated", "secure_router", "wait_until"]


def patch_wire(monkeypatch: pytest.MonkeyPatch, name: str, value: Any) -> None:
    """Set ``name`` (a bound such as MAX_TRACKS, or a private function) to ``value`` in the package
    ``fedtrack.wire`` and in each of its modules that holds it, as every one of them reads its own
    binding; undone by ``monkeypatch`` after the test."""
    import fedtrack.wire
    from fedtrack.wire import batches, codec, fields, limits, multipart, records, replay_json

    modules = (fedtrack.wire, limits, fields, records, batches, codec, multipart, replay_json)
    held = [m for m in modules if hasattr(m, name)]
    assert held, f"fedtrack.wire has no {name!r}"
    for module in held:
        monkeypatch.setattr(module, name, value)


class CliOutcome(NamedTuple):
    """A ``fedtrack`` command's exit code and standard error."""

    returncode: int
    stderr: str


def cli_in_subprocess(args: list[str], timeout: float = 60.0) -> CliOutcome:
    """``python -m fedtrack.cli ARGS`` in a new interpreter, as a user runs it."""
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", *args], capture_output=True, text=True,
                          timeout=timeout, check=False)
    return CliOutcome(proc.returncode, proc.stderr)


def cli_in_process(args: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> CliOutcome:
    """``fedtrack ARGS`` as ``cli.main`` in this process, without an interpreter's start-up (1-2 s a
    command): a traceback is an exception that fails the test, and a command that would start a
    process (``subprocess.Popen``, as launch does) fails it too instead of starting one."""
    from fedtrack import cli

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"a process was started: {args[:1]}")

    with monkeypatch.context() as patched:
        patched.setattr(subprocess, "Popen", refuse)
        capsys.readouterr()
        try:
            code = cli.main(args)
        except SystemExit as exc:  # argparse's errors; a message the interpreter would print, exit 1
            if exc.code is not None and not isinstance(exc.code, int):
                print(exc.code, file=sys.stderr)
            code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    return CliOutcome(code, capsys.readouterr().err)


def numbered_measurements(path: Path, until: float = math.inf) -> list[Measurement]:
    """The multi-target scan lines of ``path`` up to time ``until``, in file (arrival) order, as the sensors'
    measurements: each sensor's scans numbered from 0 (``seq``) in that order."""
    seq: dict[str, int] = {}
    out = []
    for line in path.read_text().splitlines():
        scan = parse_scan(json.loads(line), str(path))
        if scan.t > until:
            continue
        seq[scan.sensor] = seq.get(scan.sensor, -1) + 1
        out.append(scan_to_measurement(scan, seq[scan.sensor], 1))
    return out


def route_reports(centre: Any, local: dict[str, Any], published: list[Any], keys: Any, done: int) -> int:
    """Deliver what the in-process services published from ``published[done]`` on as Zenoh would: each report to
    ``centre``, each answer (federated resets) to its sensor's tracker in ``local``, in publication order, until
    nothing new comes; returns the new ``done``. A message held (the centre's start, fedtrack/services/lead.py)
    is answered later, when what it waits for came."""
    from fedtrack.wire import TrackReport, TrackResets, encode

    while done < len(published):
        msg, done = published[done], done + 1
        if isinstance(msg, TrackReport):
            centre._dispatch(("sample", 0, keys.mtt_report(msg.sensor), encode(msg)))
        elif isinstance(msg, TrackResets):
            local[msg.sensor]._dispatch(("sample", 1, keys.mtt_resets(msg.sensor), encode(msg)))
    return done


def feed(session: Any, key: str, payload: bytes) -> None:
    """Put ``payload`` on ``key`` as the services publish, with BLOCK congestion control. A test's plain
    ``session.put`` takes Zenoh's default, DROP: a message that finds the link's queue full is dropped without a
    word, which Zenoh allows (a scan of s2 lost at a load of 18, and the test waited 30 s for its report)."""
    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)


def feed_one_by_one(session: Any, key: str, payload: bytes, tracker: Any | None, scans: int) -> None:
    """:func:`feed` a scan, then wait until ``tracker`` (a local tracker service, or None) has counted ``scans``
    of its scans (reports and late): its report is out before the next scan, so the reports of several trackers
    reach a centre in the scans' order, as at real time. Fed at once, one tracker's thread ran 4 s of data ahead
    of another's under load, and the centre held and dropped its report as stamped far ahead (lead.py)."""
    feed(session, key, payload)
    if tracker is not None:
        assert wait_until(lambda: tracker.counters.get("reports", 0) + tracker.counters.get("late", 0) >= scans,
                          timeout=30.0), dict(tracker.counters)


def wait_until(predicate: Callable[[], bool], timeout: float = WAIT_S) -> bool:
    """Poll ``predicate`` every 20 ms until it holds or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


WORKERS = 2  # the CI machine's cores
CALL_TIMEOUT_S = 300.0  # one call's bound (the longest, a fuzzing part, takes about 12 s)
_pool: ProcessPoolExecutor | None = None


def in_parallel(calls: list[tuple[Callable[..., Any], tuple[Any, ...]]]) -> list[Any]:
    """``[f(*args) for f, args in calls]``, computed by ``WORKERS`` processes: the suite runs its
    tests one at a time, so a test made of independent CPU-bound calls (replays, seeded runs) can
    use the CI machine's second core. The processes are spawned, not forked (this one may hold
    Zenoh's threads), once per session: they import what the calls need once. A process takes
    the next call when it is free, so give the longest first. A call still running after
    ``CALL_TIMEOUT_S`` fails the test, and the processes are killed (the next call starts new ones)."""
    global _pool
    if _pool is None:
        _pool = ProcessPoolExecutor(WORKERS, mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = [_pool.submit(f, *args) for f, args in calls]
        return [f.result(timeout=CALL_TIMEOUT_S) for f in futures]
    except (BrokenProcessPool, TimeoutError):
        for proc in list(_pool._processes.values()):  # the pool's own processes, nothing else
            proc.kill()
        _pool.shutdown(wait=False, cancel_futures=True)
        _pool = None
        raise


def replay_evaluated(algorithm: str, measurements: Path, config: Path, out: Path, truth: Path,
                     sensor: str | None = None) -> dict[str, Any]:
    """``evaluate`` of ``fedtrack replay --algorithm ALGORITHM`` (written to ``out``) against ``truth``."""
    from fedtrack.fusion_center.mtt.evaluation import evaluate
    from fedtrack.fusion_center.mtt.replay import replay_mtt

    with contextlib.redirect_stderr(io.StringIO()):
        replay_mtt(algorithm, measurements, config, out, sensor=sensor)
    return evaluate(out, truth)


class Deployment:
    """A deployment whose processes the test starts, kills and restarts itself (from ``service_plan``).

    ``tracks`` collects ``(FusedTrack, payload)`` as the test's own client sees them live.
    """

    def __init__(self, tmp_path: Path, n_sensors: int = 2, seed: int = 1, pacing: str = "lockstep",
                 speed: float = 1.0, deadline_s: float = 2.0, tls_dir: Path | None = None) -> None:
        from dataclasses import replace

        from fedtrack.deploy.demo import demo_settings, write_config
        from fedtrack.deploy.plan import apply_zenoh_settings, service_plan
        from fedtrack.deploy.security import ZenohSettings
        from fedtrack.keys import Keys

        self.tmp_path = tmp_path
        self.port = free_port()
        settings = demo_settings(n_sensors, 1, "federated", seed, self.port, tmp_path)
        name = f"t{time.monotonic_ns() % 10**9}"
        proto = "tls" if tls_dir is not None else "tcp"
        self.endpoint = f"{proto}/127.0.0.1:{self.port}"
        self.settings = replace(settings, deployment=replace(settings.deployment, name=name, pacing=pacing,
                                                             speed=speed, deadline_s=deadline_s,
                                                             router_listen=self.endpoint),
                                zenoh=ZenohSettings(tls_dir=str(tls_dir) if tls_dir is not None else None))
        self.config = tmp_path / "config.toml"
        write_config(self.settings, self.config)
        self.keys = Keys(name)
        plan = service_plan(self.settings, self.config, tmp_path, tmp_path / "logs")
        self.zenoh_config = apply_zenoh_settings(self.settings, self.config, tmp_path, plan)
        self.plan = {sp.name: sp for sp in plan}
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.tracks: list[tuple[Any, bytes]] = []
        self.health: dict[str, dict[str, int]] = {}
        self.session: Any = None
        self._subs: list[Any] = []

    def spawn(self, name: str) -> None:
        sp = self.plan[name]
        sp.log_path.parent.mkdir(parents=True, exist_ok=True)
        with sp.log_path.open("ab") as log:
            self.procs[name] = subprocess.Popen(sp.argv, stdout=log, stderr=subprocess.STDOUT,
                                                stdin=subprocess.DEVNULL)

    def wait_alive(self, names: list[str], timeout: float = 30.0) -> None:
        from fedtrack.zsession import wait_alive

        keys = [self.keys.alive(*name.split("/")) for name in names]
        missing = wait_alive(self.session, keys, timeout)
        assert not missing, f"not alive: {missing}; logs in {self.tmp_path / 'logs'}"

    def start(self, sensors: bool = True) -> None:
        from fedtrack.wire import FusedTrack, Health, decode
        from fedtrack.zsession import SessionOptions, open_session

        def on_health(sample: Any) -> None:
            h = decode(sample.payload.to_bytes(), Health)
            self.health[f"{h.role}/{h.id}"] = dict(h.counters)

        self.spawn("router/router")
        self.session = open_session(SessionOptions(connect=(self.endpoint,), connect_timeout_s=20.0,
                                                   config_file=self.zenoh_config))
        self._subs.append(self.session.declare_subscriber(
            self.keys.fusion_track(),
            lambda s: self.tracks.append((decode(s.payload.to_bytes(), FusedTrack), s.payload.to_bytes()))))
        self._subs.append(self.session.declare_subscriber(self.keys.health(), on_health))
        others = [n for n, sp in self.plan.items() if sp.role not in ("router", "sensor")]
        for name in others:
            self.spawn(name)
        self.wait_alive(["router/router", *others])
        if sensors:
            self.start_sensors()

    def start_sensors(self) -> None:
        for name, sp in self.plan.items():
            if sp.role == "sensor":
                self.spawn(name)

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        proc = self.procs[name]
        proc.send_signal(sig)
        proc.wait(10)

    def wait_sensors_done(self, timeout: float = 90.0) -> bool:
        sensors = [p for n, p in self.procs.items() if self.plan[n].role == "sensor"]
        return wait_until(lambda: all(p.poll() is not None for p in sensors), timeout)

    def stop(self, name: str, timeout: float = 10.0) -> int:
        proc = self.procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        return int(proc.returncode)

    def close(self) -> None:
        from fedtrack.zsession import close_session

        for sub in self._subs:
            sub.undeclare()
        if self.session is not None:
            close_session(self.session)
        for name in reversed(list(self.procs)):
            self.stop(name)


class SecureBus:
    """A router's endpoint and the Zenoh files of its identities (:func:`secure_router`); calling it opens a
    client session under one of them, ``link`` added to the endpoint (``#so_rcvbuf=4096``: Zenoh's link
    options)."""

    def __init__(self, endpoint: str, paths: dict[str, Path]) -> None:
        self.endpoint = endpoint
        self.paths = paths
        self.sessions: list[Any] = []
        self.router: Any = None  # the router's own session

    def __call__(self, ident: str, link: str = "", connect_timeout_s: float = 10.0) -> Any:
        from fedtrack.zsession import SessionOptions, open_session

        self.sessions.append(open_session(SessionOptions(connect=(self.endpoint + link,), config_file=str(
            self.paths[ident]), connect_timeout_s=connect_timeout_s)))
        return self.sessions[-1]


@contextlib.contextmanager
def secure_router(tmp_path: Path, keys: Any, identities: list[str]) -> Iterator[SecureBus]:
    """A router on a free loopback TLS port with the access control of ``identities`` (certificates made
    in ``tmp_path / "c"``, the files ``launch`` writes); yields its :class:`SecureBus`. Every session and
    the router are closed after."""
    from fedtrack.deploy.security import ZenohSettings, write_configs
    from fedtrack.zsession import SessionOptions, close_session, open_session

    paths = write_configs(ZenohSettings(tls_dir="c"), tmp_path, keys, ["router", *identities], tmp_path / "o")
    bus = SecureBus(f"tls/127.0.0.1:{free_port()}", paths)
    router = bus.router = open_session(SessionOptions(mode="router", connect=(), listen=(bus.endpoint,),
                                                      config_file=str(paths["router"])))
    try:
        yield bus
    finally:
        for session in bus.sessions:
            close_session(session)
        close_session(router)


def assert_same_pictures(live: list[dict[str, Any]], again: list[dict[str, Any]]) -> None:
    """Two multi-target picture streams (a live run and the replay of its recording) are the same:
    the same times, track ids, statuses, sensors and models, states and covariances to 1e-9, and
    the same central maneuvers (``maneuver``)."""
    import numpy as np

    assert [p["t"] for p in again] == [p["t"] for p in live]
    for a, b in zip(live, again):
        assert [(t["id"], t["status"], t["sensors"], t["model"], "maneuver" in t) for t in a["tracks"]] == \
            [(t["id"], t["status"], t["sensors"], t["model"], "maneuver" in t) for t in b["tracks"]]
        for ta, tb in zip(a["tracks"], b["tracks"]):
            np.testing.assert_allclose(ta["x"], tb["x"], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(ta["P"], tb["P"], rtol=1e-9, atol=1e-9)
            if "maneuver" in ta:
                for key in ("onset", "accel", "statistic"):
                    np.testing.assert_allclose(ta["maneuver"][key], tb["maneuver"][key], rtol=1e-9, atol=1e-9)
            assert sorted(ta) == sorted(tb)  # existence and lat / lon / alt in both or neither
            for key in ("existence", "lat", "lon", "alt"):
                if key in ta:
                    np.testing.assert_allclose(ta[key], tb[key], rtol=1e-9, atol=1e-9)
