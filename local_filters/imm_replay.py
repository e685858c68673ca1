"""``fedtrack replay --algorithm fsimm|vsimm|ao-vsimm``: an IMM estimator over one sensor's
recorded measurements (JSON Lines).

Input lines: ``{"t": float, "sensor": str, "z": [x, y], "R": [[..], [..]]}``; every line
is validated (finite numbers, shapes, symmetric positive-definite ``R``, non-decreasing
``t``, a single sensor) before any estimate is written, and errors name ``file:line``.
Output lines: ``t``, ``sensor``, ``x`` (``[x, vx, y, vy]``), ``P``, ``acceleration``
(``sum mu_i a_i``), ``mode_probabilities`` (model name -> probability, 0 for models not
running) and ``active_group`` (``all`` for FSIMM, ``M2``, or ``M2+M1`` for a VSIMM union).

Time steps: the motion model uses the actual ``dt`` between measurements; the transition
matrix is applied once per measurement (it is per step in paper 000, T = 1 s). The prior
is taken to hold at the first measurement's time, so the first line is a measurement
update only (``dt = 0``: ``F = I``, no process noise, no acceleration, no mode switch);
the same holds for later lines with a repeated timestamp.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.jsonl import InputError, as_covariance, as_float, as_vector, read_jsonl, require, write_jsonl
from local_filters.imm import ALGORITHMS, group_label, initial_state, step
from local_filters.imm_config import IMMConfig, load_imm_config
from local_filters.models import cv_model


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
        t = as_float(require(obj, "t", where), "t", where)
        sensor = require(obj, "sensor", where)
        if not isinstance(sensor, str) or not sensor:
            raise InputError(f"{where}: sensor must be a non-empty string, got {sensor!r}")
        z = as_vector(require(obj, "z", where), "z", where, size=2)
        R = as_covariance(require(obj, "R", where), "R", where, size=2)
        if out and t < out[-1].t:
            raise InputError(f"{where}: t = {t} is earlier than the previous line's t = {out[-1].t}")
        if out and sensor != out[0].sensor:
            raise InputError(f"{where}: sensor {sensor!r} differs from {out[0].sensor!r}; "
                             "the IMM replay takes a single sensor's measurements")
        out.append(Measurement(t, sensor, z, R))
    if not out:
        raise InputError(f"{path}: no measurements")
    return out


def prior(cfg: IMMConfig, first: Measurement) -> tuple[np.ndarray, np.ndarray]:
    """``x0``, ``P0`` from the config, or centred on the first measurement at rest."""
    sp, sv = cfg.initial_position_std, cfg.initial_velocity_std
    P0 = np.array(cfg.P0) if cfg.P0 is not None else np.diag([sp * sp, sv * sv, sp * sp, sv * sv])
    x0 = np.array(cfg.x0) if cfg.x0 is not None else np.array([first.z[0], 0.0, first.z[1], 0.0])
    return x0, P0


def replay_imm(algorithm: str, measurements: Path, config: Path | None, out: Path) -> int:
    """Run ``algorithm`` over ``measurements`` and write one estimate per line to ``out``."""
    if algorithm not in ALGORITHMS:
        raise InputError(f"unknown IMM algorithm {algorithm!r} (expected one of {', '.join(ALGORITHMS)})")
    cfg = load_imm_config(config)
    data = read_measurements(measurements)
    bank, th = cfg.bank(), cfg.thresholds()
    x0, P0 = prior(cfg, data[0])
    state = initial_state(bank, algorithm, cfg.initial_group_index(), x0[None], P0[None])
    rows: list[dict[str, Any]] = []
    t_prev = data[0].t
    for m in data:
        dt = m.t - t_prev
        Pi = bank.Pi if dt > 0 else np.eye(bank.size)
        state, o = step(bank, algorithm, state, cv_model(dt, cfg.q), m.z[None], m.R, th, Pi)
        rows.append({"t": m.t, "sensor": m.sensor, "x": o.est.x[0].tolist(), "P": o.est.P[0].tolist(),
                     "acceleration": o.acc[0].tolist(),
                     "mode_probabilities": dict(zip(bank.names, o.mu[0].tolist())),
                     "active_group": group_label(bank, int(o.old[0]), int(o.new[0]))})
        t_prev = m.t
    write_jsonl(out, rows)
    return len(rows)
