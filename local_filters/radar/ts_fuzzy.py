"""Takagi-Sugeno fuzzy model identified by a genetic algorithm and recursive least squares (paper 003).

Model (eqs. (5), (6), (8)-(10)): rule i has Gaussian premises ``A_k^i(x_k) = exp(-((x_k - c_k^i) /
s_k^i)^2 / 2)`` and an affine consequent ``p_0^i + sum_k p_k^i x_k``; the output is the
normalized-firing-strength (``beta_i``, eq. (9)) weighted sum of the consequents. Firing
strengths are normalized in log space (logsumexp), so samples far from every centre still get
well-defined weights. Here every rule has one affine consequent per output column (several TS
models sharing one premise), and inputs/outputs are standardized inside the model.

Identification:

* GA (section 2.3, Table 1): a chromosome holds, per rule slot (at most ``max_rules``), the centres
  and widths of the premise and an activation bit (the rule-number string, binary); the rule count
  is the number of set bits (at least 1). Fitness is eq. (7),
  ``lambda / (MSE + 1) + (1 - lambda) / (rules + 1)``, with MSE on standardized outputs of a
  validation subsample, the consequents of each candidate being the ridge least-squares fit on a
  separate fitting subsample (the GA identifies premise and rule count; consequents are linear).
  Operators: binary tournament selection, rule-wise uniform crossover (rate 0.9), per-gene
  mutation (rate 0.1: Gaussian step on centres, log-normal step on widths, bit flip), 2 elites.
  Vectorized over the population (hand-written numpy: general GA libraries evaluate fitness per
  individual in Python and would add a dependency for ~60 lines).
* RLS (eqs. (15)-(16) as corrected in the errata, ``S <- S - S x'x S / (1 + x S x')`` then
  ``P <- P + S x'(y - x P)``) refines the consequents over all training samples, starting from
  the GA's least-squares consequents. Processed in blocks with the exact block form
  ``S <- S - S X'(I + X S X')^-1 X S``, which equals the sample-by-sample recursion.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from scipy.special import logsumexp

from fedtrack.atomic import atomic_file
from fedtrack.config import ConfigError


class TSModel(NamedTuple):
    """A trained TS model: premises (rules, k), consequents (rules, k+1, outputs), scalings."""

    centers: np.ndarray
    widths: np.ndarray
    consequents: np.ndarray
    in_mean: np.ndarray
    in_std: np.ndarray
    out_mean: np.ndarray
    out_std: np.ndarray

    @property
    def n_rules(self) -> int:
        return self.centers.shape[0]


@dataclass(frozen=True)
class GAParams:
    """GA settings; defaults are paper 003's Table 1 plus the unstated sample sizes."""

    population: int = 200
    generations: int = 80
    max_rules: int = 50
    crossover: float = 0.9
    mutation: float = 0.1
    lam: float = 0.7
    fit_samples: int = 600
    val_samples: int = 600
    rls_samples: int = 20000
    ridge: float = 1e-6
    rls_alpha: float = 1e3

    def validate(self) -> None:
        for name in ("population", "generations", "max_rules", "fit_samples", "val_samples",
                     "rls_samples"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: must be >= 1")
        for name in ("crossover", "mutation", "lam"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name}: must be in [0, 1]")


def _log_firing(xs: np.ndarray, centers: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """``log prod_k A_k^i(x_k)`` (eq. (6)): (..., m, rules) for xs (m, k), premises (..., rules, k)."""
    d = (xs[:, None, :] - centers[..., None, :, :]) / widths[..., None, :, :]
    return -0.5 * np.sum(d * d, axis=-1)


def _design(xs: np.ndarray, log_fire: np.ndarray) -> np.ndarray:
    """Rows of eq. (13): ``beta_i * [1, x_1..x_k]`` for every rule (..., m, rules*(k+1))."""
    beta = np.exp(log_fire - logsumexp(log_fire, axis=-1, keepdims=True))  # eqs. (9), (14)
    xa = np.concatenate([np.ones(xs.shape[:-1] + (1,)), xs], axis=-1)
    X = beta[..., :, None] * xa[..., None, :]
    return X.reshape(X.shape[:-2] + (-1,))


def predict(model: TSModel, x: np.ndarray) -> np.ndarray:
    """Model output (..., outputs) for inputs (..., k) (eq. (8))."""
    lead = x.shape[:-1]
    xs = ((x - model.in_mean) / model.in_std).reshape(-1, x.shape[-1])
    X = _design(xs, _log_firing(xs, model.centers, model.widths))
    y = X @ model.consequents.reshape(X.shape[-1], -1)  # eq. (10)
    return (y * model.out_std + model.out_mean).reshape(lead + (-1,))


def rls(theta: np.ndarray, S: np.ndarray, X: np.ndarray, Y: np.ndarray,
        block: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Recursive least squares over the rows of ``X``/``Y`` (eqs. (15)-(16), corrected).

    ``theta`` (d, outputs), ``S`` (d, d). Blocks of rows use the exact block form of the
    one-row recursion (``block=1`` is the printed sample-by-sample algorithm).
    """
    for s in range(0, X.shape[0], block):
        Xb, Yb = X[s:s + block], Y[s:s + block]
        SX = S @ Xb.T
        G = np.linalg.solve(np.eye(Xb.shape[0]) + Xb @ SX, SX.T)  # (I + X S X')^-1 X S
        S = S - SX @ G  # eq. (16)
        S = 0.5 * (S + S.T)
        theta = theta + S @ Xb.T @ (Yb - Xb @ theta)  # eq. (15)
    return theta, S


def _ridge_fit(X: np.ndarray, Y: np.ndarray, ridge: float) -> np.ndarray:
    """Batched ridge least squares ``(X'X + ridge I)^-1 X'Y`` by a linear solve."""
    d = X.shape[-1]
    A = np.swapaxes(X, -1, -2) @ X + ridge * np.eye(d)
    return np.linalg.solve(A, np.swapaxes(X, -1, -2) @ Y)


class Population(NamedTuple):
    """GA population: centres/widths (P, max_rules, k), activation bits (P, max_rules)."""

    centers: np.ndarray
    widths: np.ndarray
    active: np.ndarray


def _fitness(pop: Population, xf: np.ndarray, yf: np.ndarray, xv: np.ndarray, yv: np.ndarray,
             params: GAParams, chunk: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (7) for every individual, and its validation MSE.

    Individuals are processed in chunks of similar rule count, each with its active rules
    moved to the front and the design cut to the chunk's largest count (cost ~ rules^2).
    """
    rules = pop.active.sum(axis=1)
    mse = np.empty(rules.shape[0])
    order = np.argsort(rules, kind="stable")
    for s in range(0, order.shape[0], chunk):
        ids = order[s:s + chunk]
        slot = np.argsort(~pop.active[ids], axis=1, kind="stable")[:, :rules[ids].max()]
        c = np.take_along_axis(pop.centers[ids], slot[..., None], axis=1)
        w = np.take_along_axis(pop.widths[ids], slot[..., None], axis=1)
        mask = np.where(np.take_along_axis(pop.active[ids], slot, axis=1), 0.0, -np.inf)[:, None, :]
        Xf = _design(xf, _log_firing(xf, c, w) + mask)
        Xv = _design(xv, _log_firing(xv, c, w) + mask)
        theta = _ridge_fit(Xf, yf, params.ridge)
        mse[ids] = np.mean((Xv @ theta - yv) ** 2, axis=(-1, -2))
    return params.lam / (mse + 1.0) + (1.0 - params.lam) / (rules + 1.0), mse  # eq. (7)


def _repair(active: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Give every individual at least one active rule."""
    empty = ~active.any(axis=1)
    active[empty, rng.integers(0, active.shape[1], size=int(empty.sum()))] = True
    return active


def _next_generation(pop: Population, fit: np.ndarray, params: GAParams,
                     rng: np.random.Generator) -> Population:
    """Tournament selection, rule-wise uniform crossover, per-gene mutation, 2 elites."""
    P, Rm, k = pop.centers.shape
    a, b = rng.integers(0, P, size=(2, P))
    parents = np.where(fit[a] >= fit[b], a, b)
    mates = np.roll(parents, 1)
    cross = (rng.random(P) < params.crossover)[:, None] & (rng.random((P, Rm)) < 0.5)
    c = np.where(cross[..., None], pop.centers[mates], pop.centers[parents])
    w = np.where(cross[..., None], pop.widths[mates], pop.widths[parents])
    act = np.where(cross, pop.active[mates], pop.active[parents])
    mut = rng.random(c.shape) < params.mutation
    c = c + mut * rng.normal(0.0, 0.3, size=c.shape)
    mut = rng.random(w.shape) < params.mutation
    w = np.clip(w * np.exp(mut * rng.normal(0.0, 0.3, size=w.shape)), 0.05, 10.0)
    act = act ^ (rng.random(act.shape) < params.mutation)
    elite = np.argsort(fit)[-2:]
    c[:2], w[:2], act[:2] = pop.centers[elite], pop.widths[elite], pop.active[elite]
    return Population(c, w, _repair(act, rng))


def identify(x: np.ndarray, y: np.ndarray, params: GAParams, rng: np.random.Generator,
             progress: Callable[[int], None] | None = None) -> tuple[TSModel, dict[str, float]]:
    """Identify a TS model from samples ``x`` (m, k) -> ``y`` (m, outputs): GA then RLS.

    ``progress(n)`` is called after each generation (and once after RLS). Returns the model and
    a summary (rules, fitness, validation MSE before and after RLS, standardized).
    """
    in_mean, in_std = x.mean(axis=0), x.std(axis=0) + 1e-12
    out_mean, out_std = y.mean(axis=0), y.std(axis=0) + 1e-12
    xs, ys = (x - in_mean) / in_std, (y - out_mean) / out_std
    m = xs.shape[0]
    pick = rng.permutation(m)
    nf, nv = min(params.fit_samples, m // 2), min(params.val_samples, m - m // 2)
    fi, vi = pick[:nf], pick[nf:nf + nv]
    P, Rm, k = params.population, params.max_rules, xs.shape[1]
    counts = rng.integers(1, Rm + 1, size=P)
    active = rng.random((P, Rm)) < (counts / Rm)[:, None]
    pop = Population(xs[rng.integers(0, m, size=(P, Rm))], rng.uniform(0.2, 2.0, size=(P, Rm, k)),
                     _repair(active, rng))
    fit, mse = _fitness(pop, xs[fi], ys[fi], xs[vi], ys[vi], params)
    for _ in range(params.generations):
        pop = _next_generation(pop, fit, params, rng)
        fit, mse = _fitness(pop, xs[fi], ys[fi], xs[vi], ys[vi], params)
        if progress is not None:
            progress(1)
    best = int(np.argmax(fit))
    on = pop.active[best]
    centers, widths = pop.centers[best, on], pop.widths[best, on]
    Xf = _design(xs[fi], _log_firing(xs[fi], centers, widths))
    theta0 = _ridge_fit(Xf, ys[fi], params.ridge)
    ri = rng.permutation(m)[:params.rls_samples]
    Xr = _design(xs[ri], _log_firing(xs[ri], centers, widths))
    theta, _ = rls(theta0, params.rls_alpha * np.eye(Xr.shape[1]), Xr, ys[ri])
    Xv = _design(xs[vi], _log_firing(xs[vi], centers, widths))
    if progress is not None:
        progress(1)
    model = TSModel(centers, widths, theta.reshape(int(on.sum()), k + 1, -1), in_mean, in_std,
                    out_mean, out_std)
    summary = {"rules": int(on.sum()), "fitness": float(fit[best]), "ga_val_mse": float(mse[best]),
               "rls_val_mse": float(np.mean((Xv @ theta - ys[vi]) ** 2))}
    return model, summary


def save_model(path: str | Path, model: TSModel, **meta: np.ndarray | float | int | str) -> None:
    """Write the model (and metadata) to ``path``, an ``.npz`` file (whole or not at all:
    :func:`fedtrack.atomic.atomic_file`; the name as given, no suffix added)."""
    with atomic_file(path) as fh:
        np.savez(fh, **model._asdict(), **{f"meta_{k}": np.asarray(v) for k, v in meta.items()})


def load_model(path: str | Path, name: str = "model") -> tuple[TSModel, dict[str, np.ndarray]]:
    """Read a model written by :func:`save_model`; a bad file is a :class:`ConfigError` naming ``name``,
    where the file was given."""
    p = Path(path)
    if p.is_file() and not zipfile.is_zipfile(p):  # np.load would offer to unpickle it
        raise ConfigError(f"{name}: {p} is not a TS-fuzzy model file (not an .npz archive, which "
                          "`fedtrack train ts-fuzzy` writes)")
    try:
        with np.load(p) as data:
            model = TSModel(*(np.asarray(data[f], float) for f in TSModel._fields))
            meta = {k[5:]: data[k] for k in data.files if k.startswith("meta_")}
    except FileNotFoundError as exc:
        raise ConfigError(f"{name}: file {p} does not exist (train one with `fedtrack train ts-fuzzy`)") from exc
    except (KeyError, ValueError, OSError) as exc:
        raise ConfigError(f"{name}: {p} is not a TS-fuzzy model file ({exc})") from exc
    if model.centers.ndim != 2 or model.consequents.shape[:2] != (model.n_rules, model.centers.shape[1] + 1):
        raise ConfigError(f"{name}: {p} has inconsistent shapes")
    return model, meta
