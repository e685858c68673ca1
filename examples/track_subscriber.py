"""Print a fedtrack deployment's fused tracks as JSON lines: zenoh + msgpack only.

Subscribes to ``fedtrack/<deployment>/fusion/track`` and prints one line per track:
``{"seq", "t", "model", "x", "maneuver", "degraded", "sensors"}`` (``x`` in the model's
state order: CV ``[x, vx, y, vy]``, CA ``[x, vx, ax, y, vy, ay]``). The first line,
``{"subscribed": key}``, says it is listening (tracks published before are not seen).

    python examples/track_subscriber.py --connect tcp/127.0.0.1:7447 --deployment demo --count 20
"""

from __future__ import annotations

import argparse
import json
import queue
import sys
import time

from wire_contract import decode, from_array, session


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447",
                    help="the deployment's router (default: %(default)s)")
    ap.add_argument("--deployment", default="demo",
                    help="key prefix fedtrack/<deployment>/: the [deployment] name (default: %(default)s, "
                         "as fedtrack's)")
    ap.add_argument("--count", type=int, default=0, help="stop after this many tracks (0: never; default: %(default)s)")
    ap.add_argument("--timeout", type=float, default=0.0,
                    help="stop after this many seconds (0: never; default: %(default)s)")
    ap.add_argument("--zenoh-config", metavar="FILE",
                    help="Zenoh JSON5 file loaded first: an authenticated deployment's mutual TLS, e.g. the "
                         "OUT/zenoh/launcher.json5 fedtrack launch writes, with a tls/ --connect "
                         "(default: none, plain)")
    args = ap.parse_args()
    key = f"fedtrack/{args.deployment}/fusion/track"
    tracks: queue.Queue[bytes] = queue.Queue()
    s = session(args.connect, config_file=args.zenoh_config)
    try:
        sub = s.declare_subscriber(key, lambda sample: tracks.put(sample.payload.to_bytes()))
        print(json.dumps({"subscribed": key}), flush=True)
        deadline = time.monotonic() + args.timeout if args.timeout > 0 else float("inf")
        seen = 0
        while seen < args.count or args.count == 0:
            try:
                payload = tracks.get(timeout=max(min(deadline - time.monotonic(), 0.5), 0.0))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    break
                continue
            try:
                tr = decode(payload, "FusedTrack")
            except ValueError as exc:
                print(f"track_subscriber: skipped a payload: {exc}", file=sys.stderr)
                continue
            print(json.dumps({"seq": tr["seq"], "t": tr["t"], "model": tr["model"], "x": from_array(tr["x"]),
                              "maneuver": tr["maneuver"], "degraded": tr["degraded"], "sensors": tr["sensors"]}),
                  flush=True)
            seen += 1
        sub.undeclare()
    finally:
        s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
