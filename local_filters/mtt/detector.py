"""Maneuver events on the tracks of a 3-D tracker (``[mtt] maneuver = "vdie"``).

Paper 004's VDIE switches a 2-D track between CV and CA (:mod:`.maneuver`); a 3-D track (a
radar's, or ``mtt-centralized`` over a mixed sensor set) stays CV, and runs instead the input
estimator of :mod:`fedtrack.local_filters.vdie.input_bank` on its own (linearized) innovations,
the detector the central tracks of the track-to-track centre run: each track reports a
detected horizontal maneuver (onset, acceleration, statistic) without any change to its
estimate. A track's bank steps at each detection the track takes, over the interval since its
last one (a missed scan is only a longer interval: the bias of a constant input composes
exactly over the CV predictions it spans).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.local_filters.vdie.input_bank import InputBank, InputDetection, input_step, new_banks, no_detection


class TrackInputs(NamedTuple):
    """Per track: the input estimators' bank, the time of its last step, the detection after it."""

    bank: InputBank
    t: np.ndarray  # (N,)
    detection: InputDetection


def start(n: int, dim: int, t: float, params: VdieParams) -> TrackInputs:
    """The detectors of ``n`` tracks started at ``t``."""
    return TrackInputs(new_banks(n, params.window, dim, t), np.full(n, t), no_detection(n))


def take(inputs: TrackInputs, idx: np.ndarray) -> TrackInputs:
    return TrackInputs(InputBank(*(a[idx] for a in inputs.bank)), inputs.t[idx],
                       InputDetection(*(a[idx] for a in inputs.detection)))


def concat(a: TrackInputs, b: TrackInputs) -> TrackInputs:
    return TrackInputs(InputBank(*(np.concatenate([u, v]) for u, v in zip(a.bank, b.bank))),
                       np.concatenate([a.t, b.t]),
                       InputDetection(*(np.concatenate([u, v]) for u, v in zip(a.detection, b.detection))))


def observe(inputs: TrackInputs, rows: np.ndarray, t: float, x_prior: np.ndarray, P_prior: np.ndarray,
            H: np.ndarray, R: np.ndarray, z: np.ndarray) -> TrackInputs:
    """The tracks ``rows`` took the observations ``(H, R, z)`` at ``t`` (their filters' priors
    there: ``x_prior``, ``P_prior``); the other tracks' detectors are unchanged."""
    if not rows.size:
        return inputs
    bank, detection = input_step(InputBank(*(a[rows] for a in inputs.bank)), t - inputs.t[rows],
                                 x_prior, P_prior, H, R, z, t)
    banks = [a.copy() for a in inputs.bank]
    dets = [a.copy() for a in inputs.detection]
    for whole, part in zip(banks + dets, list(bank) + list(detection)):
        whole[rows] = part
    times = inputs.t.copy()
    times[rows] = t
    return TrackInputs(InputBank(*banks), times, InputDetection(*dets))
