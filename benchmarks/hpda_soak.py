"""``fedtrack bench hpda-soak [--minutes 10] [--clutter 1.5e-4] [--rate 4] [--algorithm hpda] [--json PATH]``:
``fedtrack serve hpda`` for a long run in dense clutter, outside CI (issue 15).

A loopback Zenoh router runs in this process; the tracker runs as its own ``fedtrack serve hpda``
process. This process publishes the simulated sonar's scans (paper 001's target on a straight
course, Poisson clutter of density ``--clutter`` over 2 km x 2 km: 600 detections a scan at the
paper's densest 1.5e-4) at ``--rate`` scans per second of wall time, each stamped with its
publish time, and subscribes to the tracker's confirmed tracks and Health. Reported per minute:
scans published, the publish-to-track latency p50 / p99 (over the scans with a confirmed track;
a scan's latency is its first track's), confirmed tracks per scan, the tracker's live track count
(Health ``live_tracks``) and resident set size; and the first minute against the last.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.benchmarks.soak import median, rss_mb
from fedtrack.config import seed_number
from fedtrack.jsonl import check_output, output_file
from fedtrack.keys import Keys
from fedtrack.sensors.sonar import ScenarioConfig, SonarConfig, sonar_scans
from fedtrack.wire import FusedTrack, Health, decode, encode, measurement_from_replay
from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive

DEPLOYMENT = "hpdasoak"
SENSOR = "sonar1"
MINUTE_S = 60.0


class Recorder:
    """What the subscriber saw, keyed by scan (thread-safe appends from Zenoh callbacks)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.first_track_ns: dict[int, int] = {}  # seq -> arrival of its first track
        self.tracks_per_scan: dict[int, int] = {}
        self.live: list[tuple[float, int]] = []  # (monotonic s, live_tracks)

    def on_track(self, payload: bytes) -> None:
        now = time.time_ns()
        track = decode(payload, FusedTrack)
        with self.lock:
            self.first_track_ns.setdefault(track.seq, now)
            self.tracks_per_scan[track.seq] = self.tracks_per_scan.get(track.seq, 0) + 1

    def on_health(self, payload: bytes) -> None:
        health = decode(payload, Health)
        if "live_tracks" in health.counters:
            with self.lock:
                self.live.append((time.monotonic(), int(health.counters["live_tracks"])))


def minute_stats(sent: list[tuple[float, int, int]], rec: Recorder, rss: list[tuple[float, float]],
                 lo: float, hi: float) -> dict[str, Any]:
    """Statistics of the scans published in ``[lo, hi)`` seconds after the start."""
    scans = [(seq, stamp) for t, seq, stamp in sent if lo <= t < hi]
    lat = [(rec.first_track_ns[seq] - stamp) / 1e6 for seq, stamp in scans if seq in rec.first_track_ns]
    live = [n for t, n in rec.live if lo <= t < hi]
    mem = [m for t, m in rss if lo <= t < hi]
    return {"scans": len(scans), "scans_with_track": len(lat),
            "p50_ms": float(np.percentile(lat, 50)) if lat else None,
            "p99_ms": float(np.percentile(lat, 99)) if lat else None,
            "confirmed_per_scan": float(np.mean([rec.tracks_per_scan.get(seq, 0) for seq, _ in scans])) if scans else None,
            "live_tracks_mean": float(np.mean(live)) if live else None,
            "live_tracks_max": max(live) if live else None,
            "rss_mb": median(mem) if mem else None}


def run(minutes: float, clutter: float, rate: float, algorithm: str, seed: int) -> dict[str, Any]:
    from fedtrack.deploy.demo import free_port

    port = free_port()
    keys = Keys(DEPLOYMENT)
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    opts = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=10.0)
    session = open_session(opts)
    rec = Recorder()
    session.declare_subscriber(keys.tracker_track("hpda", SENSOR), lambda s: rec.on_track(s.payload.to_bytes()))
    session.declare_subscriber(keys.health("hpda", "h1"), lambda s: rec.on_health(s.payload.to_bytes()))
    tracker = subprocess.Popen([sys.executable, "-m", "fedtrack.cli", "serve", "hpda", "--sensor", SENSOR,
                                "--algorithm", algorithm, "--id", "h1", "--deployment", DEPLOYMENT,
                                "--connect", f"tcp/127.0.0.1:{port}"], stderr=subprocess.PIPE)
    sent: list[tuple[float, int, int]] = []
    rss: list[tuple[float, float]] = []
    total = int(minutes * MINUTE_S * rate)
    try:
        if wait_alive(session, [keys.alive("hpda", "h1")], 30.0):
            raise RuntimeError("fedtrack serve hpda did not come up in 30 s")
        scenario = ScenarioConfig(duration=25.0 * (total + 1), maneuver_start=1e12)
        cfg = replace(SonarConfig(clutter_density=clutter), scenario=scenario)
        t0 = time.monotonic()
        next_rss = 0.0
        for seq, line in zip(range(total), sonar_scans(cfg, seed)):
            line.pop("truth")
            wait = t0 + seq / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            stamp = time.time_ns()
            line["stamp_ns"] = stamp
            session.put(keys.sensor_meas(SENSOR), encode(measurement_from_replay(line, "soak", seq)))
            now = time.monotonic() - t0
            sent.append((now, seq, stamp))
            if now >= next_rss:
                mem = rss_mb(tracker.pid)
                if mem is not None:
                    rss.append((now, mem))
                next_rss = now + 5.0
            if seq % int(MINUTE_S * rate) == 0:
                print(f"hpda-soak: {now / MINUTE_S:.1f} min, {seq} scans sent", file=sys.stderr, flush=True)
        time.sleep(3.0)
        rec.live = [(t - t0, n) for t, n in rec.live]
    finally:
        tracker.send_signal(signal.SIGINT)
        try:
            code = tracker.wait(15.0)
        except subprocess.TimeoutExpired:
            tracker.kill()
            code = tracker.wait()
        close_session(session)
        close_session(router)
    span = minutes * MINUTE_S
    per_minute = [minute_stats(sent, rec, rss, m * MINUTE_S, (m + 1) * MINUTE_S) for m in range(int(np.ceil(minutes)))]
    first, last = per_minute[0], per_minute[-1]
    ratios = {k: (last[k] / first[k] if first[k] and last[k] is not None else None)
              for k in ("p50_ms", "p99_ms", "live_tracks_mean", "rss_mb")}
    return {"minutes": minutes, "clutter_density": clutter, "rate_scans_per_s": rate, "algorithm": algorithm,
            "seed": seed, "scans_sent": len(sent), "scans_with_track": len(rec.first_track_ns),
            "whole_run": minute_stats(sent, rec, rss, 0.0, span + 1.0), "per_minute": per_minute,
            "last_over_first_minute": ratios, "tracker_exit_code": code}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack bench hpda-soak", description=(
        "fedtrack bench hpda-soak: fedtrack serve hpda for --minutes in dense clutter (the paper's densest, 600 "
        "detections a scan); latency, track counts and resident memory per minute (issue 15)."))
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak, at least 1 (its numbers are "
                        "per minute; default: %(default)s)")
    parser.add_argument("--clutter", type=float, default=1.5e-4, help="clutter density per m^2 (default: %(default)s)")
    parser.add_argument("--rate", type=float, default=4.0, help="scans per second (default: %(default)s)")
    parser.add_argument("--algorithm", default="hpda", choices=("hpda", "pda-ai"), help="the tracker (default: %(default)s)")
    parser.add_argument("--seed", type=seed_number, default=1, help="seed of the scenario (default: %(default)s)")
    parser.add_argument("--json", type=Path, help="write the result here (default: printed only)")
    args = parser.parse_args(argv)
    if not 1.0 <= args.minutes < math.inf:
        parser.error(f"--minutes: must be finite and >= 1 (its numbers are per minute), got {args.minutes:g}")
    for name in ("rate", "clutter"):
        if not 0.0 < getattr(args, name) < math.inf:
            parser.error(f"--{name}: must be finite and > 0, got {getattr(args, name):g}")
    if args.json:
        check_output(args.json)
    result = run(args.minutes, args.clutter, args.rate, args.algorithm, args.seed)
    for m, row in enumerate(result["per_minute"]):
        print(f"minute {m + 1}: {row['scans']} scans, {row['scans_with_track']} with a track, "
              f"p50 {row['p50_ms']:.1f} ms, p99 {row['p99_ms']:.1f} ms, "
              f"confirmed/scan {row['confirmed_per_scan']:.2f}, live tracks {row['live_tracks_mean']:.0f} "
              f"(max {row['live_tracks_max']}), RSS {row['rss_mb']:.0f} MB")
    print("last / first minute:", {k: (round(v, 3) if v is not None else None)
                                   for k, v in result["last_over_first_minute"].items()})
    if args.json:
        with output_file(args.json) as fh:
            fh.write(json.dumps(result, indent=1))
    return 0 if result["tracker_exit_code"] == 0 else 1
