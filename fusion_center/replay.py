"""``fedtrack replay`` for the fusion algorithms (kf, federated-kf, decentralized-kf, fvdie, dvdie).

Input: JSON Lines, one position measurement per line,
``{"t": float, "sensor": str, "z": [x, y], "R": [[..], [..]]}``; lines with the same ``t``
form one scan (they must be consecutive and ``t`` must never decrease); a second line of a sensor
in a scan is left out and counted, as its local filter refuses it
(:class:`~fedtrack.jsonl.RepeatedTimes`). Output: one line per scan,
``{"t", "x", "P", "model", "maneuver", "sensors", "degraded", "event"}``.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.config import ConfigError, in_file, load_tables
from fedtrack.fusion_center.trackers import ModelEstimate, make_tracker
from fedtrack.jsonl import InputError, RepeatedTimes, output_file, position_line, read_jsonl
from fedtrack.local_filters.linear.models import CA
from fedtrack.local_filters.vdie.config import PipelineSettings


class Scan(NamedTuple):
    """All measurements that share one timestamp."""

    t: float
    z: dict[str, np.ndarray]
    R: dict[str, np.ndarray]


def read_scans(path: Path, repeats: RepeatedTimes | None = None) -> Iterator[Scan]:
    """Parse and validate a measurements file into scans as it is read (errors name ``file:line``); a
    sensor's second line in a scan is left out, counted in ``repeats``."""
    repeats = RepeatedTimes() if repeats is None else repeats
    scan: Scan | None = None
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        t, sensor, z, R = position_line(obj, where)
        if scan is not None and t < scan.t:
            raise InputError(f"{where}: timestamp {t} goes backwards (previous scan at {scan.t})")
        if scan is None or t > scan.t:
            if scan is not None:
                yield scan
            scan = Scan(t, {}, {})
        if repeats.taken(sensor, t):
            scan.z[sensor] = z
            scan.R[sensor] = R
    if scan is None:
        raise InputError(f"{path}: no measurements")
    yield scan


def sensors_seen(scans: Iterable[Scan]) -> list[str]:
    """The sensors of ``scans`` in the order of their first appearance."""
    seen: list[str] = []
    for scan in scans:
        seen.extend(s for s in scan.z if s not in seen)
    return seen


def sensor_order(seen: list[str], configured: tuple[str, ...] | None) -> list[str]:
    """The configured sensor order (which must list every sensor ``seen``), or ``seen``."""
    if configured is None:
        return seen
    unknown = [s for s in seen if s not in configured]
    if unknown:
        raise ConfigError(f"fusion.sensors: does not list sensor {unknown[0]!r} of the measurements")
    return list(configured)


def estimate_record(t: float, est: ModelEstimate, sensors: list[str], n_sensors: int,
                    extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """One output line; ``x``/``P`` in the model's own state order (CV 4-D or CA 6-D)."""
    rec = {
        "t": t,
        "x": est.x.tolist(),
        "P": est.P.tolist(),
        "model": est.model,
        "maneuver": est.model == CA,
        "sensors": sensors,
        "degraded": len(sensors) < n_sensors,
        "event": est.event,
    }
    if extra:
        rec.update(extra)
    return rec


def replay_scans(algorithm: str, scans: Iterable[Scan], sensors: list[str], config: Any,
                 max_gap: float = np.inf) -> Iterator[dict[str, Any]]:
    """Run ``algorithm`` scan by scan; yields output records. After a gap longer than ``max_gap``
    seconds the tracker starts again (:func:`fedtrack.deployment.max_time_jump`)."""
    tracker = make_tracker(algorithm, len(sensors), config)
    Rs_last = {s: np.eye(2) for s in sensors}
    last_t = np.inf
    for scan in scans:
        if scan.t - last_t > max_gap:
            tracker = make_tracker(algorithm, len(sensors), config)
        last_t = scan.t
        present = np.array([s in scan.z for s in sensors])
        zs = np.array([scan.z.get(s, np.zeros(2)) for s in sensors])
        Rs_last.update(scan.R)
        Rs = np.array([Rs_last[s] for s in sensors])
        est = tracker.step(scan.t, zs, Rs, present)
        yield estimate_record(scan.t, est, [s for s in sensors if s in scan.z], len(sensors))


def replay_fusion(algorithm: str, measurements: Path, config: Path | None, out: Path) -> int:
    """Entry point of ``fedtrack replay --algorithm kf|federated-kf|decentralized-kf|fvdie|dvdie``."""
    settings = load_tables(config, PipelineSettings)
    # two passes, so that memory does not grow with the file: the first validates every line
    # and finds the sensors (their number sets the sharing factors from the first scan on)
    seen = sensors_seen(read_scans(measurements))
    with in_file(config):
        sensors = sensor_order(seen, settings.fusion.sensors)
        settings.fusion.betas(len(sensors))  # fails early if the sharing factors do not fit
    n, repeats = 0, RepeatedTimes()
    with output_file(out) as fh:
        for rec in replay_scans(algorithm, read_scans(measurements, repeats), sensors, settings.fusion,
                                settings.deployment.max_time_jump_s):
            fh.write(json.dumps(rec) + "\n")
            n += 1
    print(repeats.line(algorithm, "measurements", "time_jump"), file=sys.stderr)
    return n
