"""A third-party position sensor for a fedtrack deployment: zenoh + msgpack only.

It follows the start-up rules of docs/wire.md:

1. wait until the deployment's local filter for this sensor and the fusion center are
   alive (liveliness tokens): a scan published before their subscribers exist is lost;
2. ask ``fusion/state`` for the latest fused track: none means the deployment has not
   started and this sensor publishes scan 0 first; a track of scan k means the sensor
   joins late and publishes scan k + 1 first (earlier scans would be dropped as late);
3. scan k has ``seq = k`` and ``t = k * period`` (the deployment's scan time, not the
   wall clock); ``stamp_ns`` is the wall-clock publish time (latency only);
4. lockstep pacing: scan k + 1 goes out once ``fusion/track`` of scan k has arrived (or
   after ``--lockstep-timeout`` seconds without it).

The target is simulated here (constant velocity plus Gaussian noise); replace
``measure()`` with a real sensor.

    python examples/sensor_publisher.py --connect tcp/127.0.0.1:7447 --deployment demo --sensor ext
"""

from __future__ import annotations

import argparse
import random
import sys
import threading
import time

import zenoh
from wire_contract import ENCODING, array, decode, encode, session


def measure(t: float, rng: random.Random, sigma: float) -> tuple[float, float]:
    """The sensor's position measurement at scan time ``t`` (m)."""
    return 1000.0 + 20.0 * t + rng.gauss(0.0, sigma), 2000.0 + 10.0 * t + rng.gauss(0.0, sigma)


def wait_alive(s: zenoh.Session, keys: list[str], timeout_s: float) -> list[str]:
    """Wait until a liveliness token exists for every key; returns the keys still missing."""
    deadline = time.monotonic() + timeout_s
    missing = list(keys)
    while missing and time.monotonic() < deadline:
        missing = [k for k in missing if not any(r.ok is not None for r in s.liveliness().get(k, timeout=0.5))]
        if missing:
            time.sleep(0.1)
    return missing


def first_seq(s: zenoh.Session, prefix: str) -> int:
    """0 on a fresh deployment; the scan after the latest fused track when joining late."""
    for reply in s.get(f"{prefix}/fusion/state", timeout=2.0):
        if reply.ok is not None:
            return int(decode(reply.ok.payload.to_bytes(), "FusedTrack")["seq"]) + 1
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447",
                    help="the deployment's router (default: %(default)s)")
    ap.add_argument("--deployment", default="demo",
                    help="key prefix fedtrack/<deployment>/: the [deployment] name (default: %(default)s, "
                         "as fedtrack's)")
    ap.add_argument("--sensor", default="ext",
                    help="this sensor's id (listed in the deployment's [fusion] sensors; default: %(default)s)")
    ap.add_argument("--scans", type=int, default=20, help="scans to publish (default: %(default)s)")
    ap.add_argument("--period", type=float, default=1.0, help="scan period T, s (t = seq * T; default: %(default)s)")
    ap.add_argument("--sigma", type=float, default=10.0, help="measurement noise std, m (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the measurement noise (default: %(default)s)")
    ap.add_argument("--lockstep-timeout", type=float, default=5.0, metavar="SECONDS",
                    help="longest wait for the fused track of the previous scan before the next (default: %(default)s)")
    ap.add_argument("--zenoh-config", metavar="FILE",
                    help="Zenoh JSON5 file loaded first: an authenticated deployment's mutual TLS, e.g. the "
                         "OUT/zenoh/sensor-<id>.json5 fedtrack launch writes, with a tls/ --connect "
                         "(default: none, plain)")
    args = ap.parse_args()
    prefix = f"fedtrack/{args.deployment}"
    rng = random.Random(args.seed)
    R = [args.sigma**2, 0.0, 0.0, args.sigma**2]
    fused = threading.Condition()
    fused_up_to = [-1]

    def on_track(sample: zenoh.Sample) -> None:
        try:
            seq = int(decode(sample.payload.to_bytes(), "FusedTrack")["seq"])
        except ValueError:
            return
        with fused:
            fused_up_to[0] = max(fused_up_to[0], seq)
            fused.notify_all()

    s = session(args.connect, config_file=args.zenoh_config)
    try:
        missing = wait_alive(s, [f"{prefix}/alive/local-filter/{args.sensor}", f"{prefix}/alive/fusion-center/*"], 30.0)
        if missing:
            print(f"sensor_publisher: not alive after 30 s: {', '.join(missing)}", file=sys.stderr)
            return 1
        sub = s.declare_subscriber(f"{prefix}/fusion/track", on_track)
        pub = s.declare_publisher(f"{prefix}/sensor/{args.sensor}/meas", encoding=zenoh.Encoding(ENCODING),
                                  congestion_control=zenoh.CongestionControl.BLOCK)
        start = first_seq(s, prefix)
        for seq in range(start, start + args.scans):
            with fused:  # lockstep: the previous scan is fused (or the timeout passed)
                fused.wait_for(lambda: seq == start or fused_up_to[0] >= seq - 1, timeout=args.lockstep_timeout)
            t = seq * args.period
            x, y = measure(t, rng, args.sigma)
            pub.put(encode("Measurement", sensor=args.sensor, seq=seq, t=t, kind="position",
                           z=array([x, y], (2,)), R=array(R, (2, 2)), detections=[], sensor_position=None,
                           stamp_ns=time.time_ns()))
        with fused:
            fused.wait_for(lambda: fused_up_to[0] >= start + args.scans - 1, timeout=args.lockstep_timeout)
        print(f"published scans {start}..{start + args.scans - 1}; fused up to {fused_up_to[0]}")
        sub.undeclare()
        pub.undeclare()
    finally:
        s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
