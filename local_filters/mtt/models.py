"""Motion and measurement models of the multi-target trackers, batched over tracks.

State orders: 2-D ``[x, vx, y, vy]`` (D = 4), 3-D ``[x, vx, y, vy, z, vz]`` (D = 6).

Motion: constant velocity per axis with white-noise acceleration. ``noise_model =
"continuous"`` integrates a continuous white noise of intensity ``q`` [m^2/s^3] over the
interval (``Q_axis = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]``, Stone Soup's
``ConstantVelocity(noise_diff_coeff=q)``), which is consistent over irregular intervals;
``"discrete"`` is the piecewise-constant acceleration of paper 004 (``Q_axis = q G G'``,
``G = [dt^2/2, dt]'``, ``q`` in (m/s^2)^2), used to compare with the single-target mode.
With ``process_noise = "imm"`` every track carries two such modes (:class:`Modes`): CV
without process noise and CV with ``q``, an IMM over them (:func:`modes_predict`,
:func:`modes_update`).

Measurements: a 2-D position sensor sees ``[x, y]`` (``H`` picks them from either state);
a radar sees ``[range, azimuth, elevation]`` of the position relative to its
``sensor_position`` (paper 002 eq. (39)), linearized at the predicted state.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.imm.filter import Cycle, IMMState, combine, mix, posterior
from fedtrack.local_filters.linear.kalman import (
    LOG_2PI,
    GaussianState,
    innovation_covariance,
    log_likelihood,
    mat_vec,
    spd_inverse_logdet,
    symmetrize,
    transpose,
    update_residual,
)
from fedtrack.local_filters.linear.tracking import rounded_interval
from fedtrack.local_filters.radar.ekf import CV3, motion_model_3d, radar_h, radar_jacobian
from fedtrack.local_filters.radar.measurement import cartesian_from_polar, cartesian_from_polar_jacobian

POSITION_INDEX = {4: (0, 2), 6: (0, 2, 4)}
RADAR_LAYOUT = motion_model_3d(CV3, 1.0, 1.0)  # only its position indices (0, 2, 4) are used


class Motion(NamedTuple):
    F: np.ndarray  # (D, D)
    Q: np.ndarray  # (D, D)


@lru_cache(maxsize=256)
def motion(dim: int, dt: float, q: float, noise_model: str = "continuous") -> Motion:
    """CV transition and process noise for ``dim`` = 4 or 6 over ``dt`` seconds."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    if noise_model == "continuous":
        qa = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
    else:
        g = np.array([dt**2 / 2.0, dt])
        qa = q * np.outer(g, g)
    axes = dim // 2
    F, Q = np.kron(np.eye(axes), f), np.kron(np.eye(axes), qa)
    F.setflags(write=False)
    Q.setflags(write=False)
    return Motion(F, Q)


def predict_batch(x: np.ndarray, P: np.ndarray, dt: float | np.ndarray, q: float, noise_model: str = "continuous",
                  q_scale: float | np.ndarray = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Predict each of a batch ``x`` (N, D), ``P`` (N, D, D) over ``dt`` with the CV model of
    :func:`motion` (``dt`` rounded by :func:`rounded_interval`), ``Q`` scaled by ``q_scale``
    (federated ``beta_i``, a float or (N,)).

    One interval (a float, a tracker's scan): ``F P F'`` with the cached ``F``, two BLAS
    products over the stack. Each its own (``dt`` (N,), central tracks at their own times):
    ``F = I + dt E`` (``E`` moves each velocity into its position), so ``F P F'`` is two row and
    column operations instead of building and multiplying a stack of ``F`` (at 1,000 tracks the
    products cost half the row operations, which cost less than a stack of ``F``), done with the
    batch as the last axis (long contiguous rows: a third less time at 800 rows than on 4x4 blocks)."""
    scale = np.asarray(q_scale, dtype=float)
    if np.ndim(dt) == 0:
        m = motion(x.shape[1], rounded_interval(float(dt)), q, noise_model)
        xp = x @ m.F.T
        Pp = m.F @ P @ m.F.T + scale[..., None, None] * m.Q
        return xp, 0.5 * (Pp + np.swapaxes(Pp, -1, -2))
    dt = rounded_interval(np.asarray(dt, dtype=float))
    if noise_model == "continuous":
        q11, q12, q22 = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    else:
        q11, q12, q22 = q * dt**4 / 4.0, q * dt**3 / 2.0, q * dt**2
    if scale.ndim or scale != 1.0:
        q11, q12, q22 = scale * q11, scale * q12, scale * q22
    dim = x.shape[1]
    pos, vel = slice(0, dim, 2), slice(1, dim, 2)
    # the batch as the last, contiguous axis: each row operation is one pass over long rows
    xp = np.array(x.T, order="C")  # copies (ascontiguousarray would not for one track)
    xp[pos] += dt * xp[vel]
    FP = np.array(P.transpose(1, 2, 0), order="C")
    FP[pos] += dt * FP[vel]
    FP[:, pos] += dt * FP[:, vel]
    for a in range(0, dim, 2):
        FP[a, a] += q11
        FP[a, a + 1] += q12
        FP[a + 1, a] += q12
        FP[a + 1, a + 1] += q22
    return np.ascontiguousarray(xp.T), np.ascontiguousarray((0.5 * (FP + FP.swapaxes(0, 1))).transpose(2, 0, 1))


class Modes(NamedTuple):
    """Each track's two motion modes (``[mtt] process_noise = "imm"``), batched: mode-conditioned
    states ``x`` (N, 2, D), ``P`` (N, 2, D, D) and probabilities ``mu`` (N, 2); mode 0 is CV
    without process noise (a straight leg), mode 1 CV with ``q`` (a maneuver)."""

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray

    def take(self, idx: np.ndarray) -> Modes:
        return Modes(self.x[idx], self.P[idx], self.mu[idx])


class ModeRates(NamedTuple):
    """The modes' switching rates [1/s]: straight to maneuver (``1 /`` the mean straight leg) and
    back (``1 /`` the mean maneuver); docs/multitarget.md#the-90--bar-an-adaptive-level-and-an-imm-measured."""

    to_maneuver: float
    to_straight: float

    @property
    def stationary(self) -> np.ndarray:
        """The long-run mode probabilities (a new track's)."""
        total = self.to_maneuver + self.to_straight
        return np.array([self.to_straight / total, self.to_maneuver / total])


def maneuver_visible(q: float, noise_model: str, maneuver_s: float, sigma: float) -> bool:
    """Whether a position sensor of noise ``sigma`` [m] per axis (its least) can tell the two modes apart:
    the maneuvering mode's own position spread over a mean maneuver, ``Q(maneuver_s)``'s position
    variance (``q tau^3 / 3`` for the continuous model), reaches ``sigma^2`` (the straight mode's innovation
    then shows a maneuver within its mean duration, the one-sigma rule of ``q``'s derivation). Below it the
    mode probabilities stay near their long-run values, and the IMM's combination is a CV filter of about
    ``q`` times the maneuver's long-run probability, below the ``q`` a turn needs
    (docs/jipda.md#a-sensor-too-coarse-to-see-a-maneuver-coarse60-session)."""
    return bool(motion(2, maneuver_s, q, noise_model).Q[0, 0] >= sigma**2)


def mode_transition(dt: float | np.ndarray, rates: ModeRates) -> np.ndarray:
    """``Pi(dt)`` (2, 2) or (N, 2, 2), row = from: the two-state Markov chain of ``rates`` over
    ``dt`` (closed form: ``p_01 = r_01 / r (1 - e^(-r dt))``, ``r = r_01 + r_10``)."""
    total = rates.to_maneuver + rates.to_straight
    decay = 1.0 - np.exp(-total * np.asarray(dt, dtype=float))
    p01, p10 = rates.to_maneuver / total * decay, rates.to_straight / total * decay
    Pi = np.empty(decay.shape + (2, 2))
    Pi[..., 0, 0], Pi[..., 0, 1], Pi[..., 1, 0], Pi[..., 1, 1] = 1.0 - p01, p01, p10, 1.0 - p10
    return Pi


def start_modes(x: np.ndarray, P: np.ndarray, rates: ModeRates) -> Modes:
    """New tracks' modes: both at ``(x, P)``, with the long-run probabilities."""
    return Modes(np.repeat(x[:, None], 2, axis=1), np.repeat(P[:, None], 2, axis=1),
                 np.broadcast_to(rates.stationary, (x.shape[0], 2)).copy())


def modes_predict(modes: Modes, dt: float | np.ndarray, q: float, noise_model: str, rates: ModeRates,
                  q_scale: float | np.ndarray = 1.0) -> tuple[Modes, GaussianState]:
    """IMM mixing (:func:`fedtrack.local_filters.imm.filter.mix`, eqs. (3), (5), (6) of paper 000)
    and each mode's prediction over ``dt`` (mode 0 without process noise); returns the predicted
    modes (``mu``: the predicted probabilities) and their combination (the tracks' CV view)."""
    n, _, d = modes.x.shape
    mixed, log_pred = mix(IMMState(*modes), mode_transition(dt, rates))
    scale = np.asarray(q_scale, dtype=float).reshape(-1, 1) * np.array([0.0, 1.0])
    step = dt if np.ndim(dt) == 0 else np.repeat(np.asarray(dt, dtype=float), 2)
    xp, Pp = predict_batch(mixed.x.reshape(-1, d), mixed.P.reshape(-1, d, d), step, q, noise_model,
                           np.broadcast_to(scale, (n, 2)).reshape(-1))
    pred = Modes(xp.reshape(n, 2, d), Pp.reshape(n, 2, d, d), np.exp(log_pred))
    return pred, combine(IMMState(*pred))


def modes_update(pred: Modes, nu: np.ndarray, H: np.ndarray, R: np.ndarray, x0: np.ndarray
                 ) -> tuple[Modes, GaussianState]:
    """Each mode of the tracks ``pred`` (K) updated with one detection each (``R`` (m, m) or
    (K, m, m)): ``nu`` (K, m) the innovation at the combined prediction ``x0`` (K, D), where ``H``
    (K, m, D) is linearized (each mode's innovation ``nu + H (x0 - x_j)``); probabilities by the
    modes' likelihoods (paper 000 eq. (1), in log space); returns the modes and their combination."""
    k, _, d = pred.x.shape
    m = nu.shape[1]
    Hj = np.broadcast_to(H[:, None], (k, 2, m, d))
    nu_j = nu[:, None, :] + np.einsum("kmd,kjd->kjm", H, x0[:, None, :] - pred.x)
    Rj = np.broadcast_to(np.broadcast_to(R, (k, m, m))[:, None], (k, 2, m, m))
    upd = update_residual(GaussianState(pred.x, pred.P), nu_j, Hj, Rj)
    with np.errstate(divide="ignore"):
        post = posterior(Cycle(upd.state, np.log(pred.mu), log_likelihood(upd.innovation)))
    return Modes(*post), combine(post)


def position_matrix(dim: int, m: int = 2) -> np.ndarray:
    """``H`` (m, dim) that picks the first ``m`` position coordinates of the state."""
    H = np.zeros((m, dim))
    H[np.arange(m), list(POSITION_INDEX[dim][:m])] = 1.0
    return H


class Linearized(NamedTuple):
    """A measurement model at a batch of states: ``z ~ zhat + H (x - x0)``."""

    zhat: np.ndarray  # (N, m)
    H: np.ndarray  # (N, m, D)
    angular: tuple[int, ...]  # measurement components that are angles (residuals wrapped)
    picks: tuple[int, ...] | None = None  # the state coordinates ``H`` picks (a position sensor's), None: any ``H``

    def times(self, P: np.ndarray) -> np.ndarray:
        """``H P`` (N, m, D) for covariances ``P`` (N, D, D); where ``H`` picks coordinates, their
        rows of ``P``: the same numbers (``H``'s entries are 0 and 1, every other term an exact zero)."""
        return self.H @ P if self.picks is None else P[:, list(self.picks)]

    def covariance(self, P: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """``H P H'`` (K, m, m) of the tracks ``rows`` (``P`` theirs, (K, D, D)); where ``H`` picks
        coordinates, by picking them (the same numbers)."""
        if self.picks is None:
            H = self.H[rows]
            return H @ P @ transpose(H)
        idx = np.array(self.picks)
        return P[:, idx[:, None], idx]

    def mean(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """``H x`` (K, m) of the tracks ``rows`` (``x`` theirs, (K, D)); where ``H`` picks
        coordinates, by picking them (the same numbers)."""
        return mat_vec(self.H[rows], x) if self.picks is None else x[:, list(self.picks)]

    def innovation_covariance(self, P: np.ndarray, R: np.ndarray) -> np.ndarray:
        """``S = H P H' + R`` (N, m, m), symmetric (:func:`~fedtrack.local_filters.linear.kalman.
        innovation_covariance`); where ``H`` picks coordinates, by picking them (the same numbers)."""
        if self.picks is None:
            return innovation_covariance(P, self.H, R)
        return symmetrize(self.covariance(P) + R)


class ModeInnovations(NamedTuple):
    """Each mode's measurement model about the combination (:func:`mode_innovations`), the ``N k``
    modes as rows ``t k + j`` (mode ``j`` of track ``t``)."""

    at: Linearized  # each mode's model: zhat_j = zhat + H (x_j - x0), the combination's H
    S: np.ndarray  # (N k, m, m) S_j = H P_j H' + R
    S_inv: np.ndarray  # (N k, m, m)
    logdet: np.ndarray  # (N k,)
    shift: np.ndarray  # (N, k, m) zhat_j - zhat


def mode_innovations(modes: Modes, x0: np.ndarray, lin: Linearized, R: np.ndarray) -> ModeInnovations:
    """The measurement model of every mode of ``modes`` (each track's prediction per mode, of which
    ``x0`` (N, D) is the combination, where ``lin`` was computed)."""
    n, k, d = modes.x.shape
    m = R.shape[0]
    shift = np.einsum("nmd,njd->njm", lin.H, modes.x - x0[:, None])
    at = Linearized((lin.zhat[:, None] + shift).reshape(-1, m), np.repeat(np.asarray(lin.H), k, axis=0),
                    lin.angular, lin.picks)
    S = at.innovation_covariance(modes.P.reshape(n * k, d, d), R)
    S_inv, logdet = spd_inverse_logdet(S)
    return ModeInnovations(at, S, S_inv, logdet, shift)


def mode_densities(mi: ModeInnovations, rows: np.ndarray, nu: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (track ``rows``, innovation ``nu`` from the combination's ``zhat``) seen by each mode:
    the mode rows (K k), innovations ``nu + zhat - zhat_j``, ``d2_j`` and ``ln N(nu_j; 0, S_j)``."""
    k, m = mi.shift.shape[1], nu.shape[-1]
    mode_rows = (rows[:, None] * k + np.arange(k)).ravel()
    nu_j = (nu[:, None] - mi.shift[rows]).reshape(-1, m)
    d2 = np.sum(nu_j * mat_vec(mi.S_inv[mode_rows], nu_j), axis=-1)
    return mode_rows, nu_j, d2, -0.5 * (d2 + mi.logdet[mode_rows] + m * LOG_2PI)


def linearize(x: np.ndarray, sensor_position: np.ndarray | None) -> Linearized:
    """Position sensor (``sensor_position`` None) or radar at the states ``x`` (N, D)."""
    n, dim = x.shape
    if sensor_position is None:
        H = position_matrix(dim)
        return Linearized(x[:, [0, 2]], np.broadcast_to(H, (n, 2, dim)), (), POSITION_INDEX[dim][:2])
    if dim != 6:
        raise ValueError("a radar needs the 3-D state [x, vx, y, vy, z, vz]")
    return Linearized(radar_h(x, RADAR_LAYOUT, sensor_position), radar_jacobian(x, RADAR_LAYOUT, sensor_position),
                      (1,))


def position_from_detection(z: np.ndarray, R: np.ndarray, sensor_position: np.ndarray | None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Cartesian positions (M, k) and their covariances (M, k, k) of detections ``z`` (M, m)."""
    if sensor_position is None:
        return z.copy(), np.broadcast_to(R, (z.shape[0],) + R.shape).copy()
    J = cartesian_from_polar_jacobian(z)
    return sensor_position + cartesian_from_polar(z), J @ R @ np.swapaxes(J, -1, -2)
