"""Per-sensor linear tracking pieces shared by the local filters and the fusion centre.

Cached CV/CA models per interval, the one-point initialisation, the stand-alone local
Kalman step and the federated sharing factors of paper 004 (eq. (17), errata convention:
``sum_i 1/beta_i = 1``). All functions batch over leading axes.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update
from fedtrack.local_filters.linear.models import LinearModel, ca_model, cv_model


def equal_sharing(n_sensors: int) -> np.ndarray:
    """Default sharing factors ``beta_i = N`` (so ``sum 1/beta_i = 1``)."""
    return np.full(n_sensors, float(n_sensors))


def validate_sharing(betas: np.ndarray) -> np.ndarray:
    """Check eq. (17): ``sum 1/beta_i = 1`` and ``0 < 1/beta_i <= 1``."""
    b = np.asarray(betas, dtype=float)
    if b.ndim != 1 or b.size == 0 or not np.all(np.isfinite(b)):
        raise ValueError("sharing factors must be a non-empty list of finite numbers")
    if np.any(b < 1.0):
        raise ValueError("every sharing factor beta_i must be >= 1 (0 < 1/beta_i <= 1)")
    if abs(np.sum(1.0 / b) - 1.0) > 1e-9:
        raise ValueError(f"sharing factors must satisfy sum(1/beta_i) = 1, got {np.sum(1.0 / b):.6g}")
    return b


def rounded_interval(dt: float | np.ndarray) -> float | np.ndarray:
    """A prediction interval rounded to 1e-12 s, so that one interval met as different
    differences of times gives one model (and one cache entry of :func:`motion`)."""
    return np.round(dt, 12) if isinstance(dt, np.ndarray) else round(dt, 12)


@lru_cache(maxsize=64)
def models_for(dt: float, q: float) -> tuple[LinearModel, LinearModel]:
    """CV and CA models for a scan interval ``dt`` (cached: matrices are built once)."""
    return cv_model(dt, q), ca_model(dt, q)


def one_point_init(zs: np.ndarray, Rs: np.ndarray, speed_var: float) -> GaussianState:
    """Per-sensor one-point CV estimates ``(..., N, 4)`` from position measurements."""
    batch = zs.shape[:-1]
    x = np.zeros(batch + (4,))
    x[..., 0], x[..., 2] = zs[..., 0], zs[..., 1]
    P = np.zeros(batch + (4, 4))
    P[..., [0, 0, 2, 2], [0, 2, 0, 2]] = np.broadcast_to(Rs, batch + (2, 2)).reshape(batch + (4,))
    P[..., 1, 1] = P[..., 3, 3] = speed_var
    return GaussianState(x, P)


def masked(present: np.ndarray | None, post: GaussianState, prior: GaussianState) -> GaussianState:
    """Posterior where the sensor reported, prior where it did not."""
    if present is None:
        return post
    m = np.asarray(present, dtype=bool)
    return GaussianState(np.where(m[..., None], post.x, prior.x), np.where(m[..., None, None], post.P, prior.P))


def local_kf_step(local: GaussianState, model: LinearModel, zs: np.ndarray, Rs: np.ndarray,
                  present: np.ndarray | None) -> tuple[GaussianState, GaussianState]:
    """Stand-alone local Kalman filters (full Q, no feedback): ``(prior, posterior)``."""
    prior = predict(local, model.F, model.Q)
    post, _ = update(prior, zs, model.H, Rs)
    return prior, masked(present, post, prior)
