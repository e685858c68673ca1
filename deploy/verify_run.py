"""Check a recorded deployment: every scan fused, finite, and equal to the offline replay.

``python -m fedtrack.deploy.verify_run --config CONFIG.toml --run DIR`` reads ``DIR/tracks.jsonl``
and ``DIR/measurements.jsonl`` (written by the recorder), replays the measurements with
the deployment's algorithm (``fvdie`` for federated, ``dvdie`` for decentralized) and
prints a JSON verdict. Exit code 0 when the run is complete and matches the replay,
1 when it does not, 2 for a missing or unreadable file or a bad config.

With ``[multitarget]`` in the config (a live multi-target deployment) the replay is ``fedtrack
replay --algorithm <[multitarget] algorithm>``, with ``--regions config`` when the config has
``[regions]``, and the verdict compares every picture: the same times, ids, statuses and
sensors, states and covariances to ``TOLERANCE`` (relative, as above: :func:`scaled_diff`). ``--algorithm mtt-*``
does the same for a config without ``[multitarget]`` (the services started by hand, ``serve mtt-centre --algorithm``);
a run of pictures checked without either is refused in one line saying so (before the tour58 session the
paper replay read the scans and said ``unknown field 'detections'``).

The replay's own lines (its counters, stage timings, notes) are held back and written to stderr only when
the verdict is not ok or the check fails, where they help explain it: a run that agrees prints the verdict
alone (before the tour59 session they went to stderr every time, noise in ``netns-demo.sh``'s output).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
from contextlib import redirect_stderr
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import ConfigError
from fedtrack.deploy.report import REPLAY_ALGORITHM
from fedtrack.deploy.settings import MTT_ALGORITHMS, load_settings
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.replay import replay_fusion
from fedtrack.jsonl import InputError, read_jsonl
from fedtrack.local_filters.regions import load_regions
from fedtrack.sensors.scenarios import deployment_scenario

TOLERANCE = 1e-9


@dataclass(frozen=True)
class RunCheck:
    """What :func:`verify_run` found."""

    scans: int
    scans_expected: int
    measurements: int
    measurements_expected: int
    degraded: int
    finite: bool
    max_replay_diff: float

    @property
    def ok(self) -> bool:
        return (self.scans == self.scans_expected and self.measurements == self.measurements_expected
                and self.degraded == 0 and self.finite and self.max_replay_diff <= TOLERANCE)

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "tolerance": TOLERANCE, "ok": self.ok}


def _rows(path: Path) -> list[dict[str, Any]]:
    return [obj for _, obj in read_jsonl(path)]


def scaled_diff(a: list[Any], b: list[Any]) -> float:
    """``max |a - b| / max(1, max |b|)``: the largest difference relative to the largest entry of ``b`` (one
    state or covariance), inf on a shape mismatch. Round-off in a filter's arithmetic is mixed across the
    entries by ``F``, ``K`` and the fusion, so each entry's error scales with the largest one, not its own:
    before the tour60 session each entry was scaled by itself, and a correct run failed on an acceleration
    below 1 m/s² that differed by 1.5e-9 in a state of entries up to 1e5 (``demo --scenario 2 --sensors 1
    --mode decentralized --seed 5``: 1.5e-14 of that state's scale)."""
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if x.shape != y.shape:
        return float("inf")
    return float(np.max(np.abs(x - y), initial=0.0) / max(1.0, float(np.max(np.abs(y), initial=0.0))))


def verify_run(config: Path, run_dir: Path) -> RunCheck:
    """Compare ``run_dir/tracks.jsonl`` with the replay of ``run_dir/measurements.jsonl``."""
    settings = load_settings(config)
    n_sensors = len(settings.fusion.sensors or settings.sensor)
    expected = len(deployment_scenario(settings.deployment.scenario, settings.deployment.duration_s).times)
    tracks = _rows(run_dir / "tracks.jsonl")
    measurements = _rows(run_dir / "measurements.jsonl")
    with tempfile.TemporaryDirectory() as tmp:
        replay_path = Path(tmp) / "replay.jsonl"
        replay_fusion(REPLAY_ALGORITHM[settings.deployment.mode], run_dir / "measurements.jsonl", config,
                      replay_path)
        replay = _rows(replay_path)
    diff = float("inf") if len(replay) != len(tracks) else max(
        (max(abs(tr["t"] - rp["t"]), scaled_diff(tr["x"], rp["x"]), scaled_diff(tr["P"], rp["P"]),
             0.0 if tr["model"] == rp["model"] else float("inf"))
         for tr, rp in zip(tracks, replay)), default=float("inf"))
    finite = all(np.all(np.isfinite(np.asarray(tr["x"], dtype=float)))
                 and np.all(np.isfinite(np.asarray(tr["P"], dtype=float))) for tr in tracks)
    return RunCheck(scans=len(tracks), scans_expected=expected, measurements=len(measurements),
                    measurements_expected=expected * n_sensors,
                    degraded=sum(bool(tr.get("degraded")) for tr in tracks), finite=finite, max_replay_diff=diff)


@dataclass(frozen=True)
class PictureCheck:
    """What :func:`verify_mtt_run` found: the live pictures against the replay's."""

    pictures: int
    replayed: int
    regions: int  # 0: one centre
    same_tracks: bool  # every picture's ids, statuses and sensors equal the replay's
    confirmed: int  # confirmed tracks in all pictures
    finite: bool
    max_replay_diff: float

    @property
    def ok(self) -> bool:
        return (self.pictures > 0 and self.pictures == self.replayed and self.same_tracks and self.finite
                and self.max_replay_diff <= TOLERANCE)

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "tolerance": TOLERANCE, "ok": self.ok}


def _pictures(tracks: Path) -> bool:
    """Whether ``tracks`` (a run's ``tracks.jsonl``) holds multi-target pictures: its first line has ``tracks``."""
    for _, obj in read_jsonl(tracks):
        return "tracks" in obj
    return False


def verify_mtt_run(config: Path, run_dir: Path, algorithm: str) -> PictureCheck:
    """Compare a multi-target run's ``tracks.jsonl`` with the replay by ``algorithm`` of its ``measurements.jsonl``."""
    regions = load_regions(config)
    live = _rows(run_dir / "tracks.jsonl")
    with tempfile.TemporaryDirectory() as tmp:
        replay_path = Path(tmp) / "replay.jsonl"
        replay_mtt(algorithm, run_dir / "measurements.jsonl", config, replay_path,
                   regions=None if regions is None else "config")
        replay = _rows(replay_path)

    def shape(picture: dict[str, Any]) -> list[tuple[Any, ...]]:
        return [(tr["id"], tr["status"], tr["sensors"]) for tr in picture["tracks"]]
    same = len(live) == len(replay) and all(a["t"] == b["t"] and shape(a) == shape(b) for a, b in zip(live, replay))
    diff = float("inf") if not same else max(
        (max(scaled_diff(ta["x"], tb["x"]), scaled_diff(ta["P"], tb["P"]))
         for a, b in zip(live, replay) for ta, tb in zip(a["tracks"], b["tracks"])), default=0.0)
    finite = all(np.all(np.isfinite(np.asarray(tr["x"], dtype=float))) for p in live for tr in p["tracks"])
    return PictureCheck(pictures=len(live), replayed=len(replay), regions=0 if regions is None else len(regions.ids),
                        same_tracks=same, finite=finite, max_replay_diff=diff,
                        confirmed=sum(tr["status"] == "confirmed" for p in live for tr in p["tracks"]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fedtrack.deploy.verify_run", description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, type=Path, help="the deployment TOML of the fusion host")
    parser.add_argument("--run", required=True, type=Path, help="the recorder's output directory")
    parser.add_argument("--algorithm", choices=MTT_ALGORITHMS, help="a multi-target run's centre algorithm (default: "
                        "[multitarget] algorithm of --config; a paper deployment's run: none)")
    args = parser.parse_args(argv)
    if not args.run.is_dir():  # not the first file looked for in it
        print(f"verify_run: error: --run {args.run}: no such folder (the output folder of the launch, its --out "
              "or [deployment] out)", file=sys.stderr)
        return 2
    replay_lines = io.StringIO()
    try:
        mt = load_settings(args.config).multitarget
        algorithm = args.algorithm or (None if mt is None else mt.algorithm)
        if algorithm is None and _pictures(args.run / "tracks.jsonl"):
            raise ConfigError(f"{args.run / 'tracks.jsonl'}: multi-target pictures, but {args.config} has no "
                              "[multitarget] table naming the centre's algorithm: give --algorithm (mtt-federated, "
                              "mtt-decentralized or mtt-centralized)")
        with redirect_stderr(replay_lines):
            check: RunCheck | PictureCheck = (verify_mtt_run(args.config, args.run, algorithm)
                                              if algorithm is not None else verify_run(args.config, args.run))
    except (OSError, ConfigError, InputError) as exc:
        print(replay_lines.getvalue() + f"verify_run: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(check.as_dict()))
    if not check.ok:
        print(replay_lines.getvalue(), end="", file=sys.stderr)
    return 0 if check.ok else 1


if __name__ == "__main__":
    sys.exit(main())
