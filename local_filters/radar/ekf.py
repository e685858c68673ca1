"""Extended Kalman filter for 3-D radar (range, azimuth, elevation), paper 002 section 2.

State orders (3-D; the 2-D orders of :mod:`fedtrack.local_filters.linear.models` extended by a z block):

* CV: ``[x, vx, y, vy, z, vz]``
* CA: ``[x, vx, ax, y, vy, ay, z, vz, az]``

Motion: discrete white-acceleration models, ``Q = q G G'`` with per-axis gain ``[T^2/2, T]'``
(CV) or ``[T^2/2, T, 1]'`` (CA). Measurement: ``h(x) = [r, az, el]`` of the position relative
to the sensor (paper 002 eq. (39), atan2 per the errata), linearized with the analytic
Jacobian at the predicted state (eq. (11)); the angle residuals are wrapped to (-pi, pi].
The update reuses the Joseph-form :func:`fedtrack.local_filters.linear.kalman.update` on the pseudo-measurement
``H x_pred + wrap(z - h(x_pred))`` so that the innovation it forms is the wrapped residual.
All functions batch over leading axes (Monte Carlo runs).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    Innovation,
    predict,
    transpose,
    update_residual,
)
from fedtrack.local_filters.radar.measurement import (
    cartesian_from_polar,
    cartesian_from_polar_jacobian,
    polar_from_cartesian,
    wrap_angle,
)

CV3 = "cv"
CA3 = "ca"


class MotionModel3D(NamedTuple):
    """3-D linear motion model: ``F``, ``Q = q G G'``, noise/input gain ``G`` (n x 3), indices."""

    name: str
    T: float
    q: float
    F: np.ndarray
    Q: np.ndarray
    G: np.ndarray
    pos: np.ndarray
    vel: np.ndarray

    @property
    def dim(self) -> int:
        return self.F.shape[0]


def motion_model_3d(name: str, T: float, q: float) -> MotionModel3D:
    """``cv`` or ``ca`` 3-D model: one per-axis block per Cartesian axis (x, then y, then z)."""
    if name == CV3:
        f = np.array([[1.0, T], [0.0, 1.0]])
        g = np.array([[0.5 * T * T], [T]])
    elif name == CA3:
        f = np.array([[1.0, T, 0.5 * T * T], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
        g = np.array([[0.5 * T * T], [T], [1.0]])
    else:
        raise ValueError(f"unknown motion model {name!r} (expected 'cv' or 'ca')")
    F = np.kron(np.eye(3), f)
    G = np.kron(np.eye(3), g)
    m = f.shape[0]
    return MotionModel3D(name, T, q, F, q * G @ G.T, G, np.arange(3) * m, np.arange(3) * m + 1)


def position(x: np.ndarray, model: MotionModel3D) -> np.ndarray:
    """Cartesian position (..., 3) of states (..., n)."""
    return x[..., model.pos]


def radar_h(x: np.ndarray, model: MotionModel3D, sensor_position: np.ndarray) -> np.ndarray:
    """Predicted measurement ``h(x) = [r, az, el]`` (paper 002 eq. (39))."""
    return polar_from_cartesian(position(x, model) - sensor_position)


def radar_jacobian(x: np.ndarray, model: MotionModel3D, sensor_position: np.ndarray) -> np.ndarray:
    """Analytic Jacobian ``dh/dx`` (..., 3, n) at ``x`` (paper 002 eq. (11))."""
    return jacobian_at_offset(position(x, model) - sensor_position, model)


def jacobian_at_offset(d: np.ndarray, model: MotionModel3D) -> np.ndarray:
    """:func:`radar_jacobian` from the offsets ``d`` (..., 3) of the positions from the sensor.

    One offset is handled in Python floats: a third of the cost of 0-d numpy arithmetic.
    """
    dx, dy, dz = d.tolist() if d.ndim == 1 else (d[..., 0], d[..., 1], d[..., 2])
    rho2 = dx * dx + dy * dy
    rho = rho2 ** 0.5
    r2 = rho2 + dz * dz
    r = r2 ** 0.5
    H = np.zeros(d.shape[:-1] + (3, model.dim))
    px, py, pz = model.pos.tolist()
    H[..., 0, px], H[..., 0, py], H[..., 0, pz] = dx / r, dy / r, dz / r
    H[..., 1, px], H[..., 1, py] = -dy / rho2, dx / rho2
    H[..., 2, px], H[..., 2, py], H[..., 2, pz] = -dx * dz / (r2 * rho), -dy * dz / (r2 * rho), rho / r2
    return H


def radar_residual(x: np.ndarray, z: np.ndarray, model: MotionModel3D,
                   sensor_position: np.ndarray) -> np.ndarray:
    """``z - h(x)`` with the azimuth and elevation residuals wrapped to (-pi, pi]."""
    return residual_at_offset(position(x, model) - sensor_position, z)


def residual_at_offset(d: np.ndarray, z: np.ndarray) -> np.ndarray:
    """:func:`radar_residual` from the offsets ``d`` (..., 3) of the positions from the sensor.

    A direction has two readings, ``(az, el)`` and ``(az + pi, +-pi - el)`` (through the zenith
    or the nadir); the residual is taken from the one nearer the prediction on the sphere
    (azimuth residuals weighted by ``cos(el)``). Near the zenith a target's noisy direction is
    often reported on the far side (azimuth off by pi): read as it comes, that residual is a
    jump of pi in azimuth, which the EKF took as a horizontal displacement and diverged (a target
    climbing straight above the radar: errors of kilometres with a covariance of metres)."""
    h = polar_from_cartesian(d)
    nu = z - h
    nu[..., 1:] = wrap_angle(nu[..., 1:])
    other = np.stack([wrap_angle(z[..., 1] + np.pi - h[..., 1]),
                      np.copysign(np.pi, h[..., 2]) - z[..., 2] - h[..., 2]], axis=-1)
    c = np.cos(h[..., 2])
    far = (c * other[..., 0]) ** 2 + other[..., 1] ** 2 < (c * nu[..., 1]) ** 2 + nu[..., 2] ** 2
    nu[..., 1:] = np.where(far[..., None], other, nu[..., 1:])
    return nu


def measurement_hessians(d: np.ndarray) -> np.ndarray:
    """Second derivatives (..., 3, 3, 3) of ``[r, az, el]`` with respect to the offset ``d``.

    With ``rho^2 = dx^2 + dy^2`` and ``r^2 = rho^2 + dz^2``: ``r_ij = (delta_ij - u_i u_j) / r``
    (``u = d / r``); ``az_xx = -az_yy = 2 dx dy / rho^4``, ``az_xy = (dy^2 - dx^2) / rho^4``;
    ``el_xx = dz (2 dx^2 rho^2 - dy^2 r^2) / (r^4 rho^3)``, ``el_yy`` likewise with x and y
    swapped, ``el_xy = dx dy dz (2 rho^2 + r^2) / (r^4 rho^3)``,
    ``el_xz = dx (dz^2 - rho^2) / (r^4 rho)``, ``el_yz`` likewise, ``el_zz = -2 dz rho / r^4``.
    """
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    rho2 = dx * dx + dy * dy
    rho = np.sqrt(rho2)
    r2 = rho2 + dz * dz
    r = np.sqrt(r2)
    Hs = np.zeros(d.shape[:-1] + (3, 3, 3))
    u = d / r[..., None]
    Hs[..., 0, :, :] = (np.eye(3) - u[..., :, None] * u[..., None, :]) / r[..., None, None]
    rho4 = rho2 * rho2
    Hs[..., 1, 0, 0] = 2.0 * dx * dy / rho4
    Hs[..., 1, 1, 1] = -Hs[..., 1, 0, 0]
    Hs[..., 1, 0, 1] = Hs[..., 1, 1, 0] = (dy * dy - dx * dx) / rho4
    e = r2 * r2 * rho2 * rho
    Hs[..., 2, 0, 0] = dz * (2.0 * dx * dx * rho2 - dy * dy * r2) / e
    Hs[..., 2, 1, 1] = dz * (2.0 * dy * dy * rho2 - dx * dx * r2) / e
    Hs[..., 2, 0, 1] = Hs[..., 2, 1, 0] = dx * dy * dz * (2.0 * rho2 + r2) / e
    Hs[..., 2, 0, 2] = Hs[..., 2, 2, 0] = dx * (dz * dz - rho2) / (r2 * r2 * rho)
    Hs[..., 2, 1, 2] = Hs[..., 2, 2, 1] = dy * (dz * dz - rho2) / (r2 * r2 * rho)
    Hs[..., 2, 2, 2] = -2.0 * dz * rho / (r2 * r2)
    return Hs


def second_order_noise(d: np.ndarray, P_pos: np.ndarray) -> np.ndarray:
    """The second-order term of the innovation covariance, ``1/2 tr(h_i'' P h_j'' P)`` (..., 3, 3).

    Gaussian second-order filter (Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to
    Tracking and Navigation*, 2001, eq. (10.3.2-5)); paper 002 is silent. It is the spread of
    ``h`` over the predicted position's uncertainty that the Jacobian misses: (sigma / rho)^4
    in azimuth, 1e-11 of R at the paper's 2 km and 5 m, but of order 1 rad^2 for a target
    passing over the radar, where a linearized azimuth would fix the horizontal position to
    sigma_az x rho (a millimetre) while the prediction is metres off."""
    M = measurement_hessians(d) @ P_pos[..., None, :, :]
    return 0.5 * np.einsum("...iab,...jba->...ij", M, M)


class EkfUpdate(NamedTuple):
    """Posterior, the innovation it used, the Jacobian ``H`` and the gain ``K``."""

    state: GaussianState
    innovation: Innovation
    H: np.ndarray
    K: np.ndarray


def ekf_update(pred: GaussianState, z: np.ndarray, R: np.ndarray, model: MotionModel3D,
               sensor_position: np.ndarray) -> EkfUpdate:
    """EKF measurement update (paper 002 eqs. (4), (5), (7); Joseph form), the innovation
    covariance with its second-order term (:func:`second_order_noise`) taken as measurement noise."""
    d = position(pred.x, model) - sensor_position  # one offset for h (eq. (39)) and its Jacobian
    H = jacobian_at_offset(d, model)
    nu = residual_at_offset(d, z)
    P_pos = pred.P[..., model.pos[:, None], model.pos[None, :]]
    post = update_residual(pred, nu, H, R + second_order_noise(d, P_pos))  # K = P H' S^-1, eq. (5)
    return EkfUpdate(post.state, post.innovation, H, post.gain)


def ekf_step(state: GaussianState, z: np.ndarray, R: np.ndarray, model: MotionModel3D,
             sensor_position: np.ndarray, u_effect: np.ndarray | None = None) -> EkfUpdate:
    """Predict (eq. (6), optionally with a known input effect ``B u``) then update."""
    return ekf_update(predict(state, model.F, model.Q, u_effect), z, R, model, sensor_position)


def two_point_init(z0: np.ndarray, z1: np.ndarray, R: np.ndarray, model: MotionModel3D,
                   sensor_position: np.ndarray, acc_std: float = 30.0) -> GaussianState:
    """Two-point differencing initialization at the time of ``z1``.

    Positions ``p_i = sensor + cartesian(z_i)`` with covariance ``J_i R J_i'`` (J the Jacobian
    of the polar-to-Cartesian map); velocity ``(p1 - p0)/T``; CA accelerations 0 with
    standard deviation ``acc_std``.
    """
    T = model.T
    p0, p1 = (sensor_position + cartesian_from_polar(z) for z in (z0, z1))
    J0, J1 = (cartesian_from_polar_jacobian(z) for z in (z0, z1))
    C0, C1 = J0 @ R @ transpose(J0), J1 @ R @ transpose(J1)
    batch = p1.shape[:-1]
    n = model.dim
    x = np.zeros(batch + (n,))
    P = np.zeros(batch + (n, n))
    x[..., model.pos] = p1
    x[..., model.vel] = (p1 - p0) / T
    ip, iv = model.pos, model.vel
    P[..., ip[:, None], ip[None, :]] = C1
    P[..., ip[:, None], iv[None, :]] = C1 / T
    P[..., iv[:, None], ip[None, :]] = C1 / T
    P[..., iv[:, None], iv[None, :]] = (C0 + C1) / (T * T)
    if model.name == CA3:
        ia = model.pos + 2
        P[..., ia, ia] = acc_std ** 2
    return GaussianState(x, 0.5 * (P + transpose(P)))
