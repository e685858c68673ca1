"""A router that takes no new session says why (marker ``faults``; docs/deploy.md#machine-and-storage-faults).

Under ``prlimit --nofile`` a router whose descriptors ran out refused every new session (its clients'
``cannot open a zenoh client session ... Timeout!``) and logged nothing: Zenoh's only signal is a WARN
of its own Rust log, which no fedtrack process enables; nor did it say when one identity held every
session place. The router now counts its descriptors and its sessions by identity each second
(:func:`fedtrack.services.router.descriptors`, :func:`~fedtrack.services.router.sessions_by_identity`,
the latter live in ``tests/test_slow_readers.py``), and the launcher says a router's status when it
changes. Driven in-process (the router's tick, the launcher's Health callback) and, for the count of
descriptors, in a child process under a low ``RLIMIT_NOFILE``; about 1 s in all.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import threading
from collections import Counter
from pathlib import Path

import pytest
from support import free_port
from test_hostile_monitor import sample

from fedtrack.deploy.launcher import Launcher
from fedtrack.deploy.settings import load_settings
from fedtrack.services import router as router_module
from fedtrack.services.router import Router, sessions_by_identity
from fedtrack.wire import Health, encode
from fedtrack.zsession import SessionOptions, close_session, open_session

pytestmark = pytest.mark.faults

FILL = """
import os, resource
from fedtrack.services.router import descriptors
resource.setrlimit(resource.RLIMIT_NOFILE, (64, 64))
before = descriptors()
held = []
try:
    while True:
        held.append(os.open(os.devnull, os.O_RDONLY))
except OSError:
    pass
print(before[0], before[1], *descriptors())
"""


def test_descriptors_counts_up_to_the_limit() -> None:
    """In a process under ``RLIMIT_NOFILE`` 64: fewer than 64 open at first, then, every descriptor
    taken (``/proc/self/fd`` can no longer be listed), 64 of 64."""
    out = subprocess.run([sys.executable, "-c", FILL], capture_output=True, text=True, timeout=30, check=True)
    used, limit, used_full, limit_full = map(int, out.stdout.split())
    assert limit == limit_full == 64 and 3 <= used < 64 and used_full == 64


def test_a_router_counts_more_sessions_than_a_zenoh_channel_holds() -> None:
    """A router with 260 client sessions counts them all at once. Read from its admin space (before
    2026-11-27), whose replies its own ``get`` queues into a channel of 256, the count never returned:
    the router's tick hung for good beyond 256 sessions (here, from a thread, it fails within 10 s)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(SessionOptions(mode="router", connect=(), listen=(endpoint,)))
    clients = []
    try:
        clients = [open_session(SessionOptions(connect=(endpoint,))) for _ in range(260)]
        counted: list[Counter[str]] = []
        reader = threading.Thread(target=lambda: counted.append(sessions_by_identity(router)), daemon=True)
        reader.start()
        reader.join(10.0)
        assert counted == [Counter({"": 260})]  # no certificate on these links
    finally:
        for session in [*clients, router]:
            close_session(session)


def test_a_router_that_takes_no_session_says_why_once_and_again_when_it_does(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """Ticks out of descriptors, then with every session place taken (``max_sessions`` 16 of the router's
    Zenoh configuration; sensor 2 holding 15, then 14), then with room: one line per change of cause (not
    per change of its counts), Health status naming it meanwhile, ``fd_exhausted`` and ``sessions_full``
    counting the seconds."""
    few, full = Counter({"fusion": 1, "sensor-2": 3}), Counter({"fusion": 1, "sensor-2": 15})
    still_full = Counter({"fusion": 2, "sensor-2": 14})
    ticks = iter([((30, 40), few), ((40, 40), few), ((40, 40), few), ((30, 40), full), ((31, 40), still_full),
                  ((25, 40), few)])
    now: list[tuple[tuple[int, int], Counter[str]]] = []

    def descriptors() -> tuple[int, int]:  # each tick reads the descriptors first
        now[:] = [next(ticks)]
        return now[0][0]

    monkeypatch.setattr(router_module, "descriptors", descriptors)
    monkeypatch.setattr(router_module, "sessions_by_identity", lambda session: now[0][1])
    config = tmp_path / "router.json5"
    config.write_text('{"transport": {"unicast": {"max_sessions": 16}}}')
    svc = Router("router", SessionOptions(mode="router", connect=(), config_file=str(config)), deployment="fd")
    svc.session = object()  # type: ignore[assignment]  # its links are read through sessions_by_identity
    statuses = []
    with caplog.at_level(logging.INFO, logger="fedtrack.router.router"):
        for _ in range(6):
            svc.on_tick()
            statuses.append(svc.status)
    fds = "out of file descriptors (40 open, RLIMIT_NOFILE 40): new sessions are refused"
    places = "every session place taken (16 of max_sessions 16; sensor-2 holds 15): new sessions are refused"
    assert statuses == ["ok", fds, fds, places, places, "ok"]
    assert svc.counters["fd_exhausted"] == 2 and svc.counters["sessions_full"] == 2
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        ("ERROR", fds), ("ERROR", places),
        ("WARNING", "new sessions are taken again (4 open, 25 file descriptors of RLIMIT_NOFILE 40)")]


def test_the_launcher_says_a_routers_status_when_it_changes(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    """The launcher's monitor says a router's Health status once per change (not every second), and
    another service's status never (the centre's ``inconsistent sensors`` is its own report's), nor the
    router's last, ``stopped`` (every run's end said 'router/router: stopped')."""
    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\nname = "fd"\n')
    launcher = Launcher(load_settings(cfg), [], quiet=True)
    out = "out of file descriptors (40 open, RLIMIT_NOFILE 40): new sessions are refused"
    for seq, (role, status) in enumerate([("router", "ok"), ("router", out), ("router", out), ("router", "ok"),
                                          ("mtt-centre", "inconsistent sensors: s1"), ("router", "stopped")]):
        h = Health(role=role, id="r", seq=seq, counters={"received": 0}, status=status)
        launcher._on_health(sample(launcher.keys.health(role, "r"), encode(h)))
    said = [line for line in capsys.readouterr().err.splitlines() if line]
    assert said == [f"fedtrack launch: router/r: {out}", "fedtrack launch: router/r: ok"]


def test_a_router_without_a_link_to_a_router_it_joins_says_so_until_it_has_one(
        caplog: pytest.LogCaptureFixture) -> None:
    """``router_connect`` to another host's router that is not up: Zenoh retries for good and the router, the
    launch with it, ran on alone and silent (tour59). Past ``--connect-timeout`` (0.5 s here) its status and a line
    name the endpoint without a link, and a line says when the link comes; a joined endpoint (given by a
    host name) is never named."""
    from support import wait_until

    joined, later = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    by_name = joined.replace("127.0.0.1", "localhost")
    first = open_session(SessionOptions(mode="router", connect=(), listen=(joined,)))
    options = SessionOptions(mode="router", connect=(by_name, later), listen=(f"tcp/127.0.0.1:{free_port()}",),
                             connect_timeout_s=0.5)
    svc = Router("router", options, deployment="rc")
    svc.session = open_session(options)
    second = None
    try:
        with caplog.at_level(logging.INFO, logger="fedtrack.router.router"):
            assert wait_until(lambda: bool(list(svc.session.info.links())), 10.0)  # type: ignore[union-attr]
            svc.on_tick()
            assert wait_until(lambda: (svc.on_tick(), svc.status != "ok")[1], 10.0)
            assert svc.status == f"no link to the router at {later} (--connect; retrying)"
            second = open_session(SessionOptions(mode="router", connect=(), listen=(later,)))
            assert wait_until(lambda: (svc.on_tick(), svc.status == "ok")[1], 10.0)
        assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
            ("ERROR", f"no link to the router at {later} after 0.5 s (retrying): its host's router not up, or the "
                      "address or port wrong?"),
            ("WARNING", f"joined the router at {later}")]
    finally:
        for session in (svc.session, first, second):
            if session is not None:
                close_session(session)
