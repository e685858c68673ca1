"""JIPDA with amplitude information: paper 001's IPDA-AI (:mod:`fedtrack.local_filters.pda`) made
multi-target (joint integrated PDA, Musicki & Evans 2004), as pure functions batched over tracks.

Per scan, tracks ``i`` with predicted state and predicted existence ``mu_bar_i`` (the Markov chain of
eqs (8), (15): :func:`~fedtrack.local_filters.pda.association.existence_predict`), and the gated pairs
``(i, j)`` of :func:`fedtrack.local_filters.mtt.roles.gating.gate`:

* pair factor ``r_ij = mu_bar_i P_D N(nu_ij; 0, S_i) A_j / lambda`` (eq (4)'s numerator over the
  clutter density, with (9)'s ``N / P_G`` likelihood times ``P_G``; ``A_j`` the amplitude likelihood
  ratio of eqs (6)-(7), 1 without amplitudes);
* miss factor ``m_i = 1 - P_D P_G mu_bar_i`` (track ``i`` does not exist, or exists and gave no
  detection in its gate);
* a joint event ``e`` gives each track at most one detection and each detection at most one track:
  ``P(e) ~ prod_{i missed} m_i prod_{i -> j} r_ij``; ``W_i0``, ``W_ij`` are the probabilities of the
  events in which ``i`` is missed or takes ``j``;
* existence ``mu_i = W_i0 mu_bar_i (1 - P_D P_G) / m_i + sum_j W_ij``; association given existence
  ``beta_i0 = W_i0 mu_bar_i (1 - P_D P_G) / (m_i mu_i)``, ``beta_ij = W_ij / mu_i``.

For a track that shares no detection these are eqs (4), (5) and (8) exactly (its events are
"missed" and "took j"): the single-target IPDA-AI. Tracks are split into clusters (connected
components of the gating graph); a cluster is enumerated exactly when its number of joint events
(every partial matching of its ``a`` tracks into its ``b`` detections, :func:`~.events.event_count`) is at
most ``MAX_EVENTS``; a larger one of at most ``K_BEST_MAX_TRACKS`` tracks sums its ``K_BEST`` most
likely events (a bounded search or Murty, :func:`~.events.k_best_clusters`); a larger one still is
approximated by the linear-multitarget rule (LM-IPDA, Musicki & La Scala 2008): track ``i`` sees
detection ``j`` with the clutter density ``lambda + sum_{s != i} p_sj P_sj / (1 - P_sj)``,
``p_sj = N_sj A_j / P_G`` the measurement density of track ``s`` and
``P_sj = P_D P_G mu_bar_s N_sj A_j / sum_k N_sk A_k`` the probability that ``j`` is ``s``'s judged
by ``s`` alone, and is then updated as a single-target IPDA. docs/jipda.md gives the limit's cost
and the approximations' measured errors.

State update per track: PDA's mixture over "missed" and each gated detection with the spread of
the means, the detected components in Joseph form (:func:`~fedtrack.local_filters.pda.association.
pda_update`). With two motion modes per track (``process_noise = "imm"``), each mode by the same
mixture with its own weights (:func:`imm_update`, docs/jipda.md#two-motion-modes-imm-jipda).
Reported to a fusion centre: the equivalent observation of :func:`equivalent_observation`.
Track management by existence: :func:`derived_rules`, :func:`manage`, :func:`birth_existence`.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.sparse.csgraph import connected_components

from fedtrack.local_filters.imm.filter import IMMState, combine
from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    logsumexp,
    solve_spd,
    spd_inverse_logdet,
    transpose,
)
from fedtrack.local_filters.mtt import association
from fedtrack.local_filters.mtt.associators.events import enumerate_clusters, event_count, k_best_clusters
from fedtrack.local_filters.mtt.associators.gnn import _pair_graph, _rank_in_component
from fedtrack.local_filters.mtt.models import Linearized, Modes, mode_densities, mode_innovations
from fedtrack.local_filters.pda.association import (
    Constants,
    Gated,
    PDAHypotheses,
    PDAParams,
    constants,
    existence_predict,
    log_amplitude_ratio,
    pda_update,
)

# Exact enumeration up to this many joint events per cluster: clusters of one shape cost about
# 0.2 ms per call plus 20-50 ns per event and track (docs/jipda.md), so 5,000 events (6 tracks x 5
# detections, 5 x 6, 4 x 8, 3 x 15, 2 x 69) cost 0.25-1.1 ms a cluster; 6 x 6 (13,327) 4-6 ms,
# 7 x 7 (130,922) 60-110 ms. Beyond, the K_BEST most likely events of a cluster of at most
# K_BEST_MAX_TRACKS tracks (about K_BEST x a assignment problems of a x (a + b)), LM-IPDA for larger.
MAX_EVENTS = 5000
K_BEST = 100
K_BEST_MAX_TRACKS = 12
MIN_CLUTTER_DENSITY = 1e-300  # lambda = 0 (no clutter): every gated detection is some track's


def jipda_constants(pd: float, clutter_density: float, gate_d2: float, m: int, snr: float = 0.0) -> Constants:
    """Paper 001's constants for an ``m``-dimensional measurement gated at ``gate_d2`` (the chi-square
    quantile of the gate probability): ``P_G``, ``C_gamma``, the amplitude threshold ``tau``."""
    return constants(PDAParams(pd=pd, clutter_density=clutter_density, snr=snr, gate=gate_d2), n=m)


def survival(dt: float | np.ndarray, period: float, per_period: float) -> float | np.ndarray:
    """``p11`` over an interval ``dt``: ``per_period ** (dt / period)``, the survival probability
    ``per_period`` of paper 001's chain (``p11`` per scan) compounded over irregular intervals."""
    return per_period ** (np.asarray(dt) / period)


class Pairs(NamedTuple):
    """Gated (track, detection) pairs of one scan with their Gaussian log-likelihoods."""

    rows: np.ndarray  # (K,) track
    cols: np.ndarray  # (K,) detection
    nu: np.ndarray  # (K, m) innovation
    d2: np.ndarray  # (K,) normalized distance squared
    log_n: np.ndarray  # (K,) log N(nu; 0, S_i)


class Association(NamedTuple):
    """Joint association of one scan: per track and per pair."""

    existence: np.ndarray  # (N,) posterior existence mu_i
    beta0: np.ndarray  # (N,) P(no detection is i's | i exists)
    beta: np.ndarray  # (K,) P(j is i's | i exists), per pair
    joint: np.ndarray  # (K,) W_ij = mu_i beta_ij: P(i exists and made j)
    log_lr: np.ndarray  # (N,) logit mu_i - logit mu_bar_i (eq (9)'s log(1 - delta) for a lone track)
    exact: np.ndarray  # (N,) the track's cluster was enumerated (or is the track alone)


def _segment_logsumexp(values: np.ndarray, seg: np.ndarray, n: int) -> np.ndarray:
    """``log sum exp`` of ``values`` per segment id ``seg`` (< n); ``-inf`` for empty segments."""
    top = np.full(n, -np.inf)
    np.maximum.at(top, seg, values)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return safe + np.log(np.bincount(seg, np.exp(values - safe[seg]), minlength=n))


def linear_multitarget(n: int, n_det: int, rows: np.ndarray, cols: np.ndarray, log_target: np.ndarray,
                       mu_bar: np.ndarray, c: Constants) -> tuple[np.ndarray, np.ndarray]:
    """LM-IPDA marginals ``(W_i0 (N,), W_ij (K,))``: each track a single-target IPDA whose clutter
    density at ``j`` is ``lambda + sum_{s != i} p_sj P_sj / (1 - P_sj)`` (``p_sj = N_sj A_j / P_G``);
    exact for a track that shares nothing."""
    lam = max(c.lam, MIN_CLUTTER_DENSITY)
    pdpg = c.pd * c.pg
    with np.errstate(divide="ignore"):
        log_mu = np.log(mu_bar)
        log_not = np.log1p(-mu_bar)
    share = np.exp(log_target - _segment_logsumexp(log_target, rows, n)[rows])
    p = pdpg * mu_bar[rows] * share  # P_sj
    density = np.exp(log_target - np.log(pdpg)) * p / (1.0 - p)  # p_sj P_sj / (1 - P_sj)
    others = np.maximum(np.bincount(cols, density, minlength=n_det)[cols] - density, 0.0)
    log_r = log_target - np.log(lam + others)  # eq (4) term over the clutter density
    log_1md = np.logaddexp(np.log1p(-pdpg), _segment_logsumexp(log_r, rows, n))  # log(1 - delta)
    log_den = np.logaddexp(log_not, log_mu + log_1md)  # log(1 - delta mu_bar)
    return np.exp(np.log1p(-pdpg * mu_bar) - log_den), np.exp(log_mu[rows] + log_r - log_den[rows])


def associate(n_det: int, pairs: Pairs, log_a: np.ndarray, mu_bar: np.ndarray, c: Constants,
              max_events: int = MAX_EVENTS, k_best: int = K_BEST) -> Association:
    """Joint association and existence of ``mu_bar.size`` tracks over one scan of ``n_det``
    detections: ``pairs`` gated, ``log_a`` (n_det,) the detections' log amplitude ratios (zeros
    without amplitudes). Clusters of at most ``max_events`` joint events are enumerated, larger
    ones of at most ``K_BEST_MAX_TRACKS`` tracks summed over their ``k_best`` most likely events,
    the rest approximated by LM-IPDA."""
    n = mu_bar.shape[0]
    rows, cols = pairs.rows, pairs.cols
    log_target = np.log(c.pd) + pairs.log_n + log_a[cols]
    w0, w = linear_multitarget(n, n_det, rows, cols, log_target, mu_bar, c)
    exact = np.ones(n, dtype=bool)
    if rows.size:
        _, label = connected_components(_pair_graph(n, n + n_det, rows, cols), directed=False)
        comp = label[rows]
        local_r, n_r = _rank_in_component(rows, comp, n + n_det)
        local_c, n_c = _rank_in_component(cols, comp, n + n_det)
        shared = np.flatnonzero(n_r[comp] > 1)
        lam = max(c.lam, MIN_CLUTTER_DENSITY)
        with np.errstate(divide="ignore"):
            log_pair = np.log(mu_bar[rows]) + log_target - np.log(lam)
        log_miss = np.log1p(-c.pd * c.pg * mu_bar)
        # the shared pairs by their cluster's shape (a tracks x b detections), then cluster
        sc = comp[shared]
        order = np.lexsort((sc, n_c[sc], n_r[sc]))
        shared, sc = shared[order], sc[order]
        first = np.diff(sc, prepend=-1) != 0  # a cluster's first pair
        shape = n_r[sc] * (n + n_det + 1) + n_c[sc]
        bounds = np.append(np.flatnonzero(np.diff(shape, prepend=-1)), shared.size)
        searched = []  # the pairs of the clusters whose k best events are searched, as one batch
        for start, stop in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
            a, b = int(n_r[sc[start]]), int(n_c[sc[start]])
            sel = shared[start:stop]
            if event_count(a, b) > max_events:
                if a > K_BEST_MAX_TRACKS:
                    exact[rows[sel]] = False  # LM-IPDA's answer stands
                else:
                    searched.append(np.arange(start, stop))
                continue
            k = np.cumsum(first[start:stop]) - 1
            dense, track, miss = _dense_clusters(sel, k, local_r, local_c, rows, log_pair, log_miss, a, b)
            W = enumerate_clusters(dense, miss)
            w[sel] = W[k, local_r[sel], local_c[sel]]
            w0[track] = W[:, :, b]
        if searched:
            at = np.concatenate(searched)
            sel = shared[at]
            a, b = int(n_r[sc[at]].max()), int(n_c[sc[at]].max())
            k = np.cumsum(first[at]) - 1
            dense, track, miss = _dense_clusters(sel, k, local_r, local_c, rows, log_pair, log_miss, a, b)
            W = k_best_clusters(dense, miss, k_best)
            w[sel] = W[k, local_r[sel], local_c[sel]]
            w0[track[track >= 0]] = W[:, :, b][track >= 0]
            exact[rows[sel]] = False
    return _posterior(w0, w, rows, mu_bar, c, exact)


def _dense_clusters(sel: np.ndarray, k: np.ndarray, local_r: np.ndarray, local_c: np.ndarray, rows: np.ndarray,
                    log_pair: np.ndarray, log_miss: np.ndarray, a: int, b: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clusters ``k`` (0, 1, ... in order) of the pairs ``sel`` as one batch of shape ``a x b``
    (smaller ones padded: no gated pair, ``log_miss`` 0): ``log_pair`` (C, a, b) (``-inf`` where
    not gated), each cluster's tracks (C, a) (-1: padding) and their ``log_miss`` (C, a)."""
    n = int(k[-1]) + 1
    dense = np.full((n, a, b), -np.inf)
    dense[k, local_r[sel], local_c[sel]] = log_pair[sel]
    track = np.full((n, a), -1, dtype=np.intp)
    track[k, local_r[sel]] = rows[sel]
    return dense, track, np.where(track >= 0, log_miss[track], 0.0)


def _posterior(w0: np.ndarray, w: np.ndarray, rows: np.ndarray, mu_bar: np.ndarray, c: Constants,
               exact: np.ndarray) -> Association:
    """Existence and conditional association probabilities from the joint marginals."""
    pdpg = c.pd * c.pg
    missed = w0 * mu_bar * (1.0 - pdpg) / (1.0 - pdpg * mu_bar)  # exists, no detection of it
    # the marginals' sum can exceed 1 by a rounding when a track is certain (mu_bar 1): clipped, or
    # the next scan's log(1 - mu_bar) is NaN and the track's existence with it
    mu = np.minimum(missed + np.bincount(rows, w, minlength=mu_bar.shape[0]), 1.0)
    alive = mu > 0.0
    inv = np.divide(1.0, mu, out=np.zeros_like(mu), where=alive)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_lr = np.log(mu) - np.log1p(-mu) - np.log(mu_bar) + np.log1p(-mu_bar)
    return Association(mu, np.where(alive, missed * inv, 1.0), w * inv[rows], w, log_lr, exact)


def _padded(pairs: Pairs, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each track's pairs in slots ``0..k-1``: (track, slot) of every pair and the valid mask (N, k)."""
    order = np.argsort(pairs.rows, kind="stable")
    rows = pairs.rows[order]
    start = np.searchsorted(rows, np.arange(n))
    slot = np.empty_like(order)
    slot[order] = np.arange(rows.size) - start[rows]
    width = int(np.bincount(pairs.rows, minlength=n).max(initial=0))
    valid = np.zeros((n, width), dtype=bool)
    valid[pairs.rows, slot] = True
    return pairs.rows, slot, valid


def update(pred: GaussianState, lin: Linearized, R: np.ndarray, pairs: Pairs, assoc: Association,
           c: Constants, innovation: tuple[np.ndarray, np.ndarray] | None = None) -> GaussianState:
    """Per track, PDA's mixture over its association hypotheses with the spread-of-means term and
    Joseph-form detected components (:func:`pda_update` with the JIPDA weights); ``innovation``:
    the tracks' ``S = H P H' + R`` and ``ln det S`` where the gate computed them."""
    n, m = pred.x.shape[0], R.shape[0]
    if innovation is None:
        S = lin.innovation_covariance(pred.P, R)
        logdet = spd_inverse_logdet(S)[1] if n else np.zeros(0)
    else:
        S, logdet = innovation
    K = transpose(solve_spd(S, lin.times(pred.P))) if n else np.zeros(pred.x.shape + (m,))
    r, slot, valid = _padded(pairs, n)
    nu = np.zeros(valid.shape + (m,))
    nu[r, slot] = pairs.nu
    d2, log_n, beta = np.full(valid.shape, np.inf), np.full(valid.shape, -np.inf), np.zeros(valid.shape)
    d2[r, slot], log_n[r, slot], beta[r, slot] = pairs.d2, pairs.log_n, assoc.beta
    log_vg = c.log_cn + 0.5 * logdet + 0.5 * m * np.log(c.gamma)
    g = Gated(nu, S, K, d2, valid, log_n, log_vg)
    return pda_update(pred, g, PDAHypotheses(assoc.beta0, beta, assoc.log_lr), c, joseph=(lin.H, R))


def mode_posteriors(log_n: np.ndarray, rows: np.ndarray, mu: np.ndarray, beta0: np.ndarray, beta: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """IMM-JIPDA's mode probabilities and each mode's association weights
    (docs/jipda.md#two-motion-modes-imm-jipda): a detection's mode posterior
    ``pi_j|i = mu_j N_j(z_i) / sum_l mu_l N_l(z_i)`` (``log_n`` (K, k): ``ln N_j`` of each pair and
    mode; ``mu`` (N, k) the predicted mode probabilities), a miss's ``pi_j|0 = mu_j``;
    ``mu_j+ = beta_0 mu_j + sum_i beta_i pi_j|i`` and ``beta_i|j = beta_i pi_j|i / mu_j+``
    (``beta_i`` where ``mu_j+ = 0``: the mode is never read).
    Returns ``mu+`` (N, k), normalized, and ``beta_i|j`` (K, k); ``beta_0|j = 1 - sum_i beta_i|j``."""
    with np.errstate(divide="ignore"):
        log_w = np.log(mu[rows]) + log_n
    pi = np.exp(log_w - logsumexp(log_w, axis=-1, keepdims=True))
    post = beta0[:, None] * mu
    np.add.at(post, rows, beta[:, None] * pi)
    weights = np.divide(beta[:, None] * pi, post[rows], out=np.repeat(beta[:, None], mu.shape[1], axis=1),
                        where=post[rows] > 0.0)
    return post / post.sum(axis=1, keepdims=True), weights


def imm_update(modes: Modes, x0: np.ndarray, lin: Linearized, R: np.ndarray, pairs: Pairs, assoc: Association,
               c: Constants) -> tuple[Modes, GaussianState]:
    """IMM-JIPDA's update of tracks with ``k`` motion modes (``modes``: each mode's prediction, of
    which ``x0`` (N, D) is the combination, where ``lin`` and ``pairs`` were computed): mode ``j``
    sees pair ``i`` with the innovation ``nu_i + H (x0 - x_j)`` and ``S_j = H P_j H' + R``
    (:func:`mode_posteriors` weighs the events per mode), and each mode is updated by :func:`update`
    (the PDA mixture) with its own weights, the ``N k`` modes as one batch. Returns the updated
    modes and their combination (the tracks' ``x``, ``P``)."""
    n, k, d = modes.x.shape
    flat = GaussianState(modes.x.reshape(n * k, d), modes.P.reshape(n * k, d, d))
    mi = mode_innovations(modes, x0, lin, R)
    rows, nu, d2, log_n = mode_densities(mi, pairs.rows, pairs.nu)  # mode j of track t: row t k + j
    mu, beta = mode_posteriors(log_n.reshape(-1, k), pairs.rows, modes.mu, assoc.beta0, assoc.beta)
    per_mode = from_weights(rows, beta.ravel(), np.repeat(assoc.existence, k))
    post = update(flat, mi.at, R, Pairs(rows, np.repeat(pairs.cols, k), nu, d2, log_n), per_mode, c,
                  (mi.S, mi.logdet))
    out = Modes(post.x.reshape(n, k, d), post.P.reshape(n, k, d, d), mu)
    return out, combine(IMMState(*out))


# A track reports an observation when it more likely than not made one of the scan's detections
# (1 - beta_0 >= 1/2), as a hard associator reports the tracks it assigned: a track that merely
# has clutter in a wide gate keeps no central track alive at a track-to-track centre.
REPORT_DETECTED = 0.5


def equivalent_observation(pred: GaussianState, lin: Linearized, R: np.ndarray, pairs: Pairs,
                           assoc: Association) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """What a soft association reports to a fusion centre: for each track that more likely than
    not exists and made one of the scan's detections, ``mu (1 - beta_0) >= REPORT_DETECTED``, the
    observation ``z ~ N(H x, R_eq)`` whose Kalman update from the prediction gives PDA's mean:
    ``z = H x_bar + nu_c / (1 - beta_0)`` (``nu_c = sum_j beta_j nu_j``),
    ``R_eq = (R + beta_0 H P_bar H') / (1 - beta_0)`` (so ``H P_bar H' + R_eq = S / (1 - beta_0)``).
    Its covariance update lacks the spread-of-means and missed-gate terms of PDA's (docs/jipda.md).
    Returns the mask of the tracks that report and their observations ``(H, R_eq, z)``."""
    n, m = pred.x.shape[0], R.shape[0]
    weighted = assoc.beta[:, None] * pairs.nu
    nu_c = np.stack([np.bincount(pairs.rows, weighted[:, j], minlength=n) for j in range(m)], axis=1)
    hit = 1.0 - assoc.beta0
    rep = np.flatnonzero(assoc.existence * hit >= REPORT_DETECTED)
    f = hit[rep, None, None]
    R_eq = (R + assoc.beta0[rep, None, None] * lin.covariance(pred.P[rep], rep)) / f
    z = lin.mean(pred.x[rep], rep) + nu_c[rep] / hit[rep, None]
    mask = np.zeros(n, dtype=bool)
    mask[rep] = True
    return mask, (lin.H[rep], 0.5 * (R_eq + transpose(R_eq)), z)


# A target's mean stay in a tracker's picture (its birth to its death or exit), the documented
# assumption behind the survival probability (docs/jipda.md#track-management): targets leave at the
# constant rate 1 / MEAN_LIFETIME, so p11 = exp(-dt / MEAN_LIFETIME) over any interval dt; a factor
# of 1 / (1 - P_D P_G) in it (10 at P_D 0.9) moves the tracks' hide and delete decisions by one miss.
MEAN_LIFETIME = 600.0
SURVIVAL_PER_SECOND = math.exp(-1.0 / MEAN_LIFETIME)
SNR = PDAParams().snr  # paper 001's mean target SNR, for scans whose detections carry amplitudes


@lru_cache(maxsize=64)
def scan_constants(pd: float, clutter_density: float, gate_d2: float, m: int) -> Constants:
    """The constants of one scan of the tracker (:func:`jipda_constants` with :data:`SNR`; jipda's
    and mht's: ``P_G``, ``C_gamma``, the amplitude threshold ``tau``)."""
    return jipda_constants(pd, clutter_density, gate_d2, m, SNR)


def predicted_existence(mu: np.ndarray, dt: float) -> np.ndarray:
    """Existence probabilities ``mu`` predicted over ``dt`` [s] (survival ``p11`` of :func:`survival`)."""
    return existence_predict(mu, survival(dt, 1.0, SURVIVAL_PER_SECOND), 0.0)


def associate_scan(inp: association.AssociationInput) -> association.Association:
    """The tracker's associate role: existence predicted over ``inp.dt`` (:func:`survival`), the
    joint association, and the tracker's view of it (every gated pair with its ``beta_ij``; a
    detection is claimed, so starts no track, when the tracks' joint probability of having made it
    is at least 1/2)."""
    c = scan_constants(inp.pd, inp.clutter_density, inp.gate_d2, inp.dim)
    mu = np.full(inp.n_tracks, BIRTH_EXISTENCE) if inp.existence is None else inp.existence
    mu_bar = predicted_existence(mu, inp.dt)
    pairs = Pairs(inp.rows, inp.cols, np.zeros((inp.rows.size, inp.dim)), np.zeros(inp.rows.size), inp.log_likelihood)
    log_a = np.zeros(inp.n_detections) if inp.amplitude is None else log_amplitude_ratio(inp.amplitude, c)
    assoc = associate(inp.n_detections, pairs, log_a, mu_bar, c)
    free = unclaimed(inp.n_detections, inp.cols, assoc)
    claimed = free <= 0.5
    existence = assoc.existence
    if inp.blind is not None:  # a sensor's miss of a track it may not see: only the survival
        existence = np.where(inp.blind, mu_bar, existence)
    return association.Association(np.arange(inp.rows.size), assoc.beta, claimed, existence, None,
                                   birth_existence(free, int(np.sum(~claimed))))


def from_weights(rows: np.ndarray, beta: np.ndarray, existence: np.ndarray) -> Association:
    """The association the update needs, from the tracker's view of :func:`associate_scan`."""
    beta0 = np.clip(1.0 - np.bincount(rows, beta, minlength=existence.shape[0]), 0.0, 1.0)
    return Association(existence, beta0, beta, existence[rows] * beta, np.zeros_like(existence),
                       np.ones(existence.shape, dtype=bool))


def unclaimed(n_det: int, cols: np.ndarray, assoc: Association) -> np.ndarray:
    """``1 - sum_i W_ij`` (M,): the probability that no existing track made detection ``j``."""
    return np.clip(1.0 - np.bincount(cols, assoc.joint, minlength=n_det), 0.0, 1.0)


# Track management by existence (docs/jipda.md#track-management).
BIRTH_EXISTENCE = 0.1  # prior probability that a scan's unclaimed detections hold a new target
FALSE_CONFIRM = 0.01  # alpha: P(a track born on one scan's clutter is ever confirmed), per scan
LOST_TRUE = 0.01  # beta: P(a true target gives the run of misses that deletes a lone new track)


# A confirmed track stays in the picture while it more likely than not exists: GOSPA with alpha = 2
# charges a false and a missed target alike (c^p / 2), so showing a track of existence mu costs
# (1 - mu) c^p / 2 and hiding it mu c^p / 2 (its localisation error aside).
SHOW = 0.5


class ExistenceRules(NamedTuple):
    birth: float  # prior existence of a lone new track (see birth_existence)
    confirm: float  # confirmed once existence >= confirm
    delete: float  # deleted once existence < delete
    show: float = SHOW  # a confirmed track stays confirmed while existence >= show


def _odds(p: float) -> float:
    return p / (1.0 - p)


def _prob(o: float) -> float:
    return o / (1.0 + o)


def derived_rules(pd: float, pg: float, birth: float = BIRTH_EXISTENCE, false_confirm: float = FALSE_CONFIRM,
                  lost: float = LOST_TRUE) -> ExistenceRules:
    """Thresholds from ``P_D`` and ``P_G``. Confirm at odds ``odds(birth) / false_confirm``: under
    clutter alone a track's existence odds over its birth odds ``o_j`` is a non-negative
    supermartingale of mean at most 1 (the likelihood ratio of eq (9) has mean 1, survival only
    lowers it), so by Ville's inequality it ever reaches the threshold with probability at most
    ``o_j / odds_c``; a scan's births share ``odds(birth)`` (:func:`birth_existence`), so the
    scan confirms a clutter track with probability at most ``false_confirm``. Delete below odds
    ``odds(birth) (1 - P_D P_G)^k``, ``k`` the fewest misses in a row a target gives with
    probability at most ``lost`` (each miss multiplies the odds by ``1 - P_D P_G``): a lone new
    track dies after ``k`` misses (one of ``B`` births after ``log B / log(1/(1 - P_D P_G))``
    fewer), a confirmed one after about ``k + log(1/false_confirm) / log(1/(1 - P_D P_G))``."""
    miss = 1.0 - pd * pg
    k = max(1, math.ceil(math.log(lost) / math.log(miss)))
    return ExistenceRules(birth, _prob(_odds(birth) / false_confirm), _prob(_odds(birth) * miss**k))


def manage(existence: np.ndarray, confirmed: np.ndarray, rules: ExistenceRules) -> tuple[np.ndarray, np.ndarray]:
    """Confirmed after this scan (existence reached ``confirm``, or the track was confirmed and its
    existence is still at least ``show``: a confirmed track that falls below goes back to
    tentative, out of the picture, until it reaches ``confirm`` again), and kept (existence not
    below the deletion threshold)."""
    return (existence >= rules.confirm) | (confirmed & (existence >= rules.show)), existence >= rules.delete


def birth_existence(unclaimed: np.ndarray, births: int, birth: float = BIRTH_EXISTENCE) -> np.ndarray:
    """Prior existence of the tracks started on each detection: the prior odds ``odds(birth)`` that
    the scan holds a new target, shared by its ``births`` unclaimed detections, times the
    probability that no existing track made the detection. Sharing the odds keeps the false
    confirmations per scan (not per birth) below ``FALSE_CONFIRM`` however many detections start
    tracks (Ville's bound, :func:`derived_rules`)."""
    odds = _odds(birth) * unclaimed / max(births, 1)
    return odds / (1.0 + odds)
