"""Hand-overs at region borders (issue 27, the hand-over storm): targets standing on and flying along
the borders of a 2 x 2 grid, and ``bench scale``'s scenario, replayed by ``mtt-federated``.

Per run: the hand-overs per confirmed track per minute, the duplicates per picture (confirmed tracks
GOSPA leaves unassigned within ``c / 2`` of a truth: a second track on a target), mean GOSPA
(c = 100 m, p = 2). Usage: ``python -m fedtrack.experiments.handover_border [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import load_tables
from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
from fedtrack.fusion_center.mtt.evaluation import evaluate, set_distance
from fedtrack.fusion_center.mtt.replay import data_regions, pictures, read_scans, state_dim
from fedtrack.jsonl import output_file
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.local_filters.regions import Regions, grid_regions
from fedtrack.sensors.multitarget import DT, Scenario, parse_spec, simulate

C = 100.0  # GOSPA cut-off [m]
MARGIN_M = 500.0  # as bench scale


def border_truth(sc: Scenario, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``sc.targets`` targets on the borders x = 0 and y = 0 of a 2 x 2 grid centred on the origin:
    a quarter standing on them, the rest flying along them at 8-30 m/s, either way."""
    steps, n = round(sc.duration / DT) + 1, sc.targets
    along_x = np.arange(n) % 2 == 0  # flying (or standing) on y = 0, else on x = 0
    speed = np.where(np.arange(n) < n // 4, 0.0, rng.uniform(8.0, 30.0, n) * rng.choice([-1, 1], n))
    start = rng.uniform(-0.6, 0.6, n) * sc.region
    t = np.arange(steps)[:, None] * DT
    s = start + speed * t  # (steps, n) along the border
    x = np.zeros((steps, n, 6))
    x[..., 0], x[..., 2] = np.where(along_x, s, 0.0), np.where(along_x, 0.0, s)
    x[..., 1], x[..., 3] = np.where(along_x, speed, 0.0), np.where(along_x, 0.0, speed)
    return x, np.ones((steps, n), dtype=bool)


def measure(sim: Path, regions: Regions | None, spec: str) -> dict[str, Any]:
    """Replay ``sim`` sharded by ``regions`` (None: the grid ``spec`` over the data); the counts."""
    cfg = load_tables(sim / "config.toml", MttSettings).mtt
    scans = read_scans(sim / "measurements.jsonl", cfg)
    if regions is None:
        (sim / "regions.toml").write_text((sim / "config.toml").read_text() + f"\n[regions]\nmargin = {MARGIN_M}\n"
                                          + "grid = {origin = [0, 0], cell = [1, 1], nx = 1, ny = 1}\n")
        regions = data_regions(spec, scans, sim / "regions.toml")
    engine = TrackToTrackEngine(cfg, state_dim(scans), feedback=True, regions=regions)
    path = sim / f"{spec}.jsonl"
    with output_file(path) as fh:
        for T, tracks in pictures(engine, scans, cfg.period, cfg.picture_delay):
            fh.write(tracks.line(T, {"algorithm": "mtt-federated"}) + "\n")
    truth = {round(line["t"], 6): np.array([g["x"][0:3:2] for g in line["targets"]]).reshape(-1, 2)
             for line in map(json.loads, (sim / "truth.jsonl").read_text().splitlines())}
    track_s, duplicates, scored = 0.0, 0, 0
    for line in map(json.loads, path.read_text().splitlines()):
        shown = np.array([tr["x"][0:3:2] for tr in line["tracks"] if tr.get("status", "confirmed") == "confirmed"])
        track_s += len(shown) * cfg.period
        X = truth.get(round(line["t"], 6))
        if X is None or not len(shown) or not len(X):
            continue
        scored += 1
        paired = {j for _, j in set_distance(X, shown, C, 2.0).pairs}
        near = np.min(np.linalg.norm(shown[:, None] - X[None], axis=-1), axis=1) < C / 2
        duplicates += sum(1 for j in np.flatnonzero(near).tolist() if j not in paired)
    centre = engine.centre
    return {"regions": len(regions.ids), "hand_overs": centre.handed_over,
            "hand_overs_per_track_min": centre.handed_over / max(track_s / 60.0, 1e-9),
            "in_flight": centre.counters()["in_flight"], "duplicates_per_picture": duplicates / max(scored, 1),
            "gospa": evaluate(path, sim / "truth.jsonl")["mean"]["gospa"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    args = parser.parse_args()
    duration = 60.0 if args.quick else 300.0
    sensors = parse_spec("pos:1.0,pos:1.0,pos:1.0,pos:1.0")
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "border"
        sc = Scenario(targets=40, duration=duration)
        simulate(sc, sensors, 3, sim, truth=border_truth(sc, np.random.default_rng(3)))
        half = sc.region
        out["border"] = measure(sim, grid_regions((-half, -half), (half, half), 2, 2, MARGIN_M), "border")
        sim = Path(tmp) / "scale"
        simulate(Scenario(targets=50, duration=duration), sensors, 2, sim)
        out["scale_2x2"] = measure(sim, None, "2x2")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
