"""Multi-sensor fusion: centralized KF, federated fusion with reset, decentralized fusion.

Notation follows paper 004 section II. With ``N`` sensors, local states carry a sensor
axis just before the state axes: ``x`` is ``(..., N, n)`` and ``P`` is ``(..., N, n, n)``.

Sharing factors use the paper's convention (errata): ``sum_i 1/beta_i = 1``, reset
``P_i = beta_i P`` and ``Q_i = beta_i Q`` (eqs. (17)-(22)). With reset at every step the
federated estimate equals the centralized Kalman filter to round-off; so does the
decentralized (Hashemipour) estimate.
"""

from __future__ import annotations

import numpy as np

from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    from_information,
    information,
    predict,
    symmetrize,
    update,
)


def centralized_update(prior: GaussianState, zs: np.ndarray, H: np.ndarray,
                       Rs: np.ndarray) -> GaussianState:
    """Centralized KF update (eqs. (6), (8) in covariance form) with all sensors stacked.

    ``zs`` is ``(..., N, m)``, ``Rs`` is ``(N, m, m)`` or ``(..., N, m, m)``. The stacked
    measurement has ``H_stack = [H; ...; H]`` and a block-diagonal ``R``.
    """
    n_sensors, m = zs.shape[-2], zs.shape[-1]
    z = zs.reshape(zs.shape[:-2] + (n_sensors * m,))
    H_stack = np.tile(H, (n_sensors, 1))
    R_block = np.zeros(Rs.shape[:-3] + (n_sensors * m, n_sensors * m))
    for i in range(n_sensors):
        R_block[..., i * m:(i + 1) * m, i * m:(i + 1) * m] = Rs[..., i, :, :]
    return update(prior, z, H_stack, R_block)[0]


def federated_reset(fused: GaussianState, betas: np.ndarray) -> GaussianState:
    """Reset (eqs. (20)-(21)): every local gets ``x_i = x`` and ``P_i = beta_i P``."""
    n_sensors = betas.shape[0]
    x = np.repeat(fused.x[..., None, :], n_sensors, axis=-2)
    P = betas[:, None, None] * fused.P[..., None, :, :]
    return GaussianState(x, P)


def federated_local_step(local: GaussianState, zs: np.ndarray, F: np.ndarray, Q: np.ndarray,
                         H: np.ndarray, Rs: np.ndarray, betas: np.ndarray,
                         present: np.ndarray | None = None) -> tuple[GaussianState, GaussianState]:
    """Local filters (eqs. (9)-(12)) with ``Q_i = beta_i Q`` (eq. (22)).

    Returns ``(prior, posterior)`` per sensor. A sensor with ``present[i] = False``
    only predicts (its posterior is its prior).
    """
    Qi = betas[:, None, None] * Q
    prior = predict(local, F, Qi)
    post, _ = update(prior, zs, H, Rs)
    if present is not None:
        mask = np.asarray(present, dtype=bool)
        post = GaussianState(np.where(mask[..., None], post.x, prior.x),
                             np.where(mask[..., None, None], post.P, prior.P))
    return prior, post


def federated_fuse(local: GaussianState, betas: np.ndarray | None = None,
                   present: np.ndarray | None = None,
                   master_prior: GaussianState | None = None) -> GaussianState:
    """Master fusion, eqs. (15)-(16): ``P = (sum P_i^-1)^-1``, ``x = P sum P_i^-1 x_i``.

    If some local estimates are missing (``present[i] = False``), their share of the
    prior information, ``(1/beta_i) P^-1(k|k-1)``, is taken from ``master_prior``:
    this renormalizes the sharing factors over the sensors that reported and keeps
    the result equal to the centralized filter over the measurements received.
    """
    Y_i, y_i = information(local)
    if present is None:
        return from_information(Y_i.sum(axis=-3), y_i.sum(axis=-2))
    if betas is None or master_prior is None:
        raise ValueError("fusing a partial set of local estimates needs betas and master_prior")
    mask = np.asarray(present, dtype=float)
    Y = np.einsum("...i,...ijk->...jk", mask, Y_i)
    y = np.einsum("...i,...ij->...j", mask, y_i)
    missing_share = np.einsum("...i,i->...", 1.0 - mask, 1.0 / betas)
    Y_pred, y_pred = information(master_prior)
    Y = Y + missing_share[..., None, None] * Y_pred
    y = y + missing_share[..., None] * y_pred
    return from_information(symmetrize(Y), y)


def decentralized_fuse(centre_prior: GaussianState, local_prior: GaussianState,
                       local_post: GaussianState) -> GaussianState:
    """Hashemipour decentralized fusion without feedback.

    ``Y(k|k) = Y(k|k-1) + sum_i [Y_i(k|k) - Y_i(k|k-1)]`` and likewise for the
    information vector: the centre subtracts each local's prior information so the
    common prior is counted once. A local that did not update (posterior == prior)
    contributes nothing.
    """
    Yc, yc = information(centre_prior)
    Yp, yp = information(local_prior)
    Yu, yu = information(local_post)
    Y = Yc + (Yu - Yp).sum(axis=-3)
    y = yc + (yu - yp).sum(axis=-2)
    return from_information(symmetrize(Y), y)
