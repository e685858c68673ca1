"""Maneuver detection on a CV filter: paper 004's input estimation on the filter's innovations.

Hosted by every central track of the track-to-track centre
(:mod:`fedtrack.fusion_center.mtt.central_track`) and by every track of a 3-D tracker
(:mod:`fedtrack.local_filters.mtt.detector`: radar ``mtt-local``, 3-D ``mtt-centralized``),
whose tracks have no per-track VDIE. A track runs, beside its CV filter, paper 004's
least-squares input estimator (eqs. (57)-(68)) on its own innovations (``[mtt] maneuver =
"vdie"``; an EKF's linearized ones for a radar). Each of the track's
last ``window`` fused observations is a candidate onset ``n``; for each, the constant
horizontal acceleration ``u`` that best explains the innovations fused since ``n``, and
``u' Gamma^-1 u``. A maneuver is detected at an observation when the most likely candidate's
statistic exceeds ``h_detect`` (``[mtt.vdie] detect_sigma``, Sidak-corrected over the tested
candidates, as the trackers' VDIE) and rests on at least ``min_samples`` observations. The
estimate stays the CV filter (so the track-to-track fusions still equal the centralized
filter); a detection is an event of that track, carried by the pictures as its ``maneuver``
(onset time, estimated acceleration, statistic).

Irregular intervals. Paper 004 carries the compensation matrix ``T`` (the bias per unit ``B u``)
under one constant ``B``; a central track fuses observations at any times, and ``B`` depends on
the interval, so this carries the bias per unit input itself (``G(n) = 0`` at the onset):

* ``G^-(j) = F(j) G(j-1) + B(j)``: the prediction's bias at ``j`` per unit ``u``;
* ``G(j) = [I - K(j) H(j)] G^-(j)``: the posterior's;
* ``W(j) = (H G^-)' S^-1 (H G^-)``, ``X(j) = (H G^-)' S^-1 nu`` ((58)-(61): the innovation
  ``nu = z - H x^-`` has mean ``H G^- u`` and covariance ``S``);
* ``Gamma^-1 = sum W(j)``, ``Psi = sum X(j)``, ``u = Gamma Psi`` (66), ``u' Gamma^-1 u`` (67).

With a constant interval ``G(j) = T(j) B``: paper 004's recursion. ``B(j) = [dt^2/2, dt]'`` on
the x and y axes (a 3-D track's vertical acceleration is not estimated).

Exactness under re-processing: the bank after each observation is kept in that observation's
ring entry (:mod:`fedtrack.fusion_center.mtt.central_track`), so an out-of-sequence observation re-runs the estimator from
the entry before it, as it re-runs the filter: the statistics equal those of the time-sorted
observations, to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import batched_product, mat_vec, solve_spd
from fedtrack.local_filters.vdie.estimation import VdieParams, candidate_inputs


class InputBank(NamedTuple):
    """The input estimators of ``W`` candidate onsets per track (newest candidate first)."""

    G: np.ndarray  # (N, n, 2 W) posterior bias per unit input since each onset (candidate w: columns 2w, 2w+1)
    info: np.ndarray  # (N, W, 2, 2) Gamma^-1
    psi: np.ndarray  # (N, W, 2) Psi
    count: np.ndarray  # (N, W) observations accumulated; -1: no candidate
    onset: np.ndarray  # (N, W) candidate onset times


class InputDetection(NamedTuple):
    """The most likely candidate after an observation (per track)."""

    statistic: np.ndarray  # (N,) u' Gamma^-1 u; -inf: no estimate yet
    u: np.ndarray  # (N, 2) estimated acceleration (x, y), m/s^2
    onset: np.ndarray  # (N,)
    count: np.ndarray  # (N,) observations the estimate rests on

    def detected(self, params: VdieParams) -> np.ndarray:
        """(68) with paper 004's threshold and the minimum sample count."""
        return (self.statistic > params.h_detect) & (self.count >= params.min_samples)

    def picture_rows(self, params: VdieParams) -> np.ndarray:
        """Per track ``[onset, ax, ay, statistic]`` of its detected maneuver, a row of NaN where
        none (the pictures' ``maneuver``)."""
        rows = np.column_stack([self.onset, self.u, self.statistic])
        rows[~self.detected(params)] = np.nan
        return rows


def no_detection(n: int) -> InputDetection:
    return InputDetection(np.full(n, -np.inf), np.zeros((n, 2)), np.zeros(n), np.zeros(n, dtype=np.int64))


def new_banks(n_tracks: int, window: int, dim: int, t: np.ndarray | float) -> InputBank:
    """Banks of tracks started at ``t``: one candidate, with its onset there."""
    count = np.full((n_tracks, window), -1, dtype=np.int64)
    count[:, 0] = 0
    onset = np.zeros((n_tracks, window))
    onset[:, 0] = t
    return InputBank(np.zeros((n_tracks, dim, 2 * window)), np.zeros((n_tracks, window, 2, 2)),
                     np.zeros((n_tracks, window, 2)), count, onset)


def input_step(bank: InputBank, dt: np.ndarray, x_prior: np.ndarray, P_prior: np.ndarray, H: np.ndarray,
               R: np.ndarray, z: np.ndarray, t: float | np.ndarray) -> tuple[InputBank, InputDetection]:
    """Add the observation ``(H, R, z)`` fused at ``t``, ``dt`` after the previous one, to every
    candidate (the filter's prior there: ``x_prior``, ``P_prior``); returns the banks with a new
    candidate (onset ``t``) in front and the oldest retired, and the detection after the step.

    Every candidate's columns go through each product at once (one (m, n) x (n, 2 W) product per
    track). A slot without a candidate (count -1) accumulates too, but is never read."""
    n_tracks = bank.count.shape[0]
    G = bank.G
    Gp = G.copy()  # F G + B (CV: every position += dt velocity; B: a constant acceleration over dt)
    Gp[:, 0::2] += dt[:, None, None] * G[:, 1::2]
    half = 0.5 * dt * dt
    Gp[:, 0, 0::2] += half[:, None]
    Gp[:, 1, 0::2] += dt[:, None]
    Gp[:, 2, 1::2] += half[:, None]
    Gp[:, 3, 1::2] += dt[:, None]
    HG = batched_product(H, Gp)  # (N, m, 2 W)
    PHt = batched_product(P_prior, np.swapaxes(H, 1, 2))
    S = batched_product(H, PHt) + R
    nu = z - mat_vec(H, x_prior)
    solved = solve_spd(S, np.concatenate([nu[:, :, None], HG], axis=2))  # S^-1 [nu, H G^-]
    S_nu, S_HG = solved[:, :, 0], solved[:, :, 1:]
    # (58) W = (H G^-)' S^-1 (H G^-) and (59) X = (H G^-)' S^-1 nu per candidate: sums over the m rows
    h0, h1, s0, s1 = HG[:, :, 0::2], HG[:, :, 1::2], S_HG[:, :, 0::2], S_HG[:, :, 1::2]  # (N, m, W)
    w00, w11 = np.sum(h0 * s0, axis=1), np.sum(h1 * s1, axis=1)
    w01 = 0.5 * (np.sum(h0 * s1, axis=1) + np.sum(h1 * s0, axis=1))
    W_j = np.stack([np.stack([w00, w01], axis=-1), np.stack([w01, w11], axis=-1)], axis=-2)  # (N, W, 2, 2)
    X_j = np.stack([np.sum(h0 * S_nu[:, :, None], axis=1), np.sum(h1 * S_nu[:, :, None], axis=1)], axis=-1)
    G_post = Gp - batched_product(PHt, S_HG)  # (I - K H) G^-, K = P^- H' S^-1
    informative = np.any(W_j != 0.0, axis=(-2, -1))  # a zero-length first interval adds nothing
    info, psi = bank.info + W_j, bank.psi + X_j
    count = np.where(bank.count >= 0, bank.count + informative, -1)
    best, stat, u_all = candidate_inputs(info, psi, count)
    rows = np.arange(n_tracks)
    detection = InputDetection(stat[rows, best], u_all[rows, best], bank.onset[rows, best], count[rows, best])
    fresh = new_banks(n_tracks, 1, G.shape[1], t)
    pushed = InputBank(np.concatenate([fresh.G, G_post[:, :, :-2]], axis=2),
                       *(np.concatenate([new, old[:, :-1]], axis=1)
                         for new, old in zip(fresh[1:], (info, psi, count, bank.onset))))
    return pushed, detection
