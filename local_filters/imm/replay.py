"""``fedtrack replay --algorithm fsimm|vsimm|ao-vsimm``: an IMM estimator over one sensor's
recorded measurements (JSON Lines).

Input lines: ``{"t": float, "sensor": str, "z": [x, y], "R": [[..], [..]]}``; every line
is validated (finite numbers, shapes, symmetric positive-definite ``R``, non-decreasing
``t``, a single sensor) as it is read and errors name ``file:line``; the output is streamed to a
temporary file renamed at the end, so a bad line leaves none. A line at the time of the last one
taken is left out and counted, as ``serve imm`` rejects it (``time_jump``:
:class:`~fedtrack.jsonl.RepeatedTimes`).
Output lines: ``t``, ``sensor``, ``x`` (``[x, vx, y, vy]``), ``P``, ``acceleration``
(``sum mu_i a_i``), ``mode_probabilities`` (model name -> probability, 0 for models not
running) and ``active_group`` (``all`` for FSIMM, ``M2``, or ``M2+M1`` for a VSIMM union).

Time steps and the prior: see :mod:`fedtrack.local_filters.imm.tracker`.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fedtrack.deployment import max_time_jump
from fedtrack.jsonl import InputError, NumericalRefusals, RepeatedTimes, output_file, position_line, read_jsonl
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.filter import ALGORITHMS
from fedtrack.local_filters.imm.tracker import IMMTracker, TrackPoint
from fedtrack.services.rejections import NUMERICAL_ERRORS, Numerical, require_covariances, require_finite


class Measurement(NamedTuple):
    t: float
    sensor: str
    z: np.ndarray
    R: np.ndarray


def read_measurements(path: Path) -> Iterator[Measurement]:
    """The measurements of ``path``, validated as they are read; :class:`InputError` names ``file:line``."""
    first: Measurement | None = None
    last_t = -np.inf
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        t, sensor, z, R = position_line(obj, where)
        if t < last_t:
            raise InputError(f"{where}: t = {t} is earlier than the previous line's t = {last_t}")
        if first is not None and sensor != first.sensor:
            raise InputError(f"{where}: sensor {sensor!r} differs from {first.sensor!r}; "
                             "the IMM replay takes a single sensor's measurements")
        m = Measurement(t, sensor, z, R)
        if first is None:
            first = m
        last_t = t
        yield m
    if first is None:
        raise InputError(f"{path}: no measurements")


def replay_imm(algorithm: str, measurements: Path, config: Path | None, out: Path) -> int:
    """Run ``algorithm`` over ``measurements`` and write one estimate per line to ``out``."""
    if algorithm not in ALGORITHMS:
        raise InputError(f"unknown IMM algorithm {algorithm!r} (expected one of {', '.join(ALGORITHMS)})")
    cfg, max_gap = load_imm_config(config), max_time_jump(config)
    tracker = IMMTracker(cfg, algorithm)
    n, repeats, numerical = 0, RepeatedTimes(), NumericalRefusals()
    with output_file(out) as fh:  # streamed; whole or not at all
        for m in read_measurements(measurements):
            if not repeats.taken(m.sensor, m.t):
                continue
            kept = tracker, tracker.state, tracker.t
            if tracker.t is not None and m.t - tracker.t > max_gap:  # a pause longer than the live
                tracker = IMMTracker(cfg, algorithm)  # services accept: start again
            point = _checked(tracker, m)
            if point is None:  # as serve imm: rejected_numerical, the tracker as it was
                tracker, tracker.state, tracker.t = kept
                repeats.refused(m.sensor, kept[2])
                numerical.left_out += 1
                continue
            fh.write(json.dumps({"sensor": m.sensor, **point.as_dict()}) + "\n")
            n += 1
    print(repeats.line(algorithm, "measurements", "time_jump"), file=sys.stderr)
    if numerical.left_out:
        print(numerical.line(algorithm, "measurements"), file=sys.stderr)
    return n


def _checked(tracker: IMMTracker, m: Measurement) -> TrackPoint | None:
    """The tracker's estimate after ``m``, or None where ``serve imm`` would reject it as numerical
    (a non-finite or unacceptable estimate: a position of 1e200 m overflows the likelihoods)."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # checked below
            p = tracker.update(m.t, m.z, m.R)
        require_finite("the IMM estimate", p.x, p.P, list(p.mode_probabilities.values()))
        require_covariances("the IMM estimate", p.P)
    except (Numerical, *NUMERICAL_ERRORS):
        return None
    return p
