"""PDA-AI, HPDA and their track-existence recursions (paper 001), as pure batched functions.

Corrected standard forms (paper 001 errata, docs/papers.md):

* (4): the amplitude term of the numerator is ``A_i`` (the printed ``A_j`` is a typo);
  ``C_gamma = P(n/2 + 1, gamma/2) / P(n/2, gamma/2)`` (regularized lower incomplete
  gamma), whose n = 2 value is the printed closed form.
* (8), (15): ``mu_k = (1 - delta) mu_bar / (1 - delta mu_bar)``,
  ``mu_bar = p11 mu_{k-1} + p21 (1 - mu_{k-1})``; computed as
  ``logit mu_k = log(1 - delta) + logit mu_bar``.
* (9): the measurement likelihood is ``N(nu; 0, S) / P_G``.
* (11)/(13): (13) gets the clutter spatial density ``1/V_G``, the third term has exponent
  ``l - 1`` and ``mu_F(m - 1)``; (14) is ``beta_l = f(M_T) / (f(M_T) + f(M_F))``.
  Dividing both by the common factor ``C(m-1, l-1) G0^(l-1) (1 - G0)^(m-l) mu_F(m-1) f0r``
  gives the closed form used in :func:`hpda_hypothesise`.
* HPDA update: ``nu* = z* - H x_bar``.

Batching: every array may carry leading batch axes (Monte Carlo runs or tracks); the
detections of one scan are ``z`` (..., M, 2), ``amplitude`` (..., M) and a ``valid`` mask
(..., M) so that scans with different clutter counts are padded to a common ``M``.
State order is the Singer state in CA order ``[x, vx, ax, y, vy, ay]``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import expm
from scipy.special import betaln, expit, gammainc, gammaln

from fedtrack.local_filters.linear.gating import gate_ball_pairs
from fedtrack.local_filters.linear.kalman import (
    LOG_2PI,
    GaussianState,
    logsumexp,
    mat_vec,
    symmetrize,
    transpose,
)
from fedtrack.local_filters.linear.models import LinearModel
from fedtrack.local_filters.pda.config import PDAParams

MEAS_DIM = 2


class Constants(NamedTuple):
    """Scalars derived once from :class:`PDAParams` (assumptions 1-4 and section 2.1)."""

    pd: float
    lam: float
    snr: float
    gamma: float
    tau: float  # amplitude threshold, P_D = exp(-tau / (1 + rho))
    pg: float  # gate probability P(n/2, gamma/2)
    c_gamma: float  # C_gamma of section 2.1
    log_cn: float  # log of the unit-ball volume C_n

    @property
    def miss_factor(self) -> float:
        """``P_D P_G (1 - C_gamma) / (1 - P_D P_G)``: the missed-gate covariance term."""
        pdpg = self.pd * self.pg
        return pdpg * (1.0 - self.c_gamma) / (1.0 - pdpg)


def constants(p: PDAParams, n: int = MEAS_DIM) -> Constants:
    """Threshold, gate probability, ``C_gamma`` and ``C_n`` for ``p``."""
    tau = -(1.0 + p.snr) * np.log(p.pd)
    pg = float(gammainc(n / 2.0, p.gate / 2.0))
    c_gamma = float(gammainc(n / 2.0 + 1.0, p.gate / 2.0)) / pg
    log_cn = 0.5 * n * np.log(np.pi) - float(gammaln(n / 2.0 + 1.0))
    return Constants(p.pd, p.clutter_density, p.snr, p.gate, float(tau), pg, c_gamma, log_cn)


def singer_model(T: float, sigma_a: float, tau_s: float) -> LinearModel:
    """Singer model of eqs (18)-(19), discretized exactly by Van Loan's matrix exponential.

    Per axis ``d[p, v, a]/dt = [v, a, -a/tau_s] + [0, 0, 1/tau_s] w`` with ``w`` of power
    spectral density ``2 tau_s sigma_a^2``, i.e. ``2 sigma_a^2 / tau_s`` on the
    acceleration. Van Loan avoids the cancellation of the closed form when ``T/tau_s``
    is small. Returned in CA order ``[x, vx, ax, y, vy, ay]``.
    """
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau_s]])
    qc = 2.0 * sigma_a**2 / tau_s
    vl = np.zeros((6, 6))
    vl[:3, :3] = -a
    vl[2, 5] = qc
    vl[3:, 3:] = a.T
    e = expm(vl * T)
    f = e[3:, 3:].T
    q = symmetrize(f @ e[:3, 3:])
    F = np.kron(np.eye(2), f)
    Q = np.kron(np.eye(2), q)
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 3] = 1.0
    G = np.kron(np.eye(2), np.array([[0.0], [0.0], [1.0]]))
    return LinearModel("singer", T, sigma_a**2, F, Q, H, G, G.copy(), (0, 3), (1, 4), (2, 5))


def log_amplitude_ratio(amplitude: np.ndarray, c: Constants) -> np.ndarray:
    """``log A = log f1r(a) - log f0r(a)``, eqs (1), (2), (6), (7).

    ``f1r = f1 / P_D``, ``f0r = f0 / P_FA`` are the amplitude densities above threshold;
    with ``u = a - tau``: ``log A = u rho / (1 + rho) - log(1 + rho)`` (zero at rho = 0).
    """
    return (amplitude - c.tau) * c.snr / (1.0 + c.snr) - np.log1p(c.snr)


def log_rank_probability(rank: np.ndarray, m: np.ndarray, snr: float) -> np.ndarray:
    """log P{target amplitude is the ``rank``-th largest of ``m`` gated detections}.

    Equals the paper's ``P_A(m)`` (rank 1), ``gamma(l, m)`` (2 <= l <= m-1) and
    ``1 / (m + (m-1) rho)`` (rank m), eq (17); computed without alternating sums as
    ``C(m-1, l-1) B(l - 1 + 1/c, m - l + 1) / c`` with ``c = 1 + rho``, because the
    clutter tail ``G0 = exp(-u)`` at the target amplitude is Beta(1/c, 1) distributed.
    Entries with ``m < 1`` or ``rank`` outside ``1..m`` are meaningless (masked by callers).
    """
    cc = 1.0 + snr
    l = np.clip(rank, 1, None).astype(float)
    mm = np.maximum(np.asarray(m, dtype=float), l)
    log_comb = gammaln(mm) - gammaln(l) - gammaln(mm - l + 1.0)
    return log_comb - np.log(cc) + betaln(l - 1.0 + 1.0 / cc, mm - l + 1.0)


class Gated(NamedTuple):
    """Validation-gate quantities for one scan (section 2.1, assumption 4)."""

    nu: np.ndarray  # (..., M, 2) innovations z_j - H x_bar
    S: np.ndarray  # (..., 2, 2) innovation covariance
    K: np.ndarray  # (..., n, 2) gain P_bar H' S^-1
    d2: np.ndarray  # (..., M) normalized distance squared
    inside: np.ndarray  # (..., M) valid and d2 <= gamma
    log_n: np.ndarray  # (..., M) log N(nu; 0, S)
    log_vg: np.ndarray  # (...) log V_G = log(C_n |S|^1/2 gamma^(n/2))


def det2(S: np.ndarray) -> np.ndarray:
    """Determinant of 2x2 matrices (..., 2, 2)."""
    return S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0]


def mahalanobis2(S: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``d' S^-1 d`` for symmetric positive definite 2x2 ``S`` (..., 2, 2) and ``d`` (..., 2),
    broadcast; the closed-form inverse (a batched ``solve`` of 2x2 systems costs 20x more)."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    x, y = d[..., 0], d[..., 1]
    return (c * x * x - 2.0 * b * x * y + a * y * y) / (a * c - b * b)


def gate(pred: GaussianState, z: np.ndarray, valid: np.ndarray, H: np.ndarray,
         R: np.ndarray, c: Constants) -> Gated:
    """Innovations, gate membership, Gaussian log-densities and gate volume of one scan."""
    n = H.shape[0]
    S = symmetrize(H @ pred.P @ H.T + R)
    PHt = pred.P @ H.T
    K = transpose(np.linalg.solve(S, transpose(PHt)))
    nu = z - mat_vec(H, pred.x)[..., None, :]
    d2 = mahalanobis2(S[..., None, :, :], nu)
    log_det = np.log(det2(S))
    log_n = -0.5 * (d2 + log_det[..., None] + n * LOG_2PI)
    inside = valid & (d2 <= c.gamma)
    log_vg = c.log_cn + 0.5 * log_det + 0.5 * n * np.log(c.gamma)
    return Gated(nu, S, K, d2, inside, log_n, log_vg)


def candidates(pred: GaussianState, z: np.ndarray, H: np.ndarray, R: np.ndarray,
               c: Constants) -> tuple[np.ndarray, np.ndarray]:
    """Per track, the detections of ``z`` (M, 2) that may lie in its validation gate: those within
    ``sqrt(gamma * trace S)`` of the predicted position (a disc holding the gate ellipse), found
    with a k-d tree. Returns ``index`` (N, K) into ``z`` and its ``valid`` mask, ``K`` the largest
    count (at least 1 if there are detections): gating, association and update then cost
    O(N K) instead of O(N M). Detections outside every gate change no association quantity,
    so the results are those of the full scan."""
    n = pred.x.shape[0]
    if z.shape[0] == 0 or n == 0:
        return np.zeros((n, 0), dtype=np.int64), np.zeros((n, 0), dtype=bool)
    rows, cols = gate_ball_pairs(z, mat_vec(H, pred.x), H @ pred.P @ H.T + R, c.gamma)
    counts = np.bincount(rows, minlength=n)
    valid = np.arange(max(1, int(counts.max()))) < counts[:, None]
    index = np.zeros(valid.shape, dtype=np.int64)
    index[valid] = cols
    return index, valid


def original_index(j: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Map detection indices ``j`` (..., -1 for none) of a :func:`candidates` scan back to the full scan."""
    if index.shape[-1] == 0:
        return j
    return np.where(j >= 0, np.take_along_axis(index, np.maximum(j, 0)[..., None], axis=-1)[..., 0], -1)


def _log(x: np.ndarray | float) -> np.ndarray:
    """Natural log with ``log 0 = -inf`` and no warning."""
    with np.errstate(divide="ignore"):
        return np.log(x)


def _masked(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return np.where(mask, values, -np.inf)


class PDAHypotheses(NamedTuple):
    """PDA-AI association probabilities, eqs (4)-(5), and the existence likelihood ratio."""

    beta0: np.ndarray  # (...)   all gated detections are clutter
    beta: np.ndarray  # (..., M) detection j is the target (0 outside the gate)
    log_lr: np.ndarray  # (...)   log(1 - delta_k), eq (9)


def pda_ai_hypothesise(g: Gated, log_a: np.ndarray, c: Constants) -> PDAHypotheses:
    """PDA-AI hypothesiser. ``log_a = 0`` everywhere gives plain (parametric) PDA.

    ``beta_i = P_D N_i A_i / (lambda (1 - P_D P_G) + P_D sum_j N_j A_j)`` (4),
    ``beta_0 = lambda (1 - P_D P_G) / (...)`` (5); in log space. The denominator over
    lambda is ``1 - delta_k`` of eq (9) with the errata's ``N / P_G`` likelihood.
    """
    log_num, log_den = _pda_terms(g, log_a, c)
    log_null_b = np.broadcast_to(np.log(c.lam * (1.0 - c.pd * c.pg)), log_den.shape)
    beta = np.exp(log_num - log_den[..., None])
    beta0 = np.exp(log_null_b - log_den)
    log_lr = log_den - np.log(c.lam)  # (9): 1 - delta = 1 - P_D P_G + P_D sum N_j A_j / lambda
    return PDAHypotheses(beta0, beta, log_lr)


def _pda_terms(g: Gated, log_a: np.ndarray, c: Constants) -> tuple[np.ndarray, np.ndarray]:
    """Log numerators of eq (4) (``-inf`` outside the gate) and their common denominator."""
    log_num = _masked(np.log(c.pd) + g.log_n + log_a, g.inside)  # (4) numerators
    log_null = np.log(c.lam * (1.0 - c.pd * c.pg))  # (5) numerator
    return log_num, np.logaddexp(log_null, logsumexp(log_num, axis=-1))


class Evidence(NamedTuple):
    """What a scan says about a track, whatever updates it (PDA-AI's eq (4)-(9) quantities)."""

    log_lr: np.ndarray  # (...) log(1 - delta_k) of eq (9)
    dominant: np.ndarray  # (...) the detection most likely the target's, -1 if none has beta >= 1/2


def scan_evidence(g: Gated, amplitude: np.ndarray, c: Constants) -> Evidence:
    """Eq (9)'s likelihood ratio of the gated detections and amplitudes ("target present"
    over "all clutter"; mean 1 under clutter alone at the configured lambda, so its running
    product is a martingale) and the detection that holds most of the association weight."""
    log_num, log_den = _pda_terms(g, log_amplitude_ratio(amplitude, c), c)
    if log_num.shape[-1] == 0:
        return Evidence(log_den - np.log(c.lam), np.full(log_den.shape, -1))
    best = np.argmax(log_num, axis=-1)
    strong = np.take_along_axis(log_num, best[..., None], axis=-1)[..., 0] - log_den >= np.log(0.5)
    return Evidence(log_den - np.log(c.lam), np.where(strong, best, -1))


def pda_update(pred: GaussianState, g: Gated, hyp: PDAHypotheses, c: Constants,
               joseph: tuple[np.ndarray, np.ndarray] | None = None) -> GaussianState:
    """PDA(-AI) updater, section 2.1 (both the M_0 and the non-empty-gate case).

    ``x = x_bar + K sum beta_i nu_i``;
    ``P = P_bar + beta_0 m_f KSK' - (1 - beta_0) KSK' + K [sum beta_i nu_i nu_i' - nu nu'] K'``
    with ``m_f = P_D P_G (1 - C_gamma) / (1 - P_D P_G)``; an empty gate has ``beta_0 = 1``.
    With ``joseph = (H, R)`` (``H`` (m, n) or per track (..., m, n)) the detected components'
    covariance ``P_bar - KSK'`` is taken in Joseph form ``(I - KH) P_bar (I - KH)' + KRK'``
    (equal in exact arithmetic, positive semidefinite under round-off; the JIPDA tracker's).
    """
    nu = np.einsum("...j,...ji->...i", hyp.beta, g.nu)
    spread = np.einsum("...j,...ji,...jk->...ik", hyp.beta, g.nu, g.nu) - nu[..., :, None] * nu[..., None, :]
    KSK = g.K @ g.S @ transpose(g.K)
    b0 = hyp.beta0[..., None, None]
    if joseph is None:
        P = pred.P + (b0 * c.miss_factor - (1.0 - b0)) * KSK + g.K @ spread @ transpose(g.K)
    else:
        H, R = joseph
        A = np.eye(pred.P.shape[-1]) - g.K @ H
        detected = A @ pred.P @ transpose(A) + g.K @ R @ transpose(g.K)
        P = b0 * (pred.P + c.miss_factor * KSK) + (1.0 - b0) * detected + g.K @ spread @ transpose(g.K)
    return GaussianState(pred.x + mat_vec(g.K, nu), symmetrize(P))


class HPDAHypothesis(NamedTuple):
    """HPDA choice (section 3.1): the most probable detection and its mixture weights."""

    index: np.ndarray  # (...) selected detection (meaningless where not found)
    found: np.ndarray  # (...) some detection is in the gate
    beta: np.ndarray  # (...) beta* of eq (14) (0 where not found)
    alpha: np.ndarray  # (...) alpha of P_bar_{k, M_F}(D)
    log_lr: np.ndarray  # (...) log(1 - delta_k), eq (16)


def amplitude_ranks(amplitude: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """1-based rank of each gated detection by decreasing amplitude (section 3.1)."""
    key = np.where(inside, -amplitude, np.inf)
    return np.argsort(np.argsort(key, axis=-1, kind="stable"), axis=-1, kind="stable") + 1


def _at_least_one(g: Gated, amplitude: np.ndarray) -> tuple[Gated, np.ndarray]:
    """Pad a scan without detections with one detection outside the gate (for argmax)."""
    if g.nu.shape[-2] > 0:
        return g, amplitude
    shape = g.nu.shape[:-2] + (1,)
    return (g._replace(nu=np.zeros(shape + g.nu.shape[-1:]), d2=np.full(shape, np.inf),
                       inside=np.zeros(shape, dtype=bool), log_n=np.full(shape, -np.inf)),
            np.ones(shape))


def hpda_hypothesise(g: Gated, amplitude: np.ndarray, c: Constants) -> HPDAHypothesis:
    """HPDA hypothesiser: eqs (10)-(14) as corrected by the errata, then alpha and eq (16).

    With ``u = a_l - tau``, rank ``l`` of ``m`` gated detections and ``A`` of eq (6):
    ``beta_l = P_D N_l A_l / (P_D N_l A_l + lambda (1 - P_D P_G)
               + (l - 1) P_G P_D exp(u rho / (1 + rho)) / V_G
               + (m - l) P_G P_D (1 - exp(-u / (1 + rho))) / (1 - exp(-u)) / V_G)``,
    the three clutter terms being those of the corrected eq (13).
    """
    g, amplitude = _at_least_one(g, amplitude)
    inside = g.inside
    m = np.sum(inside, axis=-1)
    rank = amplitude_ranks(amplitude, inside)
    u = np.maximum(amplitude - c.tau, 1e-300)
    cc = 1.0 + c.snr
    log_pdpg = np.log(c.pd * c.pg)
    log_vg = g.log_vg[..., None]
    log_t = np.log(c.pd) + g.log_n + log_amplitude_ratio(amplitude, c)  # (11)
    log_f1 = np.broadcast_to(np.log(c.lam * (1.0 - c.pd * c.pg)), log_t.shape)  # (13) first term
    log_f2 = _log(rank - 1.0) + log_pdpg + u * c.snr / cc - log_vg  # (13) second term
    log_f3 = (_log(np.maximum(m[..., None] - rank, 0.0)) + log_pdpg + np.log(-np.expm1(-u / cc))
              - np.log(-np.expm1(-u)) - log_vg)  # (13) third term, corrected
    log_f = logsumexp(np.stack([log_t, log_f1, log_f2, log_f3]), axis=0)
    log_beta = _masked(log_t - log_f, inside)  # (14)
    index = np.argmax(log_beta, axis=-1)
    found = m > 0

    def pick(arr: np.ndarray) -> np.ndarray:
        return np.take_along_axis(arr, index[..., None], axis=-1)[..., 0]

    beta = np.where(found, np.exp(pick(log_beta)), 0.0)
    log_pl = log_rank_probability(pick(rank), m, c.snr)  # (17)
    pl = np.where(found, np.exp(log_pl), 0.0)
    # alpha, multiplied through by m: mu_F(m) / mu_F(m-1) = lambda V_G / m
    pdpg = c.pd * c.pg
    lvg = c.lam * np.exp(g.log_vg)
    other = pdpg * m * (1.0 - pl)
    alpha = ((1.0 - pdpg * c.c_gamma) * lvg + c.c_gamma * other) / ((1.0 - pdpg) * lvg + other)
    # (16): 1 - delta = 1 - P_D P_G + m/(lambda V_G) P_D P_G (1 - P_A) + m/lambda P_D N_l P_A
    log_m = _log(m.astype(float))
    terms = np.stack(np.broadcast_arrays(
        np.log(1.0 - pdpg),
        np.where(found, log_m - np.log(c.lam) - g.log_vg + log_pdpg + _log(1.0 - pl), -np.inf),
        np.where(found, log_m - np.log(c.lam) + np.log(c.pd) + pick(g.log_n) + log_pl, -np.inf),
    ))
    return HPDAHypothesis(index, found, beta, alpha, logsumexp(terms, axis=0))


def hpda_update(pred: GaussianState, g: Gated, hyp: HPDAHypothesis) -> GaussianState:
    """HPDA updater, section 3.1 (an empty gate reduces to the M_0 update).

    ``x = x_bar + beta* K nu*``;
    ``P = (1 - beta*) [P_bar - KSK' + alpha KSK'] + beta* (P_bar - KSK')
          + beta* (1 - beta*) K nu* nu*' K'``.
    With no gated detection ``beta* = 0`` and ``alpha = (1 - P_D P_G C_g) / (1 - P_D P_G)``,
    which is the M_0 covariance ``P_bar + m_f KSK'``.
    """
    g, _ = _at_least_one(g, np.zeros(g.nu.shape[:-1]))
    nu = np.take_along_axis(g.nu, hyp.index[..., None, None], axis=-2)[..., 0, :]
    Knu = mat_vec(g.K, nu)
    KSK = g.K @ g.S @ transpose(g.K)
    b = hyp.beta[..., None, None]
    P = (pred.P - KSK + (1.0 - b) * hyp.alpha[..., None, None] * KSK
         + b * (1.0 - b) * Knu[..., :, None] * Knu[..., None, :])
    return GaussianState(pred.x + hyp.beta[..., None] * Knu, symmetrize(P))


def existence_predict(mu: np.ndarray, p11: float | np.ndarray, p21: float | np.ndarray) -> np.ndarray:
    """The Markov chain prediction of eqs (8), (15): ``mu_bar = p11 mu + p21 (1 - mu)``
    (``p11``, ``p21`` scalars or per track)."""
    return p11 * mu + p21 * (1.0 - mu)


def existence_update(mu: np.ndarray, log_lr: np.ndarray, p11: float, p21: float) -> np.ndarray:
    """Track existence, eqs (8) and (15) as corrected: ``logit mu = log(1 - delta) + logit mu_bar``."""
    mu_bar = existence_predict(mu, p11, p21)
    return expit(log_lr + _log(mu_bar) - _log(1.0 - mu_bar))


ALGORITHMS = ("pda-ai", "hpda")


def associate(algorithm: str, pred: GaussianState, g: Gated, amplitude: np.ndarray,
              c: Constants) -> tuple[GaussianState, np.ndarray]:
    """Hypothesise and update with ``pda-ai`` or ``hpda``; returns the posterior and
    ``log(1 - delta_k)`` (eq (9) for IPDA-AI, eq (16) for HPDA initiation)."""
    if algorithm == "pda-ai":
        hyp = pda_ai_hypothesise(g, log_amplitude_ratio(amplitude, c), c)
        return pda_update(pred, g, hyp, c), hyp.log_lr
    if algorithm == "hpda":
        hh = hpda_hypothesise(g, amplitude, c)
        return hpda_update(pred, g, hh), hh.log_lr
    raise ValueError(f"unknown algorithm {algorithm!r} (expected one of {ALGORITHMS})")


def two_point_init(z0: np.ndarray, z1: np.ndarray, dt: float, R: np.ndarray,
                   sigma_a: float) -> GaussianState:
    """Two-point differencing at the time of ``z1``: position ``z1``, velocity
    ``(z1 - z0)/dt``, zero acceleration with the Singer prior variance ``sigma_a^2``.

    Per axis ``P = [[r, r/dt, 0], [r/dt, 2r/dt^2, 0], [0, 0, sigma_a^2]]`` (cross-axis terms
    from the off-diagonal of ``R`` likewise).
    """
    v = (z1 - z0) / dt
    zero = np.zeros_like(z1[..., 0])
    x = np.stack([z1[..., 0], v[..., 0], zero, z1[..., 1], v[..., 1], zero], axis=-1)
    per_axis = np.array([[1.0, 1.0 / dt, 0.0], [1.0 / dt, 2.0 / dt**2, 0.0], [0.0, 0.0, 0.0]])
    P = np.kron(R, per_axis) + sigma_a**2 * np.diag([0.0, 0.0, 1.0, 0.0, 0.0, 1.0])
    return GaussianState(x, np.broadcast_to(P, x.shape[:-1] + (6, 6)).copy())


def gate_box(pred: GaussianState, H: np.ndarray, R: np.ndarray,
             c: Constants) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box ``(lo, hi)`` (..., 2) holding the validation gate ellipse."""
    S = H @ pred.P @ H.T + R
    half = np.sqrt(c.gamma * np.diagonal(S, axis1=-2, axis2=-1))
    centre = mat_vec(H, pred.x)
    return centre - half, centre + half


def truth_d2(pred: GaussianState, g: Gated, pos: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Normalized distance squared of the true position ``pos`` in the validation gate."""
    e = pos - mat_vec(H, pred.x)
    return np.einsum("...i,...i->...", e, np.linalg.solve(g.S, e[..., None])[..., 0])
