"""The transport floor of the federated pipeline: its hops, processes and payload sizes, no estimation.

For ``n`` sensors, on a router started as the deployment's (``fedtrack serve router``):

* ``n`` *source* processes (the sensors) publish scan ``seq`` at ``rate`` Hz from one shared
  start time on ``floor/<run>/meas/<i>``, payload the size of a wire ``Measurement``;
* ``n`` *relay* processes (the local filters) republish each on ``floor/<run>/est/<i>``, the size
  of a ``LocalEstimate``;
* one *collector* (the fusion centre) holds a scan until all ``n`` estimates are in, then publishes
  it on ``floor/<run>/track`` (a ``FusedTrack``'s size) and ``n`` resets (a ``Reset``'s size);
* the bench, as the launcher's monitor, takes each track's arrival minus the last publish of
  its scan, as ``fedtrack bench`` does for the deployment.

What is left is Zenoh, msgpack, Python callbacks and the scheduling of as many processes on
this machine: the least the pipeline's latency can be. ``python -m fedtrack.benchmarks.floor
source|relay|collector ...`` are the helper processes.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import msgpack
import numpy as np

from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive

READY_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 5.0


def payload_sizes() -> dict[str, int]:
    """Encoded sizes of the pipeline's messages for one CV sensor (4-state track)."""
    from fedtrack.wire import FusedTrack, LocalEstimate, Measurement, Reset, encode

    x, P = np.arange(4.0), np.eye(4)
    return {
        "meas": len(encode(Measurement(sensor="1", seq=1, t=1.0, kind="position", z=np.ones(2), R=np.eye(2)))),
        "est": len(encode(LocalEstimate(sensor="1", seq=1, t=1.0, model="cv", x=x, P=P, x_prior=x, P_prior=P,
                                        stamp_ns=time.time_ns()))),
        "track": len(encode(FusedTrack(seq=1, t=1.0, model="cv", x=x, P=P, maneuver=False, degraded=False,
                                       sensors=("1", "2"), stamp_ns=time.time_ns()))),
        "reset": len(encode(Reset(sensor="1", seq=1, t=1.0, model="cv", x=x, P=P, beta=0.5))),
    }


def _message(seq: int, stamp_ns: int, size: int) -> bytes:
    return msgpack.packb({"seq": seq, "stamp_ns": stamp_ns, "pad": bytes(max(size - 32, 0))})


def _session(endpoint: str) -> Any:
    return open_session(SessionOptions(mode="client", connect=(endpoint,), connect_timeout_s=READY_TIMEOUT_S))


def _serve_until_killed(session: Any, alive_key: str) -> None:
    """Declare ``alive_key`` and serve the callbacks until the bench terminates the process."""
    _token = session.liveliness().declare_token(alive_key)  # held: a collected token is undeclared
    while True:
        time.sleep(1.0)


def run_source(a: argparse.Namespace) -> None:
    """Publish ``scans`` scans at ``rate`` Hz from ``start`` (epoch seconds), then exit."""
    session = _session(a.connect)
    pub = session.declare_publisher(f"floor/{a.run}/meas/{a.index}")
    for seq in range(a.scans):
        delay = a.start + seq / a.rate - time.time()
        if delay > 0:
            time.sleep(delay)
        pub.put(_message(seq, time.time_ns(), a.size))
    time.sleep(0.5)
    close_session(session)


def run_relay(a: argparse.Namespace) -> None:
    """Republish each measurement of source ``index`` as an estimate."""
    session = _session(a.connect)
    pub = session.declare_publisher(f"floor/{a.run}/est/{a.index}")

    def on_meas(sample: Any) -> None:
        m = msgpack.unpackb(sample.payload.to_bytes())
        pub.put(_message(m["seq"], m["stamp_ns"], a.size))

    session.declare_subscriber(f"floor/{a.run}/meas/{a.index}", on_meas)
    _serve_until_killed(session, f"floor/{a.run}/alive/relay-{a.index}")


def run_collector(a: argparse.Namespace) -> None:
    """Publish a track (stamped with the scan's last publish) and ``n`` resets once all ``n`` estimates of a scan are in."""
    session = _session(a.connect)
    track_pub = session.declare_publisher(f"floor/{a.run}/track")
    reset_pubs = [session.declare_publisher(f"floor/{a.run}/reset/{i}") for i in range(a.n)]
    pending: dict[int, list[int]] = {}
    lock = threading.Lock()

    def on_est(sample: Any) -> None:
        m = msgpack.unpackb(sample.payload.to_bytes())
        with lock:
            stamps = pending.setdefault(m["seq"], [])
            stamps.append(m["stamp_ns"])
            if len(stamps) < a.n:
                return
            del pending[m["seq"]]
        track_pub.put(_message(m["seq"], max(stamps), a.size))
        for pub in reset_pubs:
            pub.put(_message(m["seq"], 0, a.reset_size))

    session.declare_subscriber(f"floor/{a.run}/est/*", on_est)
    _serve_until_killed(session, f"floor/{a.run}/alive/collector")


def measure_floor(n: int, endpoint: str, scans: int, rate: float, startup_scans: int,
                  run: str) -> dict[str, Any]:
    """Start the router and the helpers, run ``scans`` scans, return latencies from the last publish (ms)."""
    sizes = payload_sizes()
    base = [sys.executable, "-m", "fedtrack.benchmarks.floor"]
    common = ["--connect", endpoint, "--run", run]
    procs: list[subprocess.Popen[bytes]] = []
    arrivals: dict[int, int] = {}
    stamps: dict[int, int] = {}
    with tempfile.TemporaryFile() as log:
        def start(argv: list[str]) -> None:
            procs.append(subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL))

        try:
            start([sys.executable, "-m", "fedtrack.cli", "serve", "router", "--deployment", f"floor-{run}",
                   "--listen", endpoint])
            session = _session(endpoint)
            try:
                def on_track(sample: Any) -> None:
                    now = time.time_ns()
                    m = msgpack.unpackb(sample.payload.to_bytes())
                    arrivals[m["seq"]], stamps[m["seq"]] = now, m["stamp_ns"]

                sub = session.declare_subscriber(f"floor/{run}/track", on_track)
                start(base + ["collector", *common, "--n", str(n), "--size", str(sizes["track"]),
                              "--reset-size", str(sizes["reset"])])
                for i in range(n):
                    start(base + ["relay", *common, "--index", str(i), "--size", str(sizes["est"])])
                want = [f"floor/{run}/alive/collector"] + [f"floor/{run}/alive/relay-{i}" for i in range(n)]
                missing = wait_alive(session, want, READY_TIMEOUT_S)
                if missing:
                    raise RuntimeError(f"floor helpers not ready: {', '.join(sorted(missing))}")
                t0 = time.time() + 2.0  # one shared start, as the launcher aligns realtime sensors
                sources = [subprocess.Popen(base + ["source", *common, "--index", str(i), "--size", str(sizes["meas"]),
                                                    "--scans", str(scans), "--rate", str(rate), "--start", repr(t0)],
                                            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
                           for i in range(n)]
                procs.extend(sources)
                deadline = t0 + scans / rate + READY_TIMEOUT_S
                for p in sources:
                    p.wait(timeout=max(deadline - time.time(), 1.0))
                time.sleep(0.5)
                sub.undeclare()
            finally:
                close_session(session)
        finally:
            for p in reversed(procs):
                if p.poll() is None:
                    p.terminate()
            for p in procs:
                try:
                    p.wait(timeout=STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
    steady = [(arrivals[s] - stamps[s]) / 1e6 for s in arrivals if s >= startup_scans]
    p50, p99 = np.percentile(steady, [50, 99]) if steady else (float("nan"), float("nan"))
    return {"sensors": n, "scans": len(arrivals), "steady_scans": len(steady), "payload_bytes": sizes,
            "p50_ms": float(p50), "p99_ms": float(p99)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fedtrack.benchmarks.floor", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="role", required=True)
    for role in ("source", "relay", "collector"):
        p = sub.add_parser(role)
        p.add_argument("--connect", required=True)
        p.add_argument("--run", required=True)
        p.add_argument("--size", type=int, required=True)
        if role != "collector":
            p.add_argument("--index", type=int, required=True)
    sub.choices["source"].add_argument("--scans", type=int, required=True)
    sub.choices["source"].add_argument("--rate", type=float, required=True)
    sub.choices["source"].add_argument("--start", type=float, required=True)
    sub.choices["collector"].add_argument("--n", type=int, required=True)
    sub.choices["collector"].add_argument("--reset-size", type=int, required=True)
    a = parser.parse_args(argv)
    {"source": run_source, "relay": run_relay, "collector": run_collector}[a.role](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
