"""A live multi-target deployment: ``fedtrack launch deploy/multitarget.toml`` and ``fedtrack demo
--scenario multitarget``.

Before any process starts, the ``[multitarget]`` scenario is simulated into ``OUT/scenario/``
(:func:`fedtrack.sensors.multitarget.simulate`: truth and every sensor's scans). Then, as
separate processes: the router, the recorder, the centre (``serve mtt-centre``), one local
tracker per sensor (``serve mtt-local``; none for ``mtt-centralized``) and one sensor per
sensor id publishing its own scans at their own times (``serve sensor --kind scan``, realtime
pacing, ``[deployment] speed`` times real time). After the run: ``measurements.jsonl`` (the
scans in the centre's processing order) and ``tracks.jsonl`` (one picture a line) from the
recorder, ``truth.jsonl``, ``summary.json`` (GOSPA and the rest of ``fedtrack evaluate``,
latency, counters, exit codes) and ``tracks.png``.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import ConfigError, in_file
from fedtrack.jsonl import InputError
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import MultitargetSettings, Settings
from fedtrack.fusion_center.mtt.evaluation import evaluate, plot
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate

SCENARIO_DIR = "scenario"


def sensor_ids(mt: MultitargetSettings) -> list[str]:
    return [s.id for s in parse_spec(mt.sensors)]


def check_multitarget(settings: Settings, path: Path) -> None:
    """What a multi-target launch needs, checked before any process starts."""
    mt = settings.multitarget
    assert mt is not None
    with in_file(path):
        if settings.deployment.pacing != "realtime":
            raise ConfigError("deployment.pacing: a multi-target deployment paces its sensors in real time "
                              "(set pacing = \"realtime\")")
        try:
            ids = sensor_ids(mt)
        except InputError as exc:
            raise ConfigError(f"multitarget.sensors: {exc}") from None
        unknown = [s for s in ids if not settings.mtt.allows(s)]
        if unknown:
            raise ConfigError(f"mtt.sensors: does not allow the scenario's sensor {unknown[0]!r}")


def prepare(settings: Settings, out: Path) -> Path:
    """Simulate the scenario into ``out/scenario``; returns its measurements file."""
    mt = settings.multitarget
    assert mt is not None
    scenario = Scenario(targets=mt.targets, duration=mt.duration, pd=mt.pd, clutter=mt.clutter, late=0.0)
    folder = out / SCENARIO_DIR
    simulate(scenario, parse_spec(mt.sensors), settings.deployment.seed, folder)
    return folder / "measurements.jsonl"


def service_args(settings: Settings, measurements: Path) -> list[tuple[str, str, list[str]]]:
    """``(role, id, role arguments)`` of the deployment's multi-target services, in start order
    (sensors last); the caller adds ``--config`` and the Zenoh options."""
    mt = settings.multitarget
    assert mt is not None
    ids = sensor_ids(mt)
    dim = "6" if any(s.kind == "radar" for s in parse_spec(mt.sensors)) else "4"
    plan = [("mtt-centre", "centre", ["--algorithm", mt.algorithm, "--dim", dim])]
    if mt.algorithm != "mtt-centralized":
        mode = "federated" if mt.algorithm == "mtt-federated" else "decentralized"
        plan += [("mtt-local", s, ["--sensor", s, "--mode", mode]) for s in ids]
    plan += [("sensor", s, ["--kind", "scan", "--measurements", str(measurements)]) for s in ids]
    return plan


def finish_multitarget(out: Path, report: LaunchReport, title: str, delay: float = 0.0) -> dict[str, Any]:
    """Truth, summary (with GOSPA and the picture latency: from the publish of the scan that
    makes a picture due, ``delay`` = ``[mtt] picture_delay``, to its arrival at the launcher)
    and plot of a multi-target run; prints the summary."""
    truth = out / "truth.jsonl"
    shutil.copyfile(out / SCENARIO_DIR / "truth.jsonl", truth)
    tracks = out / "tracks.jsonl"
    summary: dict[str, Any] = {"pictures": 0, "exit_codes": report.exit_codes, "restarts": report.restarts,
                               "rejected": report.rejected(), "health": report.health, "wall_s": report.wall_s}
    if tracks.is_file() and tracks.stat().st_size:
        result = evaluate(tracks, truth)
        png = out / "tracks.png"
        plot(result, tracks, truth, png)
        summary.update({k: v for k, v in result.items() if k != "series"})
    latencies = report.picture_latencies_ms(delay)
    if latencies:
        summary["picture_latency_ms"] = {"p50": float(np.percentile(latencies, 50)),
                                         "p99": float(np.percentile(latencies, 99)), "pictures": len(latencies)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    mean = summary.get("mean")
    if mean:
        unit = summary["c"] ** summary["p"] / summary["alpha"]  # GOSPA^p per missed or false track
        print(f"{title}: {summary['pictures']} pictures; mean GOSPA {mean['gospa']:.1f} m (c = {summary['c']:g} m, "
              f"p = {summary['p']:g}): localisation {mean['localisation'] ** (1 / summary['p']):.1f} m, "
              f"{mean['missed'] / unit:.2f} missed targets and {mean['false'] / unit:.2f} false tracks a picture; "
              f"{summary['rejected']} messages rejected", file=sys.stderr)
    if latencies:
        lat = summary["picture_latency_ms"]
        print(f"{title}: picture latency p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms (from the publish of the "
              "scan that makes a picture due)", file=sys.stderr)
    else:
        print(f"{title}: no picture was recorded (see {out}/logs/)", file=sys.stderr)
    print(f"wrote {out}/: measurements.jsonl tracks.jsonl truth.jsonl summary.json tracks.png")
    return summary
