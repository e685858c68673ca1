"""Role 2 of a scan, the gate: ``d2_ij = nu_ij' S_i^-1 nu_ij`` with ``S_i = H_i P_i H_i' + R`` against
the chi-square quantile of ``gate_probability`` (m = 2 or 3 degrees of freedom), and each gated
pair's log-likelihood ``ln N(nu_ij; 0, S_i) = -(d2_ij + ln det(2 pi S_i)) / 2`` (with two motion
modes per track, the modes' mixture: :func:`gate_modes`); a radar linearized at the predictions,
or, for a track whose altitude is unobserved, about a plot's altitude (:func:`relinearize_altitude`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.gating import gate_ball_pairs, track_difference_d2
from fedtrack.local_filters.linear.kalman import LOG_2PI, GaussianState, logsumexp, mat_vec, spd_inverse_logdet
from fedtrack.local_filters.mtt.models import (
    Linearized,
    Modes,
    linearize,
    mode_densities,
    mode_innovations,
    position_from_detection,
)
from fedtrack.local_filters.mtt.roles.tracks import TrackParams
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.radar.measurement import wrap_angle


class Gated(NamedTuple):
    """The (track, detection) pairs inside the chi-square gate, with their innovations."""

    rows: np.ndarray  # (K,) track index
    cols: np.ndarray  # (K,) detection index
    nu: np.ndarray  # (K, m) innovation z_j - zhat_i, angles wrapped
    d2: np.ndarray  # (K,) squared Mahalanobis distance


def gate(z: np.ndarray, lin: Linearized, S: np.ndarray, gate_d2: float) -> tuple[Gated, np.ndarray]:
    """The gated pairs and ``ln det S`` (N,) per track (``d2 = nu' S^-1 nu``), computed only for
    the pairs within the balls of :func:`gate_ball_pairs` (a radar's azimuth on its circle)."""
    rows, cols = gate_ball_pairs(z, lin.zhat, S, gate_d2, bounded=True, angular=lin.angular)
    S_inv, logdet = spd_inverse_logdet(S)
    nu = z[cols] - lin.zhat[rows]
    for k in lin.angular:
        nu[:, k] = wrap_angle(nu[:, k])
    d2 = np.sum(nu * mat_vec(S_inv[rows], nu), axis=-1)
    inside = d2 <= gate_d2
    return Gated(rows[inside], cols[inside], nu[inside], d2[inside]), logdet


class Gating(NamedTuple):
    """Role 2's result: the measurement model at the predictions, the gated pairs, each pair's
    log-likelihood ``ln N(nu; 0, S)``, and each track's ``S`` and ``ln det S``."""

    lin: Linearized
    pairs: Gated
    log_likelihood: np.ndarray  # (K,)
    S: np.ndarray  # (N, m, m)
    logdet: np.ndarray  # (N,)


def relinearize_altitude(pred: GaussianState, lin: Linearized, scan: SensorScan, gate_d2: float) -> Linearized:
    """A radar's model ``lin`` at the predictions, with every track whose altitude is too uncertain
    for it relinearized about the altitude of the plot nearest it on ``x, y``.

    The range's second derivative in ``z`` is ``rho^2 / r^3`` (``rho`` the ground range), so a
    range linearized at the predicted ``z`` is biased by ``b = rho^2 P_zz / (2 r^3)`` on average (the
    second-order EKF's term), which its derivative ``dr/dz = (z - z_s) / r`` does not cover: a
    track started from a 2-D plot at ``z = 0`` (``init_z_std``) loses the radar's plots of an
    aircraft at 4 km to the range gate (170 m of bias at 66 km, against 10 m of noise) and they start
    a second track. Where ``b`` exceeds the range noise ``sqrt(R_rr)`` the track is linearized instead
    at ``x0`` = its prediction with ``z`` the altitude of the plot whose Cartesian position
    (:func:`position_from_detection`) is nearest its own on ``x, y`` (``d2`` with ``P_xy + R_xy``,
    inside the 2-D gate ``gate_d2``): ``zhat = h(x0) + H(x0) (x - x0)``, ``H = H(x0)``, so the
    innovation ``z - h(x0) - H (x - x0)`` and the observation ``z - h(x0) + H x0`` are the EKF's
    about ``x0``."""
    d = pred.x[:, [0, 2, 4]] - scan.sensor_position
    rho2 = d[:, 0] ** 2 + d[:, 1] ** 2
    bias = 0.5 * rho2 * pred.P[:, 4, 4] / np.maximum(rho2 + d[:, 2] ** 2, 1.0) ** 1.5
    wide = np.flatnonzero(bias > np.sqrt(scan.R[0, 0]))
    if not wide.size:
        return lin
    pos, Ppos = position_from_detection(scan.z, scan.R, scan.sensor_position)
    xy, Pxy = pred.x[wide][:, [0, 2]], pred.P[wide][:, [0, 2]][:, :, [0, 2]]
    widest = np.trace(Ppos[:, :2, :2], axis1=-2, axis2=-1).max()  # the balls' S: trace P_xy + the widest R_xy
    ri, cj = gate_ball_pairs(pos[:, :2], xy, Pxy + 0.5 * widest * np.eye(2), gate_d2, bounded=True)
    d2 = track_difference_d2(pos[cj, :2] - xy[ri], Pxy[ri] + Ppos[cj, :2, :2])[0]
    inside = d2 <= gate_d2
    order = np.lexsort((cj[inside], d2[inside], ri[inside]))  # each track's nearest first (argmin's tie)
    ri, cj = ri[inside][order], cj[inside][order]
    first = np.unique(ri, return_index=True)[1]
    rows = wide[ri[first]]
    if not rows.size:
        return lin
    x0 = pred.x[rows].copy()
    x0[:, 4] = pos[cj[first], 2]
    at = linearize(x0, scan.sensor_position)
    zhat, H = lin.zhat.copy(), lin.H.copy()
    zhat[rows] = at.zhat + at.H[:, :, 4] * (pred.x[rows, 4] - x0[:, 4])[:, None]
    H[rows] = at.H
    return Linearized(zhat, H, lin.angular)


def gate_scan(pred: GaussianState, scan: SensorScan, params: TrackParams, modes: Modes | None = None
              ) -> Gating | None:
    """Role 2: the gated pairs of the predicted tracks and the scan's detections (None when
    either is empty); with ``modes`` (each track's motion modes, of which ``pred`` is the
    combination), by :func:`gate_modes`."""
    if not (pred.x.shape[0] and scan.z.shape[0]):
        return None
    m = scan.dim
    lin = linearize(pred.x, scan.sensor_position)
    if scan.sensor_position is not None:
        lin = relinearize_altitude(pred, lin, scan, params.gate[2])
    S = lin.innovation_covariance(pred.P, scan.R)
    if modes is not None:
        g, logdet, log_l = gate_modes(scan.z, lin, S, modes, pred.x, scan.R, params.gate[m])
        return Gating(lin, g, log_l, S, logdet)
    g, logdet = gate(scan.z, lin, S, params.gate[m])
    return Gating(lin, g, -0.5 * (g.d2 + logdet[g.rows] + m * LOG_2PI), S, logdet)


def gate_modes(z: np.ndarray, lin: Linearized, S: np.ndarray, modes: Modes, x0: np.ndarray, R: np.ndarray,
               gate_d2: float) -> tuple[Gated, np.ndarray, np.ndarray]:
    """:func:`gate` for tracks with motion modes: a pair is gated when it is inside the gate of
    the combination (``x0``, ``S``) or of a mode of positive probability, and its log-likelihood is
    the modes' mixture ``ln sum_j mu_j N(z; zhat_j, S_j)`` (paper 000's eq. (4) summed over the
    modes: the IMM's predicted density of a detection) rather than that of the combination's
    moment-matched Gaussian. After a straight leg the combination's covariance is the straight
    mode's (with a sensor of 1 cm noise, centimetres) however likely the maneuver mode is, so a
    target that began to brake left that gate at once and its track was lost. Returns the pairs
    (``nu``, ``d2`` the combination's), ``ln det S`` per track and the pairs' log-likelihoods."""
    n, m_det = x0.shape[0], z.shape[0]
    mi = mode_innovations(modes, x0, lin, R)
    k, m = mi.shift.shape[1], z.shape[1]
    zhat_j, S_j = mi.at.zhat.reshape(n, k, m), mi.S.reshape(n, k, m, m)  # the union of the combination's
    balls = [gate_ball_pairs(z, lin.zhat, S, gate_d2, True, lin.angular)] + [  # and every mode's balls
        gate_ball_pairs(z, zhat_j[:, j], S_j[:, j], gate_d2, True, lin.angular) for j in range(k)]
    keys = np.unique(np.concatenate([r * m_det + c for r, c in balls]))
    rows, cols = keys // m_det, keys % m_det
    S_inv, logdet = spd_inverse_logdet(S)
    nu = z[cols] - lin.zhat[rows]
    for a in lin.angular:
        nu[:, a] = wrap_angle(nu[:, a])
    d2 = np.sum(nu * mat_vec(S_inv[rows], nu), axis=-1)
    _, _, d2_j, log_n = mode_densities(mi, rows, nu)
    mu = modes.mu[rows]
    inside = (d2 <= gate_d2) | np.any((d2_j.reshape(-1, k) <= gate_d2) & (mu > 0.0), axis=1)
    with np.errstate(divide="ignore"):
        log_l = logsumexp(np.log(mu) + log_n.reshape(-1, k), axis=1)
    return Gated(rows[inside], cols[inside], nu[inside], d2[inside]), logdet, log_l[inside]
