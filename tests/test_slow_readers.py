"""Readers that stop reading and links that never open their session, against a live router with mutual TLS
and the access control (marker ``security``; docs/deploy.md, "Slow readers and unopened links"). Loopback
only; the router and every client in process."""

from __future__ import annotations

import contextlib
import json
import socket
import ssl
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from support import secure_router, wait_until

from fedtrack.deploy.security import DEFAULT_LIMITS, SESSIONS_PER_IDENTITY, STALL_SHARE
from fedtrack.keys import Keys
from fedtrack.services.router import sessions_by_identity
from fedtrack.zsession import SessionError, SessionOptions, open_session

pytestmark = pytest.mark.security
DEADLINE_S = DEFAULT_LIMITS.wait_before_close_s * STALL_SHARE  # the default deployment's shortest wait
PAYLOAD = 20_000  # bytes a message: a picture of some 50 tracks
RATE_HZ = 200.0
STREAM_S = 3.0  # long enough to fill the reader's socket and queue, and to be cut
OPEN_S = 8.0  # the accept timeout and the client's retries (0.1 s doubling to 1 s): 2.9-3.7 s measured


def test_a_reader_that_stops_reading_is_cut_before_the_deadline(tmp_path: Path) -> None:
    """Sensor 2's identity subscribes to the fused tracks (as its lockstep sensor does) with a callback that
    never returns and a 4 kB socket buffer: the router waited up to Zenoh's 5 s for room in its queue,
    holding up the fusion centre's whole link: the recorder got tracks 5.0 s late (max put 5.0 s; p99 9.6 s
    over 12 s at 100 Hz), past the centre's deadline. The router now closes the reader's link after a
    quarter of the deadline (``wait_before_close``): every track reaches the recorder within the deadline,
    in order, none lost (the reader's session reconnects and stalls again: each time for that long)."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "recorder", "sensor-2"]) as bus:
        centre, recorder, reader = bus("fusion"), bus("recorder"), bus("sensor-2", "#so_rcvbuf=4096")
        release = threading.Event()
        arrived: list[tuple[int, float]] = []
        recorder.declare_subscriber(keys.fusion_track(), lambda s: arrived.append(
            (int.from_bytes(s.payload.to_bytes()[:4], "big"), time.monotonic())))
        reader.declare_subscriber(keys.fusion_track(), lambda s: release.wait(30.0))
        publisher = centre.declare_publisher(keys.fusion_track(), congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_until(lambda: publisher.put(bytes(4)) or len(arrived) > 0, 10.0)  # routed to the recorder
        sent: list[float] = []
        start = time.monotonic()
        while time.monotonic() - start < STREAM_S:
            sent.append(time.monotonic())
            publisher.put(len(sent).to_bytes(4, "big") + bytes(PAYLOAD))
            time.sleep(max(0.0, start + len(sent) / RATE_HZ - time.monotonic()))

        def tracks() -> list[tuple[int, float]]:
            return [(n, at) for n, at in arrived if n > 0]  # the probes are 0
        assert wait_until(lambda: len(tracks()) >= len(sent), 10.0), (len(tracks()), len(sent))
        release.set()
    assert [n for n, _ in tracks()] == list(range(1, len(sent) + 1))  # in order, none lost
    late = np.array([at for _, at in tracks()]) - np.array(sent)
    # the reader did hold the stream up (its queue full), and was cut before the deadline
    assert DEFAULT_LIMITS.wait_before_close_s / 2 < late.max() < DEADLINE_S, late.max()


@contextlib.contextmanager
def unopened_links(bus: Any, ident: str, count: int) -> Any:
    """``count`` links that pass mutual TLS with ``ident``'s certificate and never open a Zenoh session."""
    files = json.loads(bus.paths[ident].read_text())["transport"]["link"]["tls"]
    tls = ssl.create_default_context(cafile=files["root_ca_certificate"])
    tls.load_cert_chain(files["connect_certificate"], files["connect_private_key"])
    host, port = bus.endpoint.removeprefix("tls/").split(":")
    links = []
    try:
        for _ in range(count):
            links.append(tls.wrap_socket(socket.create_connection((host, int(port)), timeout=5.0),
                                         server_hostname=host))
        yield links
    finally:
        for link in links:
            link.close()


def test_links_that_never_open_a_session_hold_new_sessions_off_for_a_second_at_most(tmp_path: Path) -> None:
    """An identity's certificate opens 110 TLS links and sends nothing on them: Zenoh keeps at most 100
    links opening at once (``accept_pending``) and closed every new one, an honest service's included,
    until they timed out after Zenoh's 10 s (``accept_timeout``; measured: a session opened after 11.8-12.5
    s). The router now gives a link ``ACCEPT_TIMEOUT_S`` (1 s) to open its session: 3.7 s measured, the
    rest the client's retries."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "sensor-2"]) as bus, unopened_links(bus, "sensor-2", 110):
        try:
            bus.sessions.append(open_session(SessionOptions(connect=(bus.endpoint,), connect_timeout_s=OPEN_S,
                                                            config_file=str(bus.paths["fusion"]))))
        except SessionError:
            pytest.fail(f"no session within {OPEN_S} s beside 110 unopened links")


def test_one_identity_opens_no_more_sessions_than_the_router_takes_for_the_deployment(tmp_path: Path) -> None:
    """Sessions of one identity, each reading what it may (the fused tracks), multiply what the router
    sends: 400 of sensor 2's, at 20 kB and 100 Hz, took the recorder's tracks from p50 0.5 ms to 1.16 s
    (p99 1.86 s); the router took up to Zenoh's 1,000. It now takes ``SESSIONS_PER_IDENTITY`` per identity
    of the deployment (here 4 x 4: router, fusion, sensor 2, the launcher) and refuses the next, while the
    sessions it has go on. The router's links name each session's identity (its Health status says
    which holds the most when every place is taken: ``tests/test_router_descriptors.py``)."""
    keys = Keys("x")
    with secure_router(tmp_path, keys, ["fusion", "sensor-2"]) as bus:
        centre = bus("fusion")
        taken = SESSIONS_PER_IDENTITY * 4 - 1  # the centre's is one of them
        for _ in range(taken):
            bus("sensor-2")
        with pytest.raises(SessionError):
            bus("sensor-2", connect_timeout_s=1.0)
        assert sessions_by_identity(bus.router) == {"fusion": 1, "sensor-2": taken}  # what the router says
        got: list[bytes] = []
        bus.sessions[-1].declare_subscriber(keys.fusion_track(), lambda s: got.append(s.payload.to_bytes()))
        assert wait_until(lambda: centre.put(keys.fusion_track(), b"t") or got != [], 10.0)
