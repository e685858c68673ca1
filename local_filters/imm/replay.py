"""``fedtrack replay --algorithm fsimm|vsimm|ao-vsimm``: an IMM estimator over one sensor's
recorded measurements (JSON Lines).

Input lines: ``{"t": float, "sensor": str, "z": [x, y], "R": [[..], [..]]}``; every line
is validated (finite numbers, shapes, symmetric positive-definite ``R``, non-decreasing
``t``, a single sensor) before any estimate is written, and errors name ``file:line``.
Output lines: ``t``, ``sensor``, ``x`` (``[x, vx, y, vy]``), ``P``, ``acceleration``
(``sum mu_i a_i``), ``mode_probabilities`` (model name -> probability, 0 for models not
running) and ``active_group`` (``all`` for FSIMM, ``M2``, or ``M2+M1`` for a VSIMM union).

Time steps and the prior: see :mod:`fedtrack.local_filters.imm.tracker`.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from fedtrack.jsonl import InputError, position_line, read_jsonl, write_jsonl
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.filter import ALGORITHMS
from fedtrack.local_filters.imm.tracker import IMMTracker


class Measurement(NamedTuple):
    t: float
    sensor: str
    z: np.ndarray
    R: np.ndarray


def read_measurements(path: Path) -> list[Measurement]:
    """All measurements of ``path``, validated; :class:`InputError` names ``file:line``."""
    out: list[Measurement] = []
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        t, sensor, z, R = position_line(obj, where)
        if out and t < out[-1].t:
            raise InputError(f"{where}: t = {t} is earlier than the previous line's t = {out[-1].t}")
        if out and sensor != out[0].sensor:
            raise InputError(f"{where}: sensor {sensor!r} differs from {out[0].sensor!r}; "
                             "the IMM replay takes a single sensor's measurements")
        out.append(Measurement(t, sensor, z, R))
    if not out:
        raise InputError(f"{path}: no measurements")
    return out


def replay_imm(algorithm: str, measurements: Path, config: Path | None, out: Path) -> int:
    """Run ``algorithm`` over ``measurements`` and write one estimate per line to ``out``."""
    if algorithm not in ALGORITHMS:
        raise InputError(f"unknown IMM algorithm {algorithm!r} (expected one of {', '.join(ALGORITHMS)})")
    tracker = IMMTracker(load_imm_config(config), algorithm)
    rows = [{"sensor": m.sensor, **tracker.update(m.t, m.z, m.R).as_dict()}
            for m in read_measurements(measurements)]
    write_jsonl(out, rows)
    return len(rows)
