"""``fedtrack replay --algorithm ekf|ekf-ie|ekf-tsfuzzy``: radar filters over recorded measurements.

Input lines: ``{"t", "sensor", "z": [r, az, el], "R": 3x3, "sensor_position": [x, y, z]}`` (the
optional ``truth`` (written by :func:`fedtrack.sensors.radar.radar_scans`), ``kind``, ``seq`` and
``stamp_ns`` are ignored; any other field is an error naming ``file:line``). Output lines, one per input line from the second on (two-point
initialization): ``{"t", "x": [x, vx, y, vy, z, vz], "P": 6x6, "model", "maneuver"}``. Left out
and counted, as the radar local filter rejects them, so that a replay equals the live run: a line at
the time of the last one taken (``time_jump``: :class:`~fedtrack.jsonl.RepeatedTimes`); one that is
no measurement the wire carries (:func:`wire_carries`: a range of 1e300 m, or a noise below the
resolution of ``z``); one whose estimate comes out non-finite or with a covariance the wire refuses
(``numerical``, the filter kept as it was; the second such line in a row starts the filter again
from it: :func:`~fedtrack.local_filters.radar.filters.take_checked`).
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
from fedtrack.jsonl import InputError, NumericalRefusals, RepeatedTimes, output_file, read_jsonl
from fedtrack.local_filters.radar.filters import (
    ALGORITHMS,
    Measurement,
    make_radar_filter,
    parse_measurement,
    take_checked,
)
from fedtrack.services.rejections import Numerical
from fedtrack.wire import Measurement as WireMeasurement
from fedtrack.wire import WireError


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
        filt = make_radar_filter(algorithm, table, None if config is None else config.parent)
    max_gap = max_time_jump(config)
    n, repeats, numerical, off_wire, failed = 0, RepeatedTimes(), NumericalRefusals(), 0, False
    with output_file(out) as fh:  # streamed; whole or not at all
        for lineno, obj in read_jsonl(measurements):
            where = f"{measurements}:{lineno}"
            m = parse_measurement(obj, where)
            if not repeats.taken(m.sensor, m.t):
                continue
            taking = filt
            if filt.last_t is not None and m.t - filt.last_t > max_gap:
                taking = filt.afresh()  # a pause longer than the live bound: start again
            est, refused = None, not wire_carries(m)
            if refused:  # never reaches the live filter: failed stays as it was
                off_wire += 1
            else:
                try:
                    filt, est = take_checked(taking, m, failed, where)
                    failed = False
                except Numerical:
                    numerical.left_out += 1
                    failed = refused = True
            if refused:
                repeats.refused(m.sensor, filt.last_t)
            elif est is not None:
                fh.write(json.dumps(est) + "\n")
                n += 1
        if not n:
            raise InputError(f"{measurements}: need at least two measurements to initialize the filter")
    print(repeats.line(algorithm, "measurements", "time_jump"), file=sys.stderr)
    if off_wire:
        print(f"{algorithm}: {off_wire} measurements the wire does not carry, left out (live: rejected)",
              file=sys.stderr)
    if numerical.left_out:
        print(numerical.line(algorithm, "measurements"), file=sys.stderr)
    return n


def wire_carries(m: Measurement) -> bool:
    """Whether the wire carries ``m`` as a radar measurement (the wire's own check of a measurement: one
    it refuses never reaches the live filter, its receiver rejects it, ``rejected``)."""
    try:
        WireMeasurement(sensor=m.sensor, seq=0, t=m.t, kind="radar", z=m.z, R=m.R, sensor_position=m.sensor_position,
                        stamp_ns=0)
    except WireError:
        return False
    return True
