"""Micro-benchmark of the wire's cost for a multi-target scan: ``decode`` and ``encode`` of a
``Measurement`` of kind ``scan`` with n detections of 2-D and 3-D ``z``, best of ``--rounds``.

    python -m fedtrack.benchmarks.wire_decode [--rounds 7] [--sizes 1,10,100,900,2048,5000]

A size beyond MAX_DETECTIONS (2048) is packed by hand and timed as the rejection it is (msgpack's
own list limit, before any field is looked at). One JSON line per size and dimension on stdout
(microseconds); it imports nothing but ``fedtrack.wire``, so the same file can time another
checkout's wire (run it with that checkout's interpreter, alternating, to compare).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from functools import partial

import msgpack
import numpy as np

from fedtrack.wire import MAX_DETECTIONS, Measurement, WireError, decode, encode


def scan_payload(n: int, d: int, seed: int = 0) -> tuple[Measurement | None, bytes]:
    """A seeded scan of ``n`` detections of ``d`` coordinates and its payload; beyond
    MAX_DETECTIONS no message (it would not validate), the payload packed by hand."""
    rng = np.random.default_rng(seed)
    z, amplitude = rng.normal(scale=1e3, size=(n, d)), rng.uniform(0.0, 10.0, n)
    if n > MAX_DETECTIONS:
        head = msgpack.unpackb(encode(Measurement(sensor="s1", seq=3, t=0.3, kind="scan", z=[], R=np.eye(d))))
        head["detections"] = [{"z": {"dtype": "float64", "shape": [d], "data": row.tobytes()}, "amplitude": float(a)}
                              for row, a in zip(z, amplitude)]
        return None, msgpack.packb(head, use_bin_type=True)
    msg = Measurement(sensor="s1", seq=3, t=0.3, kind="scan", z=[], R=np.eye(d), detections=list(zip(z, amplitude)))
    return msg, encode(msg)


def best_us(call: Callable[[], object], rounds: int, budget_s: float = 0.05) -> float:
    """The best over ``rounds`` of the mean time of one call [us], each round repeating it for
    about ``budget_s``."""
    start = time.perf_counter()
    call()
    repeat = max(1, int(budget_s / max(time.perf_counter() - start, 1e-7)))
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(repeat):
            call()
        best = min(best, (time.perf_counter() - start) / repeat)
    return best * 1e6


def rejected(payload: bytes) -> None:
    try:
        decode(payload, Measurement)
    except WireError:
        return
    raise AssertionError("a payload beyond MAX_DETECTIONS was accepted")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--sizes", default="1,10,100,900,2048,5000")
    args = parser.parse_args(argv)
    for n in (int(s) for s in args.sizes.split(",")):
        for d in (2, 3):
            msg, payload = scan_payload(n, d)
            row = {"detections": n, "d": d, "bytes": len(payload)}
            if msg is None:
                row["reject_us"] = round(best_us(partial(rejected, payload), args.rounds), 1)
            else:
                row["decode_us"] = round(best_us(partial(decode, payload, Measurement), args.rounds), 1)
                row["encode_us"] = round(best_us(partial(encode, msg), args.rounds), 1)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
