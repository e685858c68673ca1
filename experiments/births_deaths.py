"""Births and deaths throughout (the linger session): how long a dead target's track stays in the pictures.

``write OUT [--seed S]``: the simulator's default sensors and scenario (P_D 0.9, clutter 10, late 0.2) on a
truth of ``TARGETS`` targets born uniformly over the first ``BIRTHS_S`` seconds of ``DURATION_S``, each living
``LIFE_S`` (uniform), its trajectory started at its birth: ``OUT/measurements.jsonl``, ``truth.jsonl``,
``config.toml`` (as ``simulate multitarget`` writes them) and ``deaths.json`` (each target's death time).
``delay TRACKS OUT``: per target that died at least ``TAIL_S`` before the end, the time from its death to the
last picture holding the confirmed track nearest it (within ``C`` m) in its last picture; prints their mean,
standard error and count. Usage: ``python -m fedtrack.experiments.births_deaths write /tmp/bd`` then
``replay`` with its ``config.toml`` and ``... delay tracks.jsonl /tmp/bd``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from fedtrack.sensors.multitarget import DT, Scenario, parse_spec, simulate, simulate_truth

TARGETS, DURATION_S, BIRTHS_S, LIFE_S = 200, 600.0, 540.0, (30.0, 150.0)
TAIL_S = 15.0  # s: deaths this close to the end are left out (their tracks' end unseen)
C = 100.0  # m: GOSPA's cut-off, the farthest a track counts as the target's


def write(out: Path, seed: int) -> None:
    """The scenario into ``out`` (created)."""
    sc = Scenario(targets=TARGETS, duration=DURATION_S)
    rng = np.random.default_rng(1000 + seed)
    x, _ = simulate_truth(sc, False, rng)
    born = rng.uniform(0.0, BIRTHS_S, TARGETS)
    dies = born + rng.uniform(*LIFE_S, TARGETS)
    shifted = np.zeros_like(x)
    for i, b in enumerate(np.round(born / DT).astype(int)):
        shifted[b:, i] = x[: x.shape[0] - b, i]
    t = np.arange(x.shape[0]) * DT
    alive = (t[:, None] >= born[None]) & (t[:, None] <= dies[None])
    simulate(sc, parse_spec("pos:1.0,pos:0.7,pos:1.3"), seed, out, truth=(shifted, alive))
    (out / "deaths.json").write_text(json.dumps({"dies": dies.tolist()}))


def delays(tracks: Path, out: Path) -> np.ndarray:
    """Per dead target, the seconds from its death to its nearest confirmed track's last picture."""
    seen: dict[int, float] = {}
    pictures = {}
    for line in tracks.read_text().splitlines():
        p = json.loads(line)
        pictures[round(p["t"], 6)] = [tr for tr in p["tracks"] if tr["status"] == "confirmed"]
        for tr in pictures[round(p["t"], 6)]:
            seen[tr["id"]] = max(seen.get(tr["id"], p["t"]), p["t"])
    last: dict[int, tuple[float, list[float]]] = {}
    truth = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    for line in truth:
        for target in line["targets"]:
            last[target["id"]] = (line["t"], target["x"])
    dies = json.loads((out / "deaths.json").read_text())["dies"]
    result = []
    for tid, (t, x) in last.items():
        shown = pictures.get(round(t, 6), [])
        if t >= truth[-1]["t"] - TAIL_S or not shown:
            continue
        d = [np.hypot(tr["x"][0] - x[0], tr["x"][2] - x[2]) for tr in shown]
        if min(d) <= C:
            result.append(seen[shown[int(np.argmin(d))]["id"]] - dies[tid])
    return np.array(result)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m fedtrack.experiments.births_deaths")
    sub = parser.add_subparsers(dest="command", required=True)
    w = sub.add_parser("write")
    w.add_argument("out", type=Path)
    w.add_argument("--seed", type=int, default=1)
    d = sub.add_parser("delay")
    d.add_argument("tracks", type=Path)
    d.add_argument("out", type=Path)
    args = parser.parse_args()
    if args.command == "write":
        write(args.out, args.seed)
        return
    a = delays(args.tracks, args.out)
    print(f"mean delay {a.mean():.3f} s (se {a.std(ddof=1) / np.sqrt(a.size):.3f}), {a.size} deaths")


if __name__ == "__main__":
    main()
