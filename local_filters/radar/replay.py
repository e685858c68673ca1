"""``fedtrack replay --algorithm ekf|ekf-ie|ekf-tsfuzzy``: radar filters over recorded measurements.

Input lines: ``{"t", "sensor", "z": [r, az, el], "R": 3x3, "sensor_position": [x, y, z]}`` (the
optional ``truth`` (written by :func:`fedtrack.sensors.radar.radar_scans`), ``kind``, ``seq`` and
``stamp_ns`` are ignored; any other field is an error naming ``file:line``). Output lines, one per input line from the second on (two-point
initialization): ``{"t", "x": [x, vx, y, vy, z, vz], "P": 6x6, "model", "maneuver"}``. A line at
the time of the last one taken is left out and counted, as the radar local filter rejects it
(``input``: :class:`~fedtrack.jsonl.RepeatedTimes`).
The configuration file's ``[radar_filter]`` table holds the keys of the algorithm's config
class in :mod:`fedtrack.local_filters.radar.filters` (unknown keys are rejected).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError, in_file, load_tables
from fedtrack.deployment import max_time_jump
from fedtrack.jsonl import InputError, RepeatedTimes, output_file, read_jsonl
from fedtrack.local_filters.radar.filters import ALGORITHMS, make_radar_filter, parse_measurement


@dataclass(frozen=True)
class RadarFilterSettings:
    """The table the radar replay reads: ``[radar_filter]`` (checked by the chosen filter)."""

    radar_filter: Any = None


def replay_radar(algorithm: str, measurements: Path, config: Path | None, out: Path) -> int:
    """Run ``algorithm`` over ``measurements``; write estimates to ``out``; return their number."""
    if algorithm not in ALGORITHMS:
        raise ConfigError(f"algorithm: {algorithm!r} is not a radar filter ({', '.join(ALGORITHMS)})")
    with in_file(config):
        table = load_tables(config, RadarFilterSettings).radar_filter
        filt = make_radar_filter(algorithm, table)
    max_gap = max_time_jump(config)
    n, repeats = 0, RepeatedTimes()
    with output_file(out) as fh:  # streamed; whole or not at all
        for lineno, obj in read_jsonl(measurements):
            where = f"{measurements}:{lineno}"
            m = parse_measurement(obj, where)
            if not repeats.taken(m.sensor, m.t):
                continue
            if filt.last_t is not None and m.t - filt.last_t > max_gap:
                filt = make_radar_filter(algorithm, table)  # a pause longer than the live bound: start again
            est = filt.take(m, where)
            if est is not None:
                fh.write(json.dumps(est) + "\n")
                n += 1
        if not n:
            raise InputError(f"{measurements}: need at least two measurements to initialize the filter")
    print(repeats.line(algorithm, "measurements", "input"), file=sys.stderr)
    return n
