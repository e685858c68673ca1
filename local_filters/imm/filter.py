"""Interacting multiple model (IMM) estimators over mode-conditioned CV Kalman filters.

Paper 000 (Choi & Song, "The activation-only VSIMM algorithm for maneuvering target
tracking") with the corrected standard forms of its errata (docs/papers.md):

* Each mode ``m`` is a CV Kalman filter whose prediction carries the mode's known
  acceleration: ``x(k|k-1) = F x0 + G a_m`` (eqs. (7), (9); errata "+ G a_m").
* Mode probabilities (eq. (1)) are normalized in log space (logsumexp of
  ``log mu(k|k-1) + log L``); the transition matrix is row-stochastic, row = "from".
* Mixing (eqs. (5), (6)) uses the *updated* covariance of each source model
  (errata: (6) prints the mixed one). Predicted probabilities of a target set that does
  not hold every model lose the mass of the missing ones (eq. (3)); the posterior is
  renormalized over the active set (errata).

Three estimators share one IMM cycle (:func:`model_cycle`):

* **FSIMM** (:func:`fsimm_step`): all models, every step.
* **VSIMM** by model-group switching (paper 000 section 2; Li, Zhi & Zhang parts III/IV):
  a single group runs until the activation logic fires; then the union of the old group
  ``M_o`` and the activated group ``M_a`` runs until the termination logic drops one.
* **Activation-only VSIMM** (paper 000 section 3): the activation logic of section 4.1
  fires, the new models are initialized by eqs. (2)-(6) and the cycle at ``k`` is
  re-run over ``M_a`` alone; ``M_o`` is dropped at once.

Activation logic (paper 000 section 4.1, rules (1)/(2)), stated generally: every group has
a *centre* model (its first model). While group ``g`` runs alone, if the model with the
largest likelihood in ``g`` is the centre of another group ``h`` and its posterior
probability exceeds ``t_a``, then ``h`` is activated. With the groups (10) this is exactly
rule (1) (from ``M_1`` to ``M_j`` via ``m_j``) and rule (2) (from ``M_j`` back to ``M_1``
via ``m_1``).

VSIMM termination (paper 000 eq. (8) and the text above it). Group probability
``mu^G = sum_{i in G} mu_k^i`` over the union (shared models count for both groups);
group likelihood ``L^G = sum_{i in G} mu(k|k-1)^i L^i / sum_{i in G} mu(k|k-1)^i``;
products of likelihood ratios are kept as log sums from the activation instant ``k0``.
The printed statistic ``t^mu = mu^{M_o} / mu^{M_a}`` with "terminate ``M_a`` when it is
small" reads backwards (a small ratio favours ``M_a``), and thresholds 0.85/0.93 below
one fit a probability, not a ratio. Two rules are implemented (``Thresholds.rule``):

* ``group-probability`` (default, our reading): ``t^mu = mu^{M_a}`` and
  ``t^L = prod L^{M_a} / L^{M_o}``; terminate ``M_o`` if ``t^mu > t_2^mu`` and
  ``t^L > t_2^L``; terminate ``M_a`` if ``t^mu < t_1^mu`` and ``t^L < t_1^L``.
* ``as-printed``: ``t^mu = mu^{M_o} / mu^{M_a}`` and ``t^L = prod L^{M_o} / L^{M_a}``;
  terminate ``M_a`` if ``t^mu < t_1^mu`` and ``t^L < t_1^L``; terminate ``M_o`` if
  ``t^mu > t_2^mu`` and ``t^L > t_2^L`` (literally the paper's text).

Otherwise the union keeps running. The test also runs at the activation instant ``k0``.
While the union runs the activation logic is suspended (paper 000 section 2, third
property).

All maths is batched over a leading axis (Monte Carlo runs). The variable-structure
filters keep a *dense* per-run record over the whole model set (models not running have
``mu = 0``) and each step runs, in one batched cycle, the runs whose active sets have the
same size, with per-run model indices; so the work done is proportional to the number of
models actually run.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple, TypeVar

import numpy as np

from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    log_likelihood,
    logsumexp,
    predict,
    symmetrize,
    update,
)
from fedtrack.local_filters.linear.models import LinearModel

FSIMM = "fsimm"
VSIMM = "vsimm"
AO_VSIMM = "ao-vsimm"
ALGORITHMS = (FSIMM, VSIMM, AO_VSIMM)

_Rec = TypeVar("_Rec")  # a record of arrays (IMMState, Cycle, GaussianState) or an array
NO_GROUP = -1
KEEP_UNION, DROP_OLD, DROP_NEW = 0, 1, 2
GROUP_PROBABILITY = "group-probability"  # our corrected reading of the termination rule
AS_PRINTED = "as-printed"  # paper 000 eq. (8) and the text above it, literally
TERMINATION_RULES = (GROUP_PROBABILITY, AS_PRINTED)


class ModelBank(NamedTuple):
    """The mode set: names, accelerations ``(N, 2)``, transition matrix ``(N, N)`` (row = from),
    groups as tuples of model indices (first = centre) and their names; ``member (G, N)``
    and ``centre (N,)`` (group whose centre each model is, or ``NO_GROUP``) are derived by
    :func:`make_bank`."""

    names: tuple[str, ...]
    acc: np.ndarray
    Pi: np.ndarray
    groups: tuple[tuple[int, ...], ...]
    group_names: tuple[str, ...]
    member: np.ndarray
    centre: np.ndarray

    @property
    def size(self) -> int:
        return len(self.names)


# A fractional power from the eigen-decomposition errs by about cond(V) * 2.2e-16; beyond this
# condition number (a nearly defective matrix) that would exceed 1e-8 of a probability.
MAX_EIGENVECTOR_CONDITION = 1e8


@lru_cache(maxsize=16)
def _eigen(key: bytes, n: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Eigenvalues and eigenvectors of the ``n x n`` matrix stored in ``key``, or ``None`` when
    the eigenvectors are too ill-conditioned for a power through them (cached per matrix)."""
    lam, V = np.linalg.eig(np.frombuffer(key).reshape(n, n))
    return (lam, V) if np.linalg.cond(V) <= MAX_EIGENVECTOR_CONDITION else None


def transition_over(Pi: np.ndarray, steps: float) -> np.ndarray:
    """The mode transition matrix over ``steps`` nominal intervals: ``Pi^steps``.

    An integer power is exact (a Markov chain sampled ``steps`` times); a fractional one is
    ``V diag(lambda^steps) V^-1`` from the matrix's eigen-decomposition, computed once per matrix
    (scipy's Schur-Pade ``fractional_matrix_power``, 25 ms a call at 13 modes, for a nearly
    defective one), with round-off imaginary parts and tiny negative entries removed and every
    row renormalized to sum to one. ``steps = 0`` (repeated timestamps) gives the identity.
    """
    if steps == 1.0:
        return Pi
    if float(steps).is_integer():
        return np.linalg.matrix_power(Pi, int(steps))
    Pi = np.ascontiguousarray(Pi, dtype=float)
    eig = _eigen(Pi.tobytes(), Pi.shape[0])
    if eig is None:
        from scipy.linalg import fractional_matrix_power

        power = fractional_matrix_power(Pi, steps)
    else:
        lam, V = eig
        power = np.linalg.solve(V.T, (V * lam.astype(complex) ** steps).T).T
    out = np.clip(np.real(power), 0.0, None)
    return out / out.sum(axis=1, keepdims=True)


def make_bank(names: tuple[str, ...], acc: np.ndarray, Pi: np.ndarray,
              groups: tuple[tuple[int, ...], ...], group_names: tuple[str, ...]) -> ModelBank:
    """A :class:`ModelBank` with its membership and centre tables."""
    member = np.zeros((len(groups), len(names)), dtype=bool)
    centre = np.full(len(names), NO_GROUP)
    for g, models in enumerate(groups):
        member[g, list(models)] = True
        centre[models[0]] = g
    return ModelBank(names, acc, Pi, groups, group_names, member, centre)


class Thresholds(NamedTuple):
    """Activation ``t_a``, VSIMM termination thresholds (paper 000 eq. (8)) and termination rule."""

    t_a: float = 0.4
    mu_low: float = 0.85
    mu_high: float = 0.93
    lr_low: float = 0.9
    lr_high: float = 1.0
    rule: str = GROUP_PROBABILITY


class IMMState(NamedTuple):
    """Mode-conditioned posteriors ``x (..., M, n)``, ``P (..., M, n, n)`` and probabilities ``mu (..., M)``."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray


class Cycle(NamedTuple):
    """One IMM cycle for a target model set, before normalization of the mode probabilities.

    ``log_pred``: log of ``mu(k|k-1)`` (eq. (1) third line / eq. (3)); ``log_lik``: ``log L_k``.
    """

    post: GaussianState
    log_pred: np.ndarray
    log_lik: np.ndarray


class VSState(NamedTuple):
    """Per-run record of a variable-structure IMM over the whole model set.

    ``x``, ``P``, ``mu`` are dense over all ``N`` models (inactive models have ``mu = 0``
    and their ``x``, ``P`` are never read); ``old``
    and ``new`` (``(R,)`` ints) are the running group and the activated group
    (``NO_GROUP`` when a single group runs); ``log_lr`` is ``log t^L`` since activation.
    """

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    old: np.ndarray
    new: np.ndarray
    log_lr: np.ndarray


class StepOutput(NamedTuple):
    """Per-run outputs of one step: combined estimate, acceleration estimate ``sum mu_i a_i``,
    dense mode probabilities, the group(s) the estimate came from and models run."""

    est: GaussianState
    acc: np.ndarray
    mu: np.ndarray
    old: np.ndarray
    new: np.ndarray
    models_run: np.ndarray


def mode_inputs(model: LinearModel, acc: np.ndarray) -> np.ndarray:
    """``G a_m`` for every mode, ``(N, n)`` (paper 000 eq. (7): the noise mean is the mode)."""
    return acc @ model.G.T


# ---------------------------------------------------------------------------- IMM cycle


def mix(state: IMMState, Pi: np.ndarray) -> tuple[GaussianState, np.ndarray]:
    """Mixing for target models from source models, ``Pi (Ms, Md)`` (rows = sources).

    Returns the mixed initial conditions ``(..., Md)`` (eqs. (5), (6) with the updated
    source covariances) and ``log mu(k|k-1)`` (eqs. (1), (3)). A target no source can
    reach (``E_n`` of eq. (4) empty) gets probability zero and the unconditional mixture.
    """
    w = Pi * state.mu[..., :, None]  # (..., Ms, Md), pi_ji mu_j
    c = w.sum(axis=-2)  # eq. (3)
    reachable = c > 0.0
    if reachable.all():
        w = w / c[..., None, :]  # eq. (5) mixing weights mu^{j|i}
    else:
        w = np.where(reachable[..., None, :], w / np.where(reachable, c, 1.0)[..., None, :],
                     state.mu[..., :, None])
    if w.shape[-2:] == (2, 2):  # two modes (the multi-target trackers')
        x0, P0 = _mix_two(w, state.x, state.P)
    else:
        x0 = np.einsum("...ji,...jn->...in", w, state.x)  # eq. (5)
        d = state.x[..., :, None, :] - x0[..., None, :, :]  # (..., Ms, Md, n)
        P0 = symmetrize(np.einsum("...ji,...jab->...iab", w, state.P)
                        + np.einsum("...ji,...jia,...jib->...iab", w, d, d))  # eq. (6)
    with np.errstate(divide="ignore"):
        log_pred = np.log(c)
    return GaussianState(x0, P0), log_pred


def _batch_last(a: np.ndarray, lead: int) -> np.ndarray:
    """``a``'s ``lead`` leading axes flattened into one and moved last, contiguous."""
    flat = a.reshape((-1,) + a.shape[lead:])
    return np.ascontiguousarray(flat.transpose(tuple(range(1, flat.ndim)) + (0,)))


def _batch_first(a: np.ndarray, lead: tuple[int, ...]) -> np.ndarray:
    """The inverse of :func:`_batch_last`: the last axis back in front as the ``lead`` axes."""
    return np.ascontiguousarray(a.transpose((a.ndim - 1,) + tuple(range(a.ndim - 1)))).reshape(lead + a.shape[:-1])


def _mix_two(w: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (5), (6) for two source and two target modes (``P0`` symmetrized): the sums of :func:`mix`'s
    einsums, term by term in their order (bit-identical), computed with the batch as the last,
    contiguous axis, a faster pass over a thousand tracks than over 2x4x4 blocks."""
    lead = x.shape[:-2]
    wT, xT, PT = _batch_last(w, len(lead)), _batch_last(x, len(lead)), _batch_last(P, len(lead))
    x0 = wT[0, :, None] * xT[0, None] + wT[1, :, None] * xT[1, None]  # (i, a, k), eq. (5)
    d = xT[:, None] - x0[None]  # (j, i, a, k)
    wd = wT[:, :, None] * d  # the products in einsum's order: (w d_a) d_b
    P0 = ((wT[0, :, None, None] * PT[0, None] + wT[1, :, None, None] * PT[1, None])
          + (wd[0, :, :, None] * d[0, :, None] + wd[1, :, :, None] * d[1, :, None]))  # (i, a, b, k), eq. (6)
    return _batch_first(x0, lead), _batch_first(0.5 * (P0 + P0.swapaxes(1, 2)), lead)  # symmetrize()


def model_cycle(state: IMMState, Pi: np.ndarray, u: np.ndarray, model: LinearModel,
                z: np.ndarray, R: np.ndarray) -> Cycle:
    """Mix, predict with ``+ G a_m`` (``u (Md, n)`` or per run ``(R, Md, n)``) and update
    every target model with ``z (..., 2)``."""
    mixed, log_pred = mix(state, Pi)  # Pi may be per run, (R, Ms, Md)
    pred = predict(mixed, model.F, model.Q, u_effect=u)  # eq. (7) with the mode as noise mean
    post, inn = update(pred, z[..., None, :], model.H, R[..., None, :, :] if R.ndim > 2 else R)
    return Cycle(post, log_pred, log_likelihood(inn))  # L_k^i = N(nu; 0, S^i), eq. (1)


def join(a: Cycle, b: Cycle, order: np.ndarray) -> Cycle:
    """Concatenate two cycles along the model axis and pick ``order (R, M)`` per run."""
    x = np.concatenate([a.post.x, b.post.x], axis=-2)
    P = np.concatenate([a.post.P, b.post.P], axis=-3)
    lp = np.concatenate([a.log_pred, b.log_pred], axis=-1)
    ll = np.concatenate([a.log_lik, b.log_lik], axis=-1)
    return Cycle(GaussianState(np.take_along_axis(x, order[..., None], axis=-2),
                               np.take_along_axis(P, order[..., None, None], axis=-3)),
                 np.take_along_axis(lp, order, axis=-1), np.take_along_axis(ll, order, axis=-1))


def posterior(c: Cycle) -> IMMState:
    """Mode probabilities of eq. (1), normalized over the cycle's models in log space."""
    log_w = c.log_pred + c.log_lik
    log_mu = log_w - logsumexp(log_w, axis=-1, keepdims=True)
    return IMMState(c.post.x, c.post.P, np.exp(log_mu))


def combine(state: IMMState) -> GaussianState:
    """Overall estimate ``x = sum mu_i x_i``, ``P = sum mu_i (P_i + d_i d_i')``."""
    if state.mu.shape[-1] == 2:  # two modes: the einsums' sums term by term, the batch last (as _mix_two)
        lead = state.x.shape[:-2]
        muT, xT, PT = (_batch_last(a, len(lead)) for a in (state.mu, state.x, state.P))
        xc = muT[0] * xT[0] + muT[1] * xT[1]  # (a, k)
        d = xT - xc[None]
        S = PT + d[:, :, None] * d[:, None]  # (i, a, b, k)
        P = muT[0] * S[0] + muT[1] * S[1]
        return GaussianState(_batch_first(xc, lead), _batch_first(0.5 * (P + P.swapaxes(0, 1)), lead))  # symmetrize()
    x = np.einsum("...i,...in->...n", state.mu, state.x)
    d = state.x - x[..., None, :]
    P = np.einsum("...i,...iab->...ab", state.mu, state.P + d[..., :, None] * d[..., None, :])
    return GaussianState(x, symmetrize(P))


def fsimm_step(state: IMMState, Pi: np.ndarray, u: np.ndarray, model: LinearModel,
               z: np.ndarray, R: np.ndarray) -> IMMState:
    """One FSIMM cycle over the fixed model set (paper 000 eq. (1))."""
    return posterior(model_cycle(state, Pi, u, model, z, R))


# ------------------------------------------------------------------ variable structure


@lru_cache(maxsize=None)
def _active(groups: tuple[tuple[int, ...], ...], old: int, new: int) -> np.ndarray:
    members = set(groups[old]) | (set(groups[new]) if new != NO_GROUP else set())
    out = np.array(sorted(members), dtype=int)
    out.flags.writeable = False
    return out


def active_models(bank: ModelBank, old: int, new: int) -> np.ndarray:
    """Sorted model indices of group ``old`` (union with group ``new`` when activated)."""
    return _active(bank.groups, old, new)


@lru_cache(maxsize=None)
def _switch(groups: tuple[tuple[int, ...], ...], old: int, target: int,
            union: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Models to initialize, the final set and its positions in ``[running, fresh]``."""
    running = _active(groups, old, NO_GROUP)
    fresh = np.array(sorted(set(groups[target]) - set(running.tolist())), dtype=int)
    final = _active(groups, target, old if union else NO_GROUP)
    slot = {int(m): i for i, m in enumerate(np.concatenate([running, fresh]))}
    order = np.array([slot[int(m)] for m in final], dtype=int)
    for a in (fresh, order):
        a.flags.writeable = False
    return fresh, final, order


def initial_vs(bank: ModelBank, group: int, x0: np.ndarray, P0: np.ndarray) -> VSState:
    """All runs start in ``group`` with uniform mode probabilities over it."""
    R, n = x0.shape
    idx = active_models(bank, group, NO_GROUP)
    x = np.repeat(x0[:, None], bank.size, axis=1)
    P = np.repeat(P0[:, None], bank.size, axis=1)
    mu = np.zeros((R, bank.size))
    mu[:, idx] = 1.0 / idx.size
    return VSState(x, P, mu, np.full(R, group), np.full(R, NO_GROUP), np.zeros(R))


def group_log_likelihood(c: Cycle, member: np.ndarray) -> np.ndarray:
    """``log L^G``: the group's mixture likelihood ``sum mu(k|k-1) L / sum mu(k|k-1)`` over ``member``."""
    lp = np.where(member, c.log_pred, -np.inf)
    return logsumexp(lp + c.log_lik, axis=-1) - logsumexp(lp, axis=-1)


def termination(c: Cycle, post: IMMState, in_old: np.ndarray, in_new: np.ndarray,
                log_lr: np.ndarray, th: Thresholds) -> tuple[np.ndarray, np.ndarray]:
    """VSIMM termination test (paper 000 eq. (8)); see the module docstring for the two rules.

    ``log_lr`` accumulates ``log prod L^{M_a} / L^{M_o}`` since activation. Returns it
    updated and the decision ``KEEP_UNION``/``DROP_OLD``/``DROP_NEW`` per run.
    """
    log_lr = log_lr + group_log_likelihood(c, in_new) - group_log_likelihood(c, in_old)
    p_new = np.sum(np.where(in_new, post.mu, 0.0), axis=-1)
    if th.rule == AS_PRINTED:  # t^mu = mu^{M_o} / mu^{M_a}, t^L = prod L^{M_o} / L^{M_a}
        t_mu = np.sum(np.where(in_old, post.mu, 0.0), axis=-1) / p_new
        drop_new = (t_mu < th.mu_low) & (-log_lr < np.log(th.lr_low))
        drop_old = (t_mu > th.mu_high) & (-log_lr > np.log(th.lr_high))
    else:  # t^mu = P(M_a), t^L = prod L^{M_a} / L^{M_o}
        drop_old = (p_new > th.mu_high) & (log_lr > np.log(th.lr_high))
        drop_new = (p_new < th.mu_low) & (log_lr < np.log(th.lr_low))
    decision = np.where(drop_old, DROP_OLD, np.where(drop_new, DROP_NEW, KEEP_UNION))
    return log_lr, decision


def activation(bank: ModelBank, idx: np.ndarray, current: np.ndarray, c: Cycle, post: IMMState,
               t_a: float) -> np.ndarray:
    """Activation rules (1)/(2) of paper 000 section 4.1: the group to activate per run, or ``NO_GROUP``.

    ``idx (R, M)`` are the running models, ``current (R,)`` the running group.
    """
    best = np.argmax(c.log_lik, axis=-1)[:, None]  # likelihood condition
    cand = bank.centre[np.take_along_axis(idx, best, axis=-1)[:, 0]]
    mu_best = np.take_along_axis(post.mu, best, axis=-1)[:, 0]
    fire = (cand != NO_GROUP) & (cand != current) & (mu_best > t_a)  # probability condition
    return np.where(fire, cand, NO_GROUP)


def _rows(a: _Rec, sel: np.ndarray | slice) -> _Rec:
    """Select runs ``sel`` of a (nested) record of arrays."""
    if isinstance(a, np.ndarray):
        return a[sel]  # type: ignore[return-value]
    return type(a)(*(_rows(f, sel) for f in a))  # type: ignore[arg-type]


class _Writer:
    """Collects the per-run results of one variable-structure step into fresh arrays."""

    def __init__(self, bank: ModelBank, s: VSState) -> None:
        R, _, n = s.x.shape
        self.bank = bank
        # x, P of models outside the next active set are never read: no need to copy them
        self.state = VSState(np.empty_like(s.x), np.empty_like(s.P), np.zeros_like(s.mu),
                             s.old.copy(), s.new.copy(), s.log_lr.copy())
        self.out = StepOutput(GaussianState(np.zeros((R, n)), np.zeros((R, n, n))),
                              np.zeros((R, 2)), np.zeros_like(s.mu), s.old.copy(), s.new.copy(),
                              np.zeros(R, dtype=int))

    def output(self, rows: np.ndarray, idx: np.ndarray, post: IMMState, old: np.ndarray,
               new: np.ndarray, run: int) -> None:
        """The estimate at ``k`` for ``rows`` from ``post`` over models ``idx (b, M)``."""
        est = combine(post)
        o = self.out
        o.est.x[rows], o.est.P[rows] = est.x, est.P
        o.acc[rows] = np.einsum("bi,bia->ba", post.mu, self.bank.acc[idx])
        o.mu[rows] = 0.0  # an activation re-writes the step's output over a different set
        o.mu[rows[:, None], idx] = post.mu
        o.old[rows], o.new[rows], o.models_run[rows] = old, new, run

    def keep(self, rows: np.ndarray, idx: np.ndarray, post: IMMState, keep: np.ndarray,
             old: np.ndarray, new: np.ndarray) -> None:
        """Store ``post`` for the next step, dropping the models outside ``keep (b, M)`` (eq. (3) renormalized)."""
        mu = np.where(keep, post.mu, 0.0)
        st = self.state
        st.x[rows[:, None], idx] = post.x
        st.P[rows[:, None], idx] = post.P
        st.mu[rows[:, None], idx] = mu / mu.sum(axis=-1, keepdims=True)
        st.old[rows], st.new[rows] = old, new


def _terminate(w: _Writer, rows: np.ndarray, idx: np.ndarray, c: Cycle,
               post: IMMState, old: np.ndarray, new: np.ndarray, log_lr: np.ndarray,
               th: Thresholds) -> None:
    """Apply the termination test to union runs ``rows`` and store their next-step records."""
    in_old = w.bank.member[old[:, None], idx]
    in_new = w.bank.member[new[:, None], idx]
    log_lr, decision = termination(c, post, in_old, in_new, log_lr, th)
    keep = np.where((decision == DROP_OLD)[:, None], in_new,
                    np.where((decision == DROP_NEW)[:, None], in_old, True))
    nxt_old = np.where(decision == DROP_OLD, new, old)
    nxt_new = np.where(decision == KEEP_UNION, new, NO_GROUP)
    w.keep(rows, idx, post, keep, nxt_old, nxt_new)
    w.state.log_lr[rows] = np.where(decision == KEEP_UNION, log_lr, 0.0)


def _activate(bank: ModelBank, algorithm: str, w: _Writer, rows: np.ndarray, idx: np.ndarray,
              prev: IMMState, c: Cycle, fire: np.ndarray, old: np.ndarray, target: np.ndarray,
              Pi: np.ndarray, u: np.ndarray, model: LinearModel, z: np.ndarray, R: np.ndarray,
              th: Thresholds) -> None:
    """Initialize the newly activated models (eqs. (2)-(6)) and re-run the cycle at ``k``.

    Models shared with the running group keep their cycle (paper 000: no computation is
    needed for them); only ``M_n = M_a minus M_o`` is run, from the running group's
    posterior at ``k-1``. Activation-only VSIMM keeps ``M_a`` alone; VSIMM runs the union
    and applies the termination test at once. Runs are batched by the sizes of ``M_n``
    and of the final set.
    """
    pairs = {(o, g): _switch(bank.groups, o, g, algorithm == VSIMM)
             for o, g in set(zip(old[fire].tolist(), target[fire].tolist()))}
    batches: dict[tuple[int, int], list[int]] = {}
    for r in fire.tolist():
        fresh, final, _ = pairs[(int(old[r]), int(target[r]))]
        batches.setdefault((fresh.size, final.size), []).append(r)
    for (n_fresh, _), members in batches.items():
        sel = np.array(members)
        keys = list(zip(old[sel].tolist(), target[sel].tolist()))
        fresh = np.array([pairs[k][0] for k in keys], dtype=int).reshape(sel.size, n_fresh)
        final = np.array([pairs[k][1] for k in keys], dtype=int)
        order = np.array([pairs[k][2] for k in keys], dtype=int)
        sub_idx = idx[sel]
        new_cycle = model_cycle(_rows(prev, sel), Pi[sub_idx[:, :, None], fresh[:, None, :]],
                                u[fresh], model, z[sel], R[sel] if R.ndim > 2 else R)
        joint = join(_rows(c, sel), new_cycle, order)
        post = posterior(joint)
        run = sub_idx.shape[1] + n_fresh
        if algorithm == AO_VSIMM:
            none = np.full(sel.size, NO_GROUP)
            w.output(rows[sel], final, post, target[sel], none, run)
            w.keep(rows[sel], final, post, np.ones(final.shape, dtype=bool), target[sel], none)
        else:
            w.output(rows[sel], final, post, old[sel], target[sel], run)
            _terminate(w, rows[sel], final, joint, post, old[sel], target[sel], np.zeros(sel.size), th)


def vs_step(bank: ModelBank, algorithm: str, s: VSState, model: LinearModel, z: np.ndarray,
            R: np.ndarray, th: Thresholds, Pi: np.ndarray | None = None) -> tuple[VSState, StepOutput]:
    """One step of VSIMM or activation-only VSIMM for every run.

    Runs whose active sets have the same size are processed in one batched cycle with
    per-run model indices, so the arithmetic is proportional to the number of models each
    run actually runs. ``Pi`` overrides the bank's transition matrix (the replay passes
    ``I`` for a zero time step).
    """
    if algorithm not in (VSIMM, AO_VSIMM):
        raise ValueError(f"unknown variable-structure algorithm {algorithm!r}")
    Pi = bank.Pi if Pi is None else Pi
    u_all = mode_inputs(model, bank.acc)
    w = _Writer(bank, s)
    G = len(bank.groups)
    codes, first = np.unique(s.old * (G + 1) + s.new + 1, return_inverse=True)
    sets = [active_models(bank, int(c) // (G + 1), int(c) % (G + 1) - 1) for c in codes]
    by_size: dict[int, list[int]] = {}
    for i, a in enumerate(sets):
        by_size.setdefault(a.size, []).append(i)
    for size, which in by_size.items():
        rows = np.arange(first.size) if len(by_size) == 1 else np.flatnonzero(np.isin(first, which))
        table = np.zeros((codes.size, size), dtype=int)
        table[which] = [sets[i] for i in which]
        idx = table[first[rows]]  # (b, M) running models per run
        prev = IMMState(s.x[rows[:, None], idx], s.P[rows[:, None], idx], s.mu[rows[:, None], idx])
        Rr = R[rows] if R.ndim > 2 else R
        c = model_cycle(prev, Pi[idx[:, :, None], idx[:, None, :]], u_all[idx], model, z[rows], Rr)
        post = posterior(c)
        old, new = s.old[rows], s.new[rows]
        union = new != NO_GROUP
        if union.any():
            u = slice(None) if union.all() else union
            u_post = _rows(post, u)
            w.output(rows[u], idx[u], u_post, old[u], new[u], size)
            _terminate(w, rows[u], idx[u], _rows(c, u), u_post, old[u], new[u], s.log_lr[rows[u]], th)
            if union.all():
                continue
        single = slice(None) if not union.any() else np.flatnonzero(~union)
        target = np.full(rows.size, NO_GROUP)
        target[single] = activation(bank, idx[single], old[single], _rows(c, single), _rows(post, single), th.t_a)
        stay = (target == NO_GROUP) & ~union
        sel = slice(None) if stay.all() else stay
        s_post = _rows(post, sel)
        w.output(rows[sel], idx[sel], s_post, old[sel], new[sel], size)
        w.keep(rows[sel], idx[sel], s_post, np.ones(idx[sel].shape, dtype=bool), old[sel], new[sel])
        fire = np.flatnonzero(target != NO_GROUP)
        if fire.size:
            _activate(bank, algorithm, w, rows, idx, prev, c, fire, old, target, Pi, u_all, model,
                      z[rows], Rr, th)
    return w.state, w.out


def initial_state(bank: ModelBank, algorithm: str, group: int, x0: np.ndarray,
                  P0: np.ndarray) -> VSState:
    """Every model starts at ``x0 (R, n)``, ``P0 (R, n, n)``; uniform mode probabilities over
    all models (FSIMM) or over ``group`` (VSIMM, activation-only VSIMM)."""
    if algorithm == FSIMM:
        R = x0.shape[0]
        mu = np.full((R, bank.size), 1.0 / bank.size)
        return VSState(np.repeat(x0[:, None], bank.size, axis=1),
                       np.repeat(P0[:, None], bank.size, axis=1), mu,
                       np.full(R, NO_GROUP), np.full(R, NO_GROUP), np.zeros(R))
    return initial_vs(bank, group, x0, P0)


def step(bank: ModelBank, algorithm: str, s: VSState, model: LinearModel, z: np.ndarray,
         R: np.ndarray, th: Thresholds, Pi: np.ndarray | None = None) -> tuple[VSState, StepOutput]:
    """One step of any of the three estimators, with the same per-run outputs."""
    if algorithm != FSIMM:
        return vs_step(bank, algorithm, s, model, z, R, th, Pi)
    Pi = bank.Pi if Pi is None else Pi
    post = fsimm_step(IMMState(s.x, s.P, s.mu), Pi, mode_inputs(model, bank.acc), model, z, R)
    nxt = VSState(post.x, post.P, post.mu, s.old, s.new, s.log_lr)
    out = StepOutput(combine(post), post.mu @ bank.acc, post.mu, s.old, s.new,
                     np.full(s.old.shape, bank.size))
    return nxt, out


def group_label(bank: ModelBank, old: int, new: int) -> str:
    """``"all"`` (FSIMM), ``"M2"`` for a single group, ``"M2+M1"`` for a VSIMM union (old first)."""
    if old == NO_GROUP:
        return "all"
    if new == NO_GROUP:
        return bank.group_names[old]
    return f"{bank.group_names[old]}+{bank.group_names[new]}"
