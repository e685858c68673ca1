"""Variable-dimension filtering with input estimation (paper 004 section III).

One estimator, :func:`vdie_step`, drives any linear filter through the CV/CA model
switches; what "the filter" is comes in as a step function:

* FVDIE: the federated filter (local filters + fusion + reset). Input estimation runs
  at the master on fused quantities, which makes (57)-(59), (66) the exact
  centralized least-squares input estimate (errata).
* DVDIE: each local filter is a single-sensor VDIE on its own innovations; the
  centre fuses without feedback (:func:`dvdie_centre_step`).

States are batched: every array has leading batch axes (Monte Carlo runs, and for
DVDIE sensors). A run's state is stored in the CA order ``[x, vx, ax, y, vy, ay]``
whatever its model; for a run in CV the acceleration entries are placeholders
(mean 0, variance 1, no correlation) that are never read.

Equation readings (see the errata in docs/papers.md):

* (58): the middle ``P(j|j-1)`` is ``P(j|j)``; ``[F T(j-1) + I] B``; the inverse
  covers the whole first sum. Then ``W(j) = Theta' (sum_i H_i' S_i^-1 H_i) Theta``
  and ``X(j) = Theta' (sum_i H_i' S_i^-1 eps_i)`` by (60)-(61) with master quantities.
* (67): ``2 [J(0) - J(u)] = u' Gamma^-1 u``, compared with a chi-square(2) threshold.
* (69): the stacked ``[x, vx, y, vy, ax, ay]`` is permuted into the CA order.
* (35)-(38), (74): the banks carry ``E = T_omega B``, the posterior's bias per unit input,
  instead of ``T_omega``: ``E^-(j) = F E(j-1) (+ B(j) for a step input)``, ``Theta = E^-``,
  ``E(j) = [I - K H] E^-(j)``. With one constant ``B`` this is the paper's recursion; a step
  input's ``B`` depends on the interval, and a multi-target tracker's scans come at any times,
  where ``T_omega(j-1) B(j)`` is not the bias (a noise-free 1.5 m/s^2 onset over random
  intervals was estimated at 1.19 m/s^2).
* (72)-(74): we keep (74), ``T_omega(n) = I``: the pulse ``B u`` is added to the
  state at the onset ``n`` after its update, so ``x(n+1) = F [x(n) + B u]``: the
  acceleration component jumps at ``n`` and acts from the interval ``[n, n+1]`` on.
* (81): the acceleration significance statistic ``a' P_aa^-1 a`` summed over the
  last ``p`` steps, compared with ``h'``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable, NamedTuple

import numpy as np
from scipy.special import chdtri, ndtr

from fedtrack.config import ConfigError, require_finite_keys
from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    from_information,
    information,
    mat_vec,
    predict,
    symmetrize,
    transpose,
)
from fedtrack.local_filters.linear.models import CA_ACC, CV_IN_CA, LinearModel

EVENT_NONE, EVENT_ONSET, EVENT_NEW_CA, EVENT_END = 0, 1, 2, 3
PULSE_B = np.zeros((6, 2))  # the CA models' pulse input gain (72): the acceleration components
PULSE_B[CA_ACC, [0, 1]] = 1.0
EVENT_NAMES = {EVENT_ONSET: "onset", EVENT_NEW_CA: "new-ca", EVENT_END: "end"}
DETECT_CORRECTIONS = ("sidak", "none")


def sigma_to_chi2(k_sigma: float, dof: int) -> float:
    """Chi-square threshold with the same tail probability as a two-sided ``k`` sigma Gaussian test."""
    return float(chdtri(dof, 2.0 * ndtr(-k_sigma)))  # chi2.isf(2 norm.sf(k), dof), without scipy.stats


# scans of the detector's window and of the return test, at most: every scan tests each of the window's
# candidate onsets, and the state (a snapshot's arrays, a hand-over's) grows with both; 1,000 scans is
# minutes of data at any sensor's rate, far beyond a maneuver's onset (the paper's window is 6), and
# keeps a centre's snapshot inside the wire's size limits that its reader applies (a window of 6,145
# or more made every snapshot too large to be read back)
MAX_WINDOW = 1000


@dataclass(frozen=True)
class VdieParams:
    """Maneuver-detection parameters (paper 004 section IV: window 6, p = 2, "3 sigma", "0.5 sigma").

    ``h_detect`` is compared with ``u' Gamma^-1 u`` (chi-square, 2 dof) at the most likely
    onset. "3 sigma" (``detect_sigma``) is the detector's false-alarm probability per scan,
    0.0027. The detector tests the maximum of ``window - min_samples + 1`` candidate onsets
    (67), so with ``detect_correction = "sidak"`` (default) each candidate is tested at the
    Sidak level ``1 - (1 - 0.0027)^(1/5)`` = 5.4e-4, i.e. h = 15.05; ``"none"`` tests each
    candidate at 0.0027 (h = 11.83), which lets the maximum over the window raise false
    onsets (see docs/papers.md, "FVDIE false onsets"). ``h_cv`` is compared with the sum
    over ``p`` steps of ``a' P_aa^-1 a`` (chi-square, 2p dof); the default is the 0.5-sigma
    tail probability 0.617, i.e. 2.66 for p = 2.
    """

    window: int = 6
    p: int = 2
    detect_sigma: float = 3.0
    cv_sigma: float = 0.5
    min_samples: int = 2
    detect_correction: str = "sidak"

    def validate(self) -> None:
        if not 1 <= self.window <= MAX_WINDOW:
            raise ConfigError(f"window: must be between 1 and {MAX_WINDOW}")
        if not 1 <= self.p <= MAX_WINDOW:
            raise ConfigError(f"p: must be between 1 and {MAX_WINDOW}")
        if not 1 <= self.min_samples <= self.window:
            raise ConfigError("min_samples: must be between 1 and window")
        require_finite_keys(self, ("detect_sigma", "cv_sigma"))  # inf passed: no onset or no return to CV ever (tour62)
        if not self.detect_sigma > 0:
            raise ConfigError("detect_sigma: must be > 0")
        if not self.cv_sigma > 0:
            raise ConfigError("cv_sigma: must be > 0")
        if self.detect_correction not in DETECT_CORRECTIONS:
            raise ConfigError(f"detect_correction: must be one of {', '.join(DETECT_CORRECTIONS)}")

    @property
    def candidates_tested(self) -> int:
        """Candidate onsets whose estimate rests on ``min_samples`` scans or more (the max in (67))."""
        return self.window - self.min_samples + 1

    @cached_property
    def h_detect(self) -> float:
        tail = 2.0 * float(ndtr(-self.detect_sigma))
        if self.detect_correction == "sidak":
            tail = -float(np.expm1(np.log1p(-tail) / self.candidates_tested))  # 1 - (1 - tail)^(1/m)
        return float(chdtri(2, tail))

    @cached_property
    def h_cv(self) -> float:
        return sigma_to_chi2(self.cv_sigma, 2 * self.p)


class CandidateBank(NamedTuple):
    """Recursive input estimators for the last ``W`` candidate onset times (eq. (66)).

    ``E`` (..., W, n, 2): the posterior's bias per unit input since the onset, ``T^Omega_n(k) B``
    (eqs. (38), (74)): the maneuver compensation is ``E u``.
    ``info`` (..., W, 2, 2): ``Gamma^-1 = sum_j W(j)``. ``psi`` (..., W, 2): ``Psi = sum_j X(j)``.
    ``count`` (..., W): samples accumulated; -1 marks an empty slot. ``onset`` (..., W): ``n``.
    """

    E: np.ndarray
    info: np.ndarray
    psi: np.ndarray
    count: np.ndarray
    onset: np.ndarray


def bank_empty(batch: tuple[int, ...], window: int, n: int) -> CandidateBank:
    return CandidateBank(
        np.zeros(batch + (window, n, 2)), np.zeros(batch + (window, 2, 2)),
        np.zeros(batch + (window, 2)), np.full(batch + (window,), -1, dtype=np.int64),
        np.zeros(batch + (window,)),
    )


def bank_accumulate(bank: CandidateBank, F: np.ndarray, B: np.ndarray, pulse: bool,
                    prior: GaussianState, post: GaussianState) -> CandidateBank:
    """Add step ``j``'s terms to every live candidate (``B``: this interval's input gain).

    ``Theta = F E(j-1) + B`` for a step input (CV, eq. (50): ``[F T^Omega(j-1) + I] B``) or
    ``F E(j-1)`` for a pulse input (CA, eq. (75): ``F T^Omega(j-1) B``);
    ``W(j) = Theta' [P^-1(j|j-1) - P^-1(j|j-1) P(j|j) P^-1(j|j-1)] Theta`` (58, corrected),
    ``X(j) = Theta' P^-1(j|j-1) [x(j|j) - x(j|j-1)]`` (59),
    ``E(j) = [I - K H] Theta = P(j|j) P^-1(j|j-1) Theta`` (35)/(74) via (37).
    """
    n = F.shape[-1]
    Y_pred = symmetrize(np.linalg.solve(prior.P, np.broadcast_to(np.eye(n), prior.P.shape)))
    M = symmetrize(Y_pred - Y_pred @ post.P @ Y_pred)
    innov_info = mat_vec(Y_pred, post.x - prior.x)
    L = post.P @ Y_pred
    Theta = F @ bank.E  # (..., W, n, 2)
    if not pulse:
        Theta = Theta + B
    W_j = transpose(Theta) @ M[..., None, :, :] @ Theta
    X_j = np.einsum("...wni,...n->...wi", Theta, innov_info)
    live = bank.count >= 0
    # a step without a measurement (a multi-target track's missed scan) or of zero length adds
    # nothing to the estimate and is not counted as a sample
    informative = np.any(W_j != 0.0, axis=(-2, -1))
    return CandidateBank(
        np.where(live[..., None, None], L[..., None, :, :] @ Theta, bank.E),
        np.where(live[..., None, None], bank.info + W_j, bank.info),
        np.where(live[..., None], bank.psi + X_j, bank.psi),
        np.where(live, bank.count + informative, bank.count),
        bank.onset,
    )


class BestCandidate(NamedTuple):
    """The onset maximizing (67) and its input estimate."""

    statistic: np.ndarray  # (...,) u' Gamma^-1 u
    u: np.ndarray  # (..., 2)
    gamma: np.ndarray  # (..., 2, 2)
    E: np.ndarray  # (..., n, 2) the compensation per unit input
    onset: np.ndarray  # (...,)
    count: np.ndarray  # (...,) scans the estimate rests on


class CandidateInputs(NamedTuple):
    """Every candidate's input estimate ``u = Gamma Psi`` (66) and ``u' Gamma^-1 u`` (-inf for a
    candidate without an estimate), and the index of the largest (67) along the candidate axis."""

    best: np.ndarray  # (...,) index of the most likely onset
    statistic: np.ndarray  # (..., W)
    u: np.ndarray  # (..., W, 2)


def candidate_inputs(info: np.ndarray, psi: np.ndarray, count: np.ndarray) -> CandidateInputs:
    """(66)-(67) over the candidate axis from ``Gamma^-1`` (..., W, 2, 2), ``Psi`` (..., W, 2) and
    the sample counts (..., W)."""
    det = info[..., 0, 0] * info[..., 1, 1] - info[..., 0, 1] * info[..., 1, 0]
    scale = info[..., 0, 0] + info[..., 1, 1]
    # a candidate whose samples do not determine both input components (in a multi-target
    # tracker: only zero-length steps since its onset) has no estimate yet
    live = (count >= 1) & (det > 1e-12 * scale * scale)
    p0, p1 = psi[..., 0], psi[..., 1]
    r = 1.0 / np.where(live, det, 1.0)  # the 2 x 2 solve (without an estimate: u = Psi, never used)
    u_all = np.where(live[..., None], np.stack([(info[..., 1, 1] * p0 - info[..., 0, 1] * p1) * r,
                                                (info[..., 0, 0] * p1 - info[..., 1, 0] * p0) * r], axis=-1), psi)
    stat = np.where(live, u_all[..., 0] * p0 + u_all[..., 1] * p1, -np.inf)
    return CandidateInputs(np.argmax(stat, axis=-1), stat, u_all)


def bank_best(bank: CandidateBank) -> BestCandidate:
    """``u = Gamma Psi`` (66) for every candidate and the argmax of ``u' Gamma^-1 u`` (67)."""
    idx, stat, u_all = candidate_inputs(bank.info, bank.psi, bank.count)
    axis = idx.ndim

    def pick(a: np.ndarray) -> np.ndarray:
        sel = idx.reshape(idx.shape + (1,) * (a.ndim - axis))
        return np.take_along_axis(a, sel, axis=axis).squeeze(axis=axis)

    best_stat = pick(stat)
    info = np.where(np.isfinite(best_stat)[..., None, None], pick(bank.info), np.eye(2))  # none: any Gamma
    gamma = symmetrize(np.linalg.solve(info, np.broadcast_to(np.eye(2), info.shape)))
    return BestCandidate(best_stat, pick(u_all), gamma, pick(bank.E), pick(bank.onset), pick(bank.count))


def detected(best: BestCandidate, params: "VdieParams") -> np.ndarray:
    """(68): ``u' Gamma^-1 u > h`` at the most likely onset, once that estimate rests on
    at least ``min_samples`` scans (a one-scan estimate is too noisy to compensate with)."""
    return (best.statistic > params.h_detect) & (best.count >= params.min_samples)


def bank_push(bank: CandidateBank, onset: float, pulse_B: np.ndarray | None, clear: np.ndarray) -> CandidateBank:
    """Start a candidate with onset ``n = onset`` and retire the oldest (sliding window).

    ``clear`` (batch bool) empties the bank first (after a model switch or compensation).
    ``E(n)`` is 0 for a step input (``pulse_B`` None; ``T^Omega(n) = 0``, (35)) and the pulse's
    gain ``B`` for a pulse (``T^Omega(n) = I``, (74)).
    """
    n = bank.E.shape[-2]
    cleared = np.where(clear[..., None], -1, bank.count)
    start = np.zeros((n, 2)) if pulse_B is None else pulse_B
    batch = bank.count.shape[:-1]
    return CandidateBank(
        np.concatenate([np.broadcast_to(start, batch + (1, n, 2)), bank.E[..., :-1, :, :]], axis=-3),
        np.concatenate([np.zeros(batch + (1, 2, 2)), bank.info[..., :-1, :, :]], axis=-3),
        np.concatenate([np.zeros(batch + (1, 2)), bank.psi[..., :-1, :]], axis=-2),
        np.concatenate([np.zeros(batch + (1,), dtype=np.int64), cleared[..., :-1]], axis=-1),
        np.concatenate([np.full(batch + (1,), float(onset)), bank.onset[..., :-1]], axis=-1),
    )


class VdieState(NamedTuple):
    """Batched state of a variable-dimension filter with input estimation."""

    x: np.ndarray  # (..., 6) CA order
    P: np.ndarray  # (..., 6, 6)
    is_ca: np.ndarray  # (...,) bool
    bank_cv: CandidateBank  # step-input candidates, n = 4
    bank_ca: CandidateBank  # pulse-input candidates, n = 6
    acc_stats: np.ndarray  # (..., p) last p values of a' P_aa^-1 a (newest first)
    ca_steps: np.ndarray  # (...,) steps spent in CA


class VdieEvents(NamedTuple):
    """What the detector decided at one step (per batch element)."""

    kind: np.ndarray  # EVENT_* code
    statistic: np.ndarray  # best u' Gamma^-1 u of the active bank
    onset: np.ndarray
    u: np.ndarray  # (..., 2)
    gamma: np.ndarray  # (..., 2, 2) covariance of u, eq. (64)


def embed_cv(x4: np.ndarray, P4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Store a CV state in the CA layout with placeholder acceleration entries."""
    batch = x4.shape[:-1]
    x = np.zeros(batch + (6,))
    x[..., CV_IN_CA] = x4
    P = np.zeros(batch + (6, 6))
    P[..., CV_IN_CA[:, None], CV_IN_CA[None, :]] = P4
    P[..., CA_ACC, CA_ACC] = 1.0
    return x, P


def cv_part(x: np.ndarray, P: np.ndarray) -> GaussianState:
    return GaussianState(x[..., CV_IN_CA], P[..., CV_IN_CA[:, None], CV_IN_CA[None, :]])


def vdie_init(x: np.ndarray, P: np.ndarray, is_ca: np.ndarray, params: VdieParams,
              t0: float) -> VdieState:
    """Start in the given model (``x``/``P`` in the CA layout) with empty candidate banks."""
    batch = is_ca.shape
    clear = np.ones(batch, dtype=bool)
    bank_cv = bank_push(bank_empty(batch, params.window, 4), t0, None, clear)
    bank_ca = bank_push(bank_empty(batch, params.window, 6), t0, PULSE_B, clear)
    return VdieState(x, P, is_ca.copy(), bank_cv, bank_ca, np.zeros(batch + (params.p,)),
                     np.zeros(batch, dtype=np.int64))


StepFn = Callable[[GaussianState, LinearModel], tuple[GaussianState, GaussianState]]


def _where_state(mask: np.ndarray, a: GaussianState, b: GaussianState) -> GaussianState:
    return GaussianState(np.where(mask[..., None], a.x, b.x), np.where(mask[..., None, None], a.P, b.P))


class FilterTrace(NamedTuple):
    """The prior and posterior of the filter update a step made, in its model (CA layout)."""

    prior: GaussianState
    post: GaussianState


def vdie_step(state: VdieState, t: float, cv: LinearModel, ca: LinearModel, params: VdieParams,
              step_fn: StepFn) -> tuple[VdieState, VdieEvents, FilterTrace]:
    """One scan: filter in the current model, detect, switch models, compensate.

    ``step_fn(posterior_{k-1}, model) -> (prior_k, posterior_k)`` is the filter
    (federated round or single-sensor KF). Both model branches are computed for the
    whole batch and selected per element, so runs in different models stay batched.
    """
    batch = state.is_ca.shape
    prior_cv, post_cv = step_fn(cv_part(state.x, state.P), cv)
    prior_ca, post_ca = step_fn(GaussianState(state.x, state.P), ca)

    # --- CV branch: step-input estimation over the candidate onsets (57)-(67)
    bank_cv = bank_accumulate(state.bank_cv, cv.F, cv.B, False, prior_cv, post_cv)
    best_cv = bank_best(bank_cv)
    onset_det = detected(best_cv, params)
    # (69)-(71): x_s = [x + T B u; u], P_s with the T B Gamma cross terms (CA order)
    TB = best_cv.E
    x_sw = np.zeros(batch + (6,))
    x_sw[..., CV_IN_CA] = post_cv.x + mat_vec(TB, best_cv.u)
    x_sw[..., CA_ACC] = best_cv.u
    P_sw = np.zeros(batch + (6, 6))
    TBG = TB @ best_cv.gamma
    P_sw[..., CV_IN_CA[:, None], CV_IN_CA[None, :]] = post_cv.P + TBG @ transpose(TB)
    P_sw[..., CV_IN_CA[:, None], CA_ACC[None, :]] = TBG
    P_sw[..., CA_ACC[:, None], CV_IN_CA[None, :]] = transpose(TBG)
    P_sw[..., CA_ACC[:, None], CA_ACC[None, :]] = best_cv.gamma
    x_cv_out, P_cv_out = embed_cv(post_cv.x, post_cv.P)
    cv_x = np.where(onset_det[..., None], x_sw, x_cv_out)
    cv_P = np.where(onset_det[..., None, None], symmetrize(P_sw), P_cv_out)

    # --- CA branch: acceleration significance (81), then pulse-input estimation (79)-(83)
    acc = post_ca.x[..., CA_ACC]
    P_aa = post_ca.P[..., CA_ACC[:, None], CA_ACC[None, :]]
    acc_stat = np.einsum("...i,...i->...", acc, np.linalg.solve(P_aa, acc[..., None])[..., 0])
    acc_stats = np.concatenate([acc_stat[..., None], state.acc_stats[..., :-1]], axis=-1)
    ca_steps = state.ca_steps + 1
    end_det = (ca_steps >= params.p) & (acc_stats.sum(axis=-1) < params.h_cv)
    bank_ca = bank_accumulate(state.bank_ca, ca.F, ca.B, True, prior_ca, post_ca)
    best_ca = bank_best(bank_ca)
    pulse_det = ~end_det & detected(best_ca, params)
    TB6 = best_ca.E
    x_pulse = post_ca.x + mat_vec(TB6, best_ca.u)  # (82)
    P_pulse = symmetrize(post_ca.P + TB6 @ best_ca.gamma @ transpose(TB6))  # (83)
    x_end, P_end = embed_cv(*cv_part(post_ca.x, post_ca.P))
    ca_x = np.where(end_det[..., None], x_end, np.where(pulse_det[..., None], x_pulse, post_ca.x))
    ca_P = np.where(end_det[..., None, None], P_end,
                    np.where(pulse_det[..., None, None], P_pulse, post_ca.P))

    is_ca = state.is_ca
    kind = np.where(is_ca, np.where(end_det, EVENT_END, np.where(pulse_det, EVENT_NEW_CA, EVENT_NONE)),
                    np.where(onset_det, EVENT_ONSET, EVENT_NONE))
    new_is_ca = np.where(is_ca, ~end_det, onset_det)
    x = np.where(is_ca[..., None], ca_x, cv_x)
    P = np.where(is_ca[..., None, None], ca_P, cv_P)
    changed = kind != EVENT_NONE
    events = VdieEvents(
        kind,
        np.where(is_ca, best_ca.statistic, best_cv.statistic),
        np.where(is_ca, best_ca.onset, best_cv.onset),
        np.where(is_ca[..., None], best_ca.u, best_cv.u),
        np.where(is_ca[..., None, None], best_ca.gamma, best_cv.gamma),
    )
    new_state = VdieState(
        x, P, new_is_ca,
        bank_push(bank_cv, t, None, changed | new_is_ca),
        bank_push(bank_ca, t, ca.B, changed | ~new_is_ca),
        np.where(new_is_ca[..., None] & ~changed[..., None], acc_stats, 0.0),
        np.where(new_is_ca & ~changed, ca_steps, 0),
    )
    trace = FilterTrace(
        _where_state(is_ca, prior_ca, GaussianState(*embed_cv(prior_cv.x, prior_cv.P))),
        _where_state(is_ca, post_ca, GaussianState(*embed_cv(post_cv.x, post_cv.P))),
    )
    return new_state, events, trace


# ---------------------------------------------------------------- DVDIE centre

class CentreState(NamedTuple):
    """The DVDIE centre's fused estimate (CA layout) and its model."""

    x: np.ndarray
    P: np.ndarray
    is_ca: np.ndarray


def _embedded_information(state: GaussianState, is_ca: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Information of a CA-layout state; a CV state carries no acceleration information."""
    Y6, y6 = information(state)
    cv = cv_part(state.x, state.P)
    Y4, y4 = information(cv)
    Yc = np.zeros_like(Y6)
    yc = np.zeros_like(y6)
    Yc[..., CV_IN_CA[:, None], CV_IN_CA[None, :]] = Y4
    yc[..., CV_IN_CA] = y4
    return np.where(is_ca[..., None, None], Y6, Yc), np.where(is_ca[..., None], y6, yc)


class LocalReports(NamedTuple):
    """What the DVDIE centre knows of each local filter at one scan (sensor axis, CA layout).

    ``was_ca``: the model the local updated with; ``x``/``P``/``is_ca``: its estimate after
    the scan (compensated, possibly switched); ``kind``: its EVENT_* decision; ``prior`` /
    ``post``: the Kalman prior and posterior of its update (``post`` equals ``x``/``P``
    when ``kind`` is EVENT_NONE).
    """

    was_ca: np.ndarray
    x: np.ndarray
    P: np.ndarray
    is_ca: np.ndarray
    kind: np.ndarray
    prior: GaussianState
    post: GaussianState


def local_reports(before: VdieState, now: VdieState, events: VdieEvents, trace: FilterTrace) -> LocalReports:
    """Reports of locals run in-process (replay, Monte Carlo)."""
    return LocalReports(before.is_ca, now.x, now.P, now.is_ca, events.kind, trace.prior, trace.post)


def dvdie_centre_step(centre: CentreState, cv: LinearModel, ca: LinearModel,
                      reports: LocalReports, restart: bool = False) -> CentreState:
    """Decentralized fusion of single-sensor VDIE local filters, without feedback.

    The centre works in CA if any local is in CA, else in CV. In a scan where no local
    switched model or compensated its state, the centre runs the Hashemipour form: its
    own prediction plus every local's information increment ``Y_i(k|k) - Y_i(k|k-1)``
    (a position-only term, embedded across model dimensions), which is exact. When a
    local switches or compensates, its estimate is no longer a Kalman update of its
    prior, so the centre re-initializes from the locals' current estimates fused as if
    independent (``Y = sum Y_i``; a CV local carries no acceleration information). That
    ignores the cross-correlation through the common process noise: the correlation
    function the paper says a decentralized structure cannot afford to compute.
    ``restart`` forces that re-initialization (a local filter restarted: no prior).
    """
    any_ca = reports.is_ca.any(axis=-1)
    reinit = (reports.kind != EVENT_NONE).any(axis=-1) | (any_ca != centre.is_ca) | restart

    # local information increments: 6-D for CA locals, 4-D (embedded) for CV locals
    Yu, yu = _embedded_information(reports.post, reports.was_ca)
    Yp, yp = _embedded_information(reports.prior, reports.was_ca)
    dY, dy = (Yu - Yp).sum(axis=-3), (yu - yp).sum(axis=-2)

    Ypc, ypc = information(predict(cv_part(centre.x, centre.P), cv.F, cv.Q))
    Y_cv = Ypc + dY[..., CV_IN_CA[:, None], CV_IN_CA[None, :]]
    y_cv = ypc + dy[..., CV_IN_CA]
    Ypa, ypa = information(predict(GaussianState(centre.x, centre.P), ca.F, ca.Q))
    Y_ca, y_ca = Ypa + dY, ypa + dy

    # re-initialization: locals' current estimates fused as independent
    Y_loc, y_loc = _embedded_information(GaussianState(reports.x, reports.P), reports.is_ca)
    Y_re, y_re = Y_loc.sum(axis=-3), y_loc.sum(axis=-2)

    Y4 = np.where(reinit[..., None, None], Y_re[..., CV_IN_CA[:, None], CV_IN_CA[None, :]], Y_cv)
    y4 = np.where(reinit[..., None], y_re[..., CV_IN_CA], y_cv)
    Y6 = np.where(reinit[..., None, None], Y_re, Y_ca)
    y6 = np.where(reinit[..., None], y_re, y_ca)
    # a CA centre has acceleration information (some local is in CA); a CV centre ignores Y6
    Y6 = np.where(any_ca[..., None, None], Y6, np.eye(6))
    est_cv = from_information(symmetrize(Y4), y4)
    est_ca = from_information(symmetrize(Y6), y6)
    x_cv, P_cv = embed_cv(est_cv.x, est_cv.P)
    return CentreState(np.where(any_ca[..., None], est_ca.x, x_cv),
                       np.where(any_ca[..., None, None], est_ca.P, P_cv), any_ca)
