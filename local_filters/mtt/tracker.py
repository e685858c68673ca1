"""Local multi-target tracker: one scan as a chain of roles over the batched track set.

:func:`tracker_step` runs, each role a small pure function:

1. **predict** (:func:`predict`) every track to the scan time (CV, :mod:`.models`; or each track
   in its own model with ``[mtt] maneuver = "vdie"``, :mod:`.maneuver`).
2. **gate** (:func:`gate_scan`): ``d2_ij = nu_ij' S_i^-1 nu_ij`` with ``S_i = H_i P_i H_i' + R``
   against the chi-square quantile of ``gate_probability`` (m = 2 or 3 degrees of freedom), and
   each gated pair's log-likelihood ``ln N(nu_ij; 0, S_i) = -(d2_ij + ln det(2 pi S_i)) / 2``; a
   radar linearized at the predictions, or, for a track whose altitude is unobserved, about a
   plot's altitude (:func:`relinearize_altitude`).
3. **associate**: the :class:`~.association.Associator` that ``[mtt] associator`` names
   (:data:`ASSOCIATORS`; ``gnn``: :mod:`.gnn`). The interface, and how a soft associator
   (``jipda``) or one with memory (``mht``) plugs in: :mod:`.association`.
4. **update** (:func:`hard_update`, or the associator's): a track with one detection by the EKF
   (Joseph form; exact Kalman for position sensors).
5. **initiate** (:func:`initiate`): every detection the associator did not claim starts a
   tentative track: position from the detection and its covariance, zero velocity with
   ``init_velocity_std`` per axis (and, for a 2-D detection in a 3-D state, altitude 0 with
   ``init_z_std``); or, where it pairs with an earlier one-point start that it lies beyond but
   within ``max_speed`` of, the two-point start of :mod:`.initiation` (a fast target's). Ids are
   integers in order of creation, never reused.
6. **confirm / delete** (:func:`m_of_n`, or the associator's): a track is confirmed once it has
   ``confirm_hits`` detections within its first ``confirm_window`` scans; a tentative track that
   can no longer reach that is deleted; a confirmed track is deleted after ``delete_misses``
   consecutive misses, or more on a fast sensor (:func:`deletion_at`).

Each updated or started track carries its detection as a linearized observation
``(H, R, z - h(x0) + H x0)`` at the linearization point ``x0`` (the track's prediction;
for a start, the detection's Cartesian position with its covariance): what a fusion centre
needs to fuse the local tracks exactly (docs/multitarget.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import expit, logit

from fedtrack.geodetic import Frame, own_axes
from fedtrack.local_filters.linear.gating import gate_ball_pairs, track_difference_d2
from fedtrack.local_filters.linear.kalman import (
    LOG_2PI,
    GaussianState,
    logsumexp,
    mat_vec,
    spd_inverse_logdet,
    update_residual,
)
from fedtrack.local_filters.mtt import detector, initiation, maneuver
from fedtrack.local_filters.mtt.association import Association, AssociationInput, Associator
from fedtrack.local_filters.mtt.associators import jipda, mht
from fedtrack.local_filters.mtt.associators.gnn import GNN
from fedtrack.local_filters.mtt.config import LOST, MhtConfig, MttConfig, log_miss_of, miss_count, scan_lost
from fedtrack.local_filters.mtt.models import (
    Linearized,
    ModeRates,
    Modes,
    linearize,
    mode_densities,
    mode_innovations,
    modes_predict,
    modes_update,
    position_from_detection,
    position_matrix,
    predict_batch,
    start_modes,
)
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.radar.measurement import cartesian_from_polar, wrap_angle
from fedtrack.local_filters.vdie.estimation import VdieParams, VdieState

# the associators ``[mtt] associator`` selects (config.ASSOCIATORS lists the names, with those
# still to come)
ASSOCIATORS: dict[str, Associator] = {GNN.name: GNN}


class TrackParams(NamedTuple):
    """What one tracker needs per scan (built from ``[mtt]`` by :func:`track_params`)."""

    dim: int
    q: float
    noise_model: str
    init_velocity_std: float
    init_z_std: float
    pd: float
    clutter_density: float
    gate: dict[int, float]
    confirm_hits: int
    confirm_window: int
    delete_misses: int
    maneuver: VdieParams | None = None  # per-track VDIE (2-D position trackers), None: CV only
    detector: VdieParams | None = None  # per-track maneuver events (3-D trackers), None: none
    associator: Associator = GNN
    initial_existence: float | None = None  # a new track's existence (associators that keep it)
    mht: MhtConfig | None = None  # [mtt.mht] (associator = "mht")
    modes: ModeRates | None = None  # two motion modes per track (process_noise = "imm"), None: CV with q
    # a tracker of several sensors' scans (mtt-centralized): the scan's sensor as a bit of
    # TrackSet.detected_by (0: one sensor's tracker, every scan counts), and the misses in a row
    # that delete a confirmed track: ``sensor_misses`` per sensor that detected it, at least
    # ``lone_misses``, at most ``delete_misses`` (:func:`scan_counts`)
    sensor_bit: int = 0
    sensor_misses: int = 0
    lone_misses: int = 0
    max_speed: float = 0.0  # [m/s] two-point starts' speed bound (:mod:`.initiation`); 0: none
    frame: Frame | None = None  # [frame]: radars stand on the Earth, each with its own axes (:func:`radar_view`)


def track_params(cfg: MttConfig, sensor: str | None, dim: int, feedback: bool = False,
                 events: bool = False) -> TrackParams:
    """Parameters of the tracker of ``sensor`` (None: a tracker of every sensor's detections) for
    one scan of ``sensor``; ``events``: its tracks are the output (``mtt-local``,
    ``mtt-centralized``), not reports to a centre. ``[mtt] maneuver = "vdie"`` applies VDIE to
    2-D trackers without federated feedback (the centre's resets own a federated tracker's
    state, and its central tracks are CV), and the maneuver detector (:mod:`.detector`, with
    VDIE's parameters and window) to the tracks of a 3-D tracker whose tracks are the output (a
    track-to-track centre runs its own on the central tracks). A tracker of every sensor's scans
    (``mtt-centralized``) takes the fusion centre's policy on top
    (:func:`fedtrack.fusion_center.mtt.engines.central_params`)."""
    vdie = detect = None
    if cfg.maneuver == "vdie":  # both over the window of the tracker's own scans
        vdie = cfg.vdie if dim == 4 and not feedback else None
        detect = cfg.vdie if dim == 6 and events else None
    return TrackParams(dim, cfg.q, cfg.noise_model, cfg.init_velocity_std, cfg.init_z_std,
                       cfg.pd if sensor is None else cfg.pd_of(sensor),
                       cfg.clutter_density if sensor is None else cfg.clutter_of(sensor),
                       cfg.thresholds.gate, cfg.confirm_hits, cfg.confirm_window, cfg.misses_to_delete(sensor), vdie, detect,
                       ASSOCIATORS[cfg.associator], jipda.BIRTH_EXISTENCE if cfg.associator == "jipda" else None,
                       mht=cfg.mht_settings if cfg.associator == "mht" else None,
                       modes=cfg.mode_rates if vdie is None and not feedback else None, max_speed=cfg.max_speed)


N_ARRAYS = 7  # TrackSet's per-track arrays before the optional per-track states


class TrackSet(NamedTuple):
    """Live tracks, batched: ``x`` (N, D), ``P`` (N, D, D) (with maneuver handling, the CV view
    of ``man``, every track's VDIE state: :mod:`fedtrack.local_filters.mtt.maneuver`; or, on a
    3-D tracker, ``inputs``, every track's maneuver detector: :mod:`.detector`; with an
    associator that keeps it, ``existence``, every track's existence probability; with
    ``process_noise = "imm"``, ``modes``, every track's two motion modes, of which ``x``, ``P``
    are the combination: :class:`~.models.Modes`; in a tracker of several sensors' scans,
    ``detected_by``, each track's sensors that detected it, as bits: :func:`scan_counts`)."""

    ids: np.ndarray
    x: np.ndarray
    P: np.ndarray
    hits: np.ndarray
    age: np.ndarray  # scans since the start, the starting one included
    misses: np.ndarray  # consecutive misses
    confirmed: np.ndarray
    man: VdieState | None = None
    inputs: detector.TrackInputs | None = None
    existence: np.ndarray | None = None
    modes: Modes | None = None
    detected_by: np.ndarray | None = None  # (N,) int64

    def take(self, idx: np.ndarray) -> TrackSet:
        """The tracks at ``idx`` (indices or a bool mask), every per-track state with them."""
        return TrackSet(*(a[idx] for a in self[:N_ARRAYS]),
                        None if self.man is None else maneuver.take(self.man, idx),
                        None if self.inputs is None else detector.take(self.inputs, idx),
                        None if self.existence is None else self.existence[idx],
                        None if self.modes is None else self.modes.take(idx),
                        None if self.detected_by is None else self.detected_by[idx])

    @property
    def models(self) -> list[str]:
        """Each track's motion model, ``"cv"`` or ``"ca"``."""
        if self.man is None:
            return ["cv"] * self.size
        return ["ca" if ca else "cv" for ca in self.man.is_ca.tolist()]

    @property
    def size(self) -> int:
        return int(self.ids.shape[0])


class TrackerState(NamedTuple):
    tracks: TrackSet
    t: float | None
    next_id: int
    memory: object = None  # the associator's memory (Association.memory)
    starts: initiation.Starts = initiation.NO_STARTS  # one-point starts waiting for a second detection


class Observation(NamedTuple):
    """What one detection says about its track, linearized: ``z ~ N(H x, R)`` (batched, K tracks).

    ``z = z_det - h(x0) + H x0`` at the linearization point ``x0``; exact for position sensors.
    """

    H: np.ndarray  # (K, m, D)
    R: np.ndarray  # (K, m, m)
    z: np.ndarray  # (K, m)


class ScanResult(NamedTuple):
    state: TrackerState
    detected: np.ndarray  # (N,) bool over state.tracks: updated or started by this scan
    observations: Observation  # for the detected tracks, in order
    retired: np.ndarray  # ids deleted by this scan


def empty_tracks(dim: int) -> TrackSet:
    return TrackSet(np.zeros(0, np.int64), np.zeros((0, dim)), np.zeros((0, dim, dim)), np.zeros(0, np.int64),
                    np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool))


def initial_state(dim: int) -> TrackerState:
    return TrackerState(empty_tracks(dim), None, 0)


def _concat(a: TrackSet, b: TrackSet) -> TrackSet:
    extras = []  # the per-track states beside x, P (None on an empty side: its tracker had no tracks)
    for u, v, join in ((a.man, b.man, maneuver.concat), (a.inputs, b.inputs, detector.concat),
                       (a.existence, b.existence, lambda u, v: np.concatenate([u, v])),
                       (a.modes, b.modes, lambda u, v: Modes(*(np.concatenate([p, r]) for p, r in zip(u, v)))),
                       (a.detected_by, b.detected_by, lambda u, v: np.concatenate([u, v]))):
        if u is None or v is None:
            extras.append(v if a.size == 0 else u if b.size == 0 else None)
        else:
            extras.append(join(u, v))
    return TrackSet(*(np.concatenate([u, v]) for u, v in zip(a[:N_ARRAYS], b[:N_ARRAYS])), *extras)


def predict(tracks: TrackSet, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0) -> GaussianState:
    """Role 1: every track predicted ``dt`` ahead (its CV view with maneuver handling; with two
    modes, their combination after mixing: :func:`modes_predict`)."""
    if params.modes is not None and tracks.modes is not None and tracks.size:
        return modes_predict(tracks.modes, dt, params.q, params.noise_model, params.modes, q_scale)[1]
    if params.maneuver is not None and tracks.man is not None and tracks.size:
        return maneuver.predicted_view(tracks.man, dt, params.q, params.noise_model, q_scale)
    if tracks.size and dt > 0:
        return GaussianState(*predict_batch(tracks.x, tracks.P, dt, params.q, params.noise_model, q_scale))
    return GaussianState(tracks.x.copy(), tracks.P.copy())


class Gated(NamedTuple):
    """The (track, detection) pairs inside the chi-square gate, with their innovations."""

    rows: np.ndarray  # (K,) track index
    cols: np.ndarray  # (K,) detection index
    nu: np.ndarray  # (K, m) innovation z_j - zhat_i, angles wrapped
    d2: np.ndarray  # (K,) squared Mahalanobis distance


def gate(z: np.ndarray, lin: Linearized, S: np.ndarray, gate_d2: float) -> tuple[Gated, np.ndarray]:
    """The gated pairs and ``ln det S`` (N,) per track (``d2 = nu' S^-1 nu``).

    Only a position sensor's pairs within the balls of :func:`gate_ball_pairs` are computed; a
    radar's azimuth residual wraps, so it keeps every pair."""
    if lin.angular:
        n, m = S.shape[0], z.shape[0]
        rows, cols = np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
    else:
        rows, cols = gate_ball_pairs(z, lin.zhat, S, gate_d2, bounded=True)
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
    n_wide, n_det = wide.size, pos.shape[0]
    diff = (pos[None, :, :2] - pred.x[wide][:, None, [0, 2]]).reshape(-1, 2)
    S = pred.P[wide][:, None][..., [0, 2], :][..., [0, 2]] + Ppos[None, :, :2, :2]
    d2 = track_difference_d2(diff, S.reshape(-1, 2, 2))[0].reshape(n_wide, n_det)
    nearest = np.argmin(d2, axis=1)
    near = d2[np.arange(n_wide), nearest] <= gate_d2
    rows = wide[near]
    if not rows.size:
        return lin
    x0 = pred.x[rows].copy()
    x0[:, 4] = pos[nearest[near], 2]
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
    if lin.angular:
        rows, cols = np.repeat(np.arange(n), m_det), np.tile(np.arange(m_det), n)
    else:  # the union of the combination's and every mode's balls
        zhat_j, S_j = mi.at.zhat.reshape(n, k, m), mi.S.reshape(n, k, m, m)
        balls = [gate_ball_pairs(z, lin.zhat, S, gate_d2, bounded=True)] + [
            gate_ball_pairs(z, zhat_j[:, j], S_j[:, j], gate_d2, bounded=True) for j in range(k)]
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


def associate(state: TrackerState, gating: Gating | None, scan: SensorScan, params: TrackParams,
              dt: float = 0.0, sees: Sight | None = None) -> Association:
    """Role 3: the associator's answer (nothing to associate without gated pairs, unless the
    associator keeps the existence of tracks, which a scan without pairs still lowers); ``sees``:
    :func:`scan_sees`."""
    n, n_det = state.tracks.size, scan.z.shape[0]
    if gating is None and (params.initial_existence is None or n == 0):
        return Association(np.zeros(0, np.int64), np.zeros(0), np.zeros(n_det, bool), state.tracks.existence,
                           state.memory)
    none = np.zeros(0, np.int64)
    rows, cols, log_l = (none, none, np.zeros(0)) if gating is None else (*gating.pairs[:2], gating.log_likelihood)
    by = state.tracks.detected_by
    return params.associator.associate(AssociationInput(
        n, n_det, rows, cols, log_l, scan.dim, state.tracks.confirmed, state.tracks.existence,
        params.pd, params.clutter_density, scan.amplitude, state.memory, params.gate[scan.dim], dt,
        None if by is None or sees is None else ~sees.counts(by, params.sensor_bit)))


def predict_tracks(tracks: TrackSet, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0
                   ) -> tuple[TrackSet, GaussianState]:
    """Role 1 for the roles after it: the tracks with their modes (two per track) predicted ``dt``
    ahead, mixed once for both results, and every track's prediction (:func:`predict`)."""
    if params.modes is None or tracks.modes is None or not tracks.size:
        return tracks, predict(tracks, dt, params, q_scale)
    modes, pred = modes_predict(tracks.modes, dt, params.q, params.noise_model, params.modes, q_scale)
    return tracks._replace(modes=modes), pred


def _modes_at_scan(tracks: TrackSet, params: TrackParams) -> Modes | None:
    """The modes of ``tracks`` as :func:`predict_tracks` left them (None with one mode)."""
    return tracks.modes if params.modes is not None and tracks.size else None


def detection_update(x0: np.ndarray, P0: np.ndarray, modes: Modes | None, idx: np.ndarray, nu: np.ndarray,
                     H: np.ndarray, R: np.ndarray) -> GaussianState:
    """The predictions ``x0``, ``P0`` (K) each updated with one detection (innovation ``nu``, ``H``
    linearized at ``x0``): the EKF in Joseph form; with two modes, each of the modes ``modes[idx]``
    (:func:`modes_update`, written back into ``modes`` at ``idx``) and their combination."""
    if modes is None:
        return update_residual(GaussianState(x0, P0), nu, H, R).state
    updated, combined = modes_update(modes.take(idx), nu, H, R, x0)
    modes.x[idx], modes.P[idx], modes.mu[idx] = updated
    return combined


class Updated(NamedTuple):
    """Role 4's result: the tracks after the scan (before confirmation and deletion), which were
    detected, and the detected tracks' observations in track order."""

    tracks: TrackSet
    detected: np.ndarray  # (N,) bool
    observations: Observation


def hard_update(tracks: TrackSet, pred: GaussianState, gating: Gating | None, assoc: Association,
                scan: SensorScan, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0) -> Updated:
    """Role 4 for a hard association (each track at most one detection): the EKF update in
    Joseph form (of each mode, with two: :func:`modes_update`), or the VDIE step with maneuver
    handling; the maneuver detector of a 3-D tracker observes each update."""
    d, m = params.dim, scan.dim
    x, P = pred
    man = tracks.man if params.maneuver is not None else None
    inputs = tracks.inputs if params.detector is not None else None
    modes = _modes_at_scan(tracks, params)
    assigned = np.zeros(tracks.size, bool)
    obs = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
    ti = dj = np.zeros(0, np.int64)
    if gating is not None and assoc.pairs.size:
        g = gating.pairs
        ti, dj = g.rows[assoc.pairs], g.cols[assoc.pairs]
        H, R = gating.lin.H[ti], scan.R
        nu_a, x0, P0 = g.nu[assoc.pairs], x[ti], P[ti]
        if man is None:
            x[ti], P[ti] = detection_update(x0, P0, modes, ti, nu_a, H, R)
        obs = Observation(H, np.broadcast_to(R, (ti.size, m, m)).copy(), nu_a + np.einsum("nij,nj->ni", H, x0))
        if inputs is not None:
            inputs = detector.observe(inputs, ti, scan.t, x0, P0, *obs)
        assigned[ti] = True
    if man is not None and tracks.size:
        step = maneuver.maneuver_step(man, scan.t, dt, params.q, params.noise_model, params.maneuver,
                                      ti, scan.z[dj], scan.R, q_scale)
        (x, P), man = step.view, step.state
    return Updated(tracks._replace(x=x, P=P, man=man, inputs=inputs, existence=assoc.existence, modes=modes), assigned,
                   obs)


def popcount(bits: np.ndarray) -> np.ndarray:
    """The set bits of each int64 of ``bits`` (N,)."""
    return np.unpackbits(np.ascontiguousarray(bits, dtype=np.int64).view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1)


class Sight(NamedTuple):
    """What one scan of a tracker of several sensors' scans shows of each track's place
    (:func:`scan_sees`): ``place``, that its sensor sees it (a detection in the track's gate, or the
    track inside the extent of the scan's detections); ``view``, that the track is inside the
    radar's view the detections show (True for a position scan: its extent is ``place``'s)."""

    place: np.ndarray  # (N,) bool
    view: np.ndarray  # (N,) bool

    def take(self, idx: np.ndarray) -> Sight:
        return Sight(self.place[idx], self.view[idx])

    def counts(self, detected_by: np.ndarray, sensor_bit: int) -> np.ndarray:
        """The tracks the scan counts for: its sensor sees the place, or detected the track before
        and the track is still inside its view (or no other sensor detected it: the sensor that
        holds a track alone always counts, so that it can be deleted)."""
        others = (detected_by & ~sensor_bit) != 0
        return (((detected_by & sensor_bit) != 0) & (self.view | ~others)) | self.place


def radar_view(x: np.ndarray, scan: SensorScan, frame: Frame | None = None) -> np.ndarray:
    """Per track (its predicted state in ``x``, 3-D), whether it is inside a radar scan's view as
    its detections (targets' and clutter) show it, seen from ``sensor_position``: at an elevation
    above the lowest detection's (below it: the radar's horizon or lowest beam), at a range below
    the farthest detection's (its reach), and in the arc of azimuth the detections span (its sector:
    outside the largest gap between neighbouring detections' azimuths). A track on an edge is outside.
    With a ``frame`` (the common frame on the Earth) the elevations and azimuths are the radar's own,
    about its site's east-north-up axes (:func:`fedtrack.geodetic.own_axes`): its horizontal leans from
    the common frame's by the angle between their normals, 1.75 deg at 195 km, and in the common axes
    the lowest detection away from the origin is that much lower than the radar's horizon towards it."""
    rel = x[:, [0, 2, 4]] - scan.sensor_position
    a, e = scan.z[:, 1], scan.z[:, 2]
    if frame is not None:
        axes = own_axes(frame, tuple(scan.sensor_position.tolist()))
        rel, own = rel @ axes.T, cartesian_from_polar(scan.z) @ axes.T
        a, e = np.arctan2(own[:, 1], own[:, 0]), np.arctan2(own[:, 2], np.hypot(own[:, 0], own[:, 1]))
    rng = np.linalg.norm(rel, axis=1)
    el = np.arctan2(rel[:, 2], np.hypot(rel[:, 0], rel[:, 1]))
    az = np.arctan2(rel[:, 1], rel[:, 0])
    r, a = scan.z[:, 0], np.sort(np.mod(a, 2 * np.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    k = int(np.argmax(gaps))  # the largest gap: from a[k] on, counter-clockwise, for gaps[k]
    return (el > e.min()) & (rng < r.max()) & (np.mod(az - a[k], 2 * np.pi) > gaps[k])


def scan_sees(x: np.ndarray, gating: Gating | None, scan: SensorScan, params: TrackParams) -> Sight | None:
    """In a tracker of several sensors' scans (``params.sensor_bit``; else None), per track (its
    predicted state in ``x``) what the scan shows of its place (:class:`Sight`): a detection of the
    scan in the track's gate, or the track's position strictly inside the x-y extent of the scan's
    detections (targets' and clutter: a sensor's detections lie in what it sees; a sensor that
    covers the area puts its clutter all round a track) and, for a radar, inside its view
    (:func:`radar_view`: a far radar's clutter surrounds a low aircraft in x-y, above its horizon)."""
    if not params.sensor_bit:
        return None
    n = x.shape[0]
    sees = np.zeros(n, dtype=bool) if gating is None else np.bincount(gating.pairs.rows, minlength=n) > 0
    view = np.ones(n, dtype=bool)
    if n and scan.z.shape[0] > 1:
        pos = scan.z if scan.sensor_position is None else scan.sensor_position + cartesian_from_polar(scan.z)
        xy = pos[:, :2]
        lo, hi, at = xy.min(axis=0), xy.max(axis=0), x[:, [0, 2]]
        if scan.sensor_position is not None:
            view = radar_view(x, scan, params.frame)
        sees |= ((at > lo) & (at < hi)).all(axis=1) & view
    return Sight(sees, view)


def scan_counts(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sight: Sight | None = None
                ) -> tuple[TrackSet, np.ndarray | bool, np.ndarray | int]:
    """Which tracks the scan counts for in the life rules, and the misses in a row that delete each.

    One sensor's tracker: every track, ``delete_misses``. A tracker of several sensors' scans
    (``params.sensor_bit``): a sensor's scan counts for a track where the scan shows that the
    sensor sees the track's place (``sight``, :func:`scan_sees`: a detection in its gate, as beside
    a target's own track for its twin, or the track inside the extent of the scan's detections), or
    once that sensor has detected the track (now or before: ``detected_by``) while the track is
    inside the radar's view the scan shows (a track that descended below a radar's horizon is no
    longer counted by it, unless no other sensor detected it); a sensor that has none of these may not see the target at
    all (out of its range or field of view, behind the horizon), and its misses are then no
    evidence against it (docs/multitarget.md#sensors-that-cannot-see-a-target). A confirmed track
    is deleted after ``sensor_misses`` misses in a row per sensor that detected it, at least
    ``lone_misses``, at most ``delete_misses``."""
    if not params.sensor_bit or tracks.detected_by is None:
        return tracks, True, params.delete_misses
    by = tracks.detected_by | np.where(detected, params.sensor_bit, 0)
    counted = (by & params.sensor_bit) != 0 if sight is None else sight.counts(by, params.sensor_bit) | detected
    need = np.clip(params.sensor_misses * popcount(by), params.lone_misses, params.delete_misses)
    return tracks._replace(detected_by=by), counted, need


def m_of_n(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
           ) -> tuple[TrackSet, np.ndarray]:
    """Role 6: the track counts after the scan, and which tracks stay (M-of-N confirmation,
    deletion after ``delete_misses`` consecutive misses; the scans counted: :func:`scan_counts`,
    ``sees``: :func:`scan_sees`)."""
    tracks, counted, need = scan_counts(tracks, detected, params, sees)
    hits = tracks.hits + detected
    age = tracks.age + counted
    misses = np.where(detected, 0, tracks.misses + counted)
    confirmed = tracks.confirmed | (hits >= params.confirm_hits)
    live = np.where(confirmed, misses < need, params.confirm_window - age >= params.confirm_hits - hits)
    return tracks._replace(hits=hits, age=age, misses=misses, confirmed=confirmed), live


def jipda_update(tracks: TrackSet, pred: GaussianState, gating: Gating | None, assoc: Association,
                 scan: SensorScan, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0) -> Updated:
    """Role 4 for ``jipda``: each track's PDA mixture over its gated detections (:func:`jipda.update`;
    with two modes per track, each mode's with its own weights: :func:`jipda.imm_update`); a track
    that more likely than not exists and was detected is reported with its equivalent observation
    from the combined prediction (:func:`jipda.equivalent_observation`)."""
    d, m, n = params.dim, scan.dim, tracks.size
    existence = assoc.existence
    modes = _modes_at_scan(tracks, params)
    if gating is None or not assoc.pairs.size:
        empty = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
        return Updated(tracks._replace(x=pred.x, P=pred.P, existence=existence, modes=modes), np.zeros(n, bool),
                       empty)
    g = gating.pairs
    c = jipda.scan_constants(params.pd, params.clutter_density, params.gate[m], m)
    pairs = jipda.Pairs(g.rows, g.cols, g.nu, g.d2, gating.log_likelihood)
    ja = jipda.from_weights(g.rows, assoc.weight, existence)
    if modes is None:
        post = jipda.update(pred, gating.lin, scan.R, pairs, ja, c, (gating.S, gating.logdet))
    else:
        modes, post = jipda.imm_update(modes, pred.x, gating.lin, scan.R, pairs, ja, c)
    reported, obs = jipda.equivalent_observation(pred, gating.lin, scan.R, pairs, ja)
    return Updated(tracks._replace(x=post.x, P=post.P, existence=existence, modes=modes), reported,
                   Observation(*obs))


def existence_manage(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
                     ) -> tuple[TrackSet, np.ndarray]:
    """Role 6 for ``jipda``: confirmation and deletion by existence (:func:`jipda.derived_rules`);
    the counts kept as :func:`m_of_n` keeps them."""
    counted, _ = m_of_n(tracks, detected, params, sees)
    if tracks.existence is None:  # no tracks yet
        return counted, np.zeros(tracks.size, bool)
    pg = jipda.scan_constants(params.pd, params.clutter_density, params.gate[2], 2).pg
    confirmed, live = jipda.manage(tracks.existence, tracks.confirmed, jipda.derived_rules(params.pd, pg))
    return counted._replace(confirmed=confirmed), live


JIPDA = Associator("jipda", jipda.associate_scan, jipda_update, existence_manage)
ASSOCIATORS[JIPDA.name] = JIPDA


def start_tracks(scan: SensorScan, det: np.ndarray, params: TrackParams, first_id: int,
                 two: tuple[initiation.Pairing, TrackSet] | None = None) -> tuple[TrackSet, Observation]:
    """Tentative tracks from the detections ``det`` of ``scan`` (one-point initialization); with
    ``two`` (pairs of these detections, :func:`initiation.pair_starts`, with their starts' tracks),
    the pairs' two-point states and, in a tracker of several sensors' scans, their starts' sensors
    too."""
    d = params.dim
    pos, Ppos = position_from_detection(scan.z[det], scan.R, scan.sensor_position)
    k = pos.shape[1]
    n = pos.shape[0]
    pidx = [0, 2, 4][:k]
    x = np.zeros((n, d))
    x[:, pidx] = pos
    P = np.zeros((n, d, d))
    P[np.ix_(np.arange(n), pidx, pidx)] = Ppos
    for v in (1, 3, 5)[: d // 2]:
        P[:, v, v] = params.init_velocity_std**2
    if d == 6 and k == 2:
        P[:, 4, 4] = params.init_z_std**2
    obs = Observation(np.broadcast_to(position_matrix(d, k), (n, k, d)).copy(), Ppos, pos)
    one = np.ones(n, np.int64)
    by = np.full(n, params.sensor_bit, np.int64) if params.sensor_bit else None
    if two is not None:
        x, P = two[0].x.copy(), two[0].P.copy()
        if by is not None and two[1].detected_by is not None:
            by |= two[1].detected_by
    ids = first_id + np.arange(n, dtype=np.int64)
    man = None if params.maneuver is None else maneuver.start(x, P, scan.t, params.maneuver)
    inputs = None if params.detector is None else detector.start(n, d, scan.t, params.detector)
    existence = None if params.initial_existence is None else np.full(n, params.initial_existence)
    modes = None if params.modes is None else start_modes(x, P, params.modes)
    # confirmed at birth by the count (1 of 1) only where the count confirms: jipda's existence does
    born = (one >= params.confirm_hits) & (existence is None)
    return TrackSet(ids, x, P, one, one.copy(), np.zeros(n, np.int64), born, man, inputs, existence, modes, by), obs


class Initiated(NamedTuple):
    """Role 5's result: the new tracks (one per detection given, then one per pair) with their
    observations and each one's detection (index into the detections given), the one-point starts
    waiting after the scan, and the scan's pairs (:func:`initiation.pair_starts`) with their starts'
    rows in the tracks given to :func:`initiate`."""

    tracks: TrackSet
    observations: Observation
    source: np.ndarray
    starts: initiation.Starts
    pairs: initiation.Pairing
    partners: np.ndarray


def initiate(starts: initiation.Starts, tracks: TrackSet, live: np.ndarray, scan: SensorScan, det: np.ndarray,
             params: TrackParams, first_id: int) -> Initiated:
    """Role 5: tracks from the detections ``det`` no track took: a one-point start from each (as
    before two-point starts: a slow target's first detection starts its track whatever it pairs
    with) and a two-point start from each pair (:mod:`.initiation`; at most one per detection). A
    pair's track counts afresh, one hit at one scan old (its second detection says only that it
    lies within the speed bound's reach, as a clutter detection there does with probability
    ``lambda V``; counted as a second hit it let clutter pairs confirm on one more clutter hit: the
    false tracks of gnn's ``mtt-local`` on the default scenario doubled). ``tracks``, ``live``: the
    tracker's tracks (or mht's leaves) after the scan's update and life rules; a start waits while
    its track is live with its one detection, each at most until it pairs."""
    one, obs = start_tracks(scan, det, params, first_id)
    if params.max_speed <= 0.0:  # no two-point starts: nothing waits
        return Initiated(one, obs, np.arange(det.size), starts, initiation.no_pairing(params.dim),
                         np.zeros(0, np.int64))
    lone = np.flatnonzero(live & (tracks.hits == 1))
    order = np.argsort(tracks.ids[lone], kind="stable")
    at = np.minimum(np.searchsorted(tracks.ids[lone], starts.ids, sorter=order), max(lone.size - 1, 0))
    rows = lone[order[at]] if lone.size else np.zeros(starts.ids.size, np.int64)
    waiting = (tracks.ids[rows] == starts.ids) if lone.size else np.zeros(starts.ids.size, bool)
    pos, cov = position_from_detection(scan.z[det], scan.R, scan.sensor_position)
    scale = np.ones(det.size)
    if scan.sensor_position is not None:  # a radar's clutter per m^3: its density over |det J| = r^2 cos(el)
        scale = 1.0 / (scan.z[det, 0] ** 2 * np.abs(np.cos(scan.z[det, 2])))
    by_existence = params.initial_existence is not None or (params.mht is not None
                                                            and params.mht.management == "score")
    pairs = initiation.pair_starts(starts, waiting, scan.t, pos, cov, scale, initiation.PairParams(
        params.dim, params.q, params.noise_model, params.max_speed, params.init_velocity_std, params.init_z_std,
        params.gate, params.pd, params.clutter_density, initiation.least_log_lr(params.pd, by_existence)))
    partners = rows[pairs.start]
    waiting[pairs.start] = False
    kept = initiation.recorded(starts, waiting, one.ids, scan.t, pos, cov)
    if not pairs.det.size:
        return Initiated(one, obs, np.arange(det.size), kept, pairs, partners)
    two, obs_two = start_tracks(scan, det[pairs.det], params, first_id + det.size, (pairs, tracks.take(partners)))
    return Initiated(_concat(one, two), Observation(*(np.concatenate(u) for u in zip(obs, obs_two))),
                     np.concatenate([np.arange(det.size), pairs.det]), kept, pairs, partners)


def paired_log_odds(log_odds: np.ndarray, init: Initiated, partner_log_odds: np.ndarray) -> np.ndarray:
    """New tracks' existence log odds (jipda's existence, mht's score): ``log_odds`` (the one-point
    starts'), then for each pair's track its start's before the scan (``partner_log_odds``, over the
    tracks given to :func:`initiate`) plus the pair's log-likelihood ratio
    ``ln(1 - P_D + P_D / (lambda V))``: the start's track updated, as jipda's and mht's own
    update of a track with one detection in its gate, by the second detection under the speed
    bound (its density ``1 / V``) instead of the zero-velocity start's gate."""
    return np.concatenate([log_odds, partner_log_odds[init.partners] + init.pairs.log_lr])


def deletion_at(params: TrackParams, dt: float) -> TrackParams:
    """``params`` for a scan ``dt`` [s] after the tracker's last: ``delete_misses`` at least the
    misses in a row whose chance for a live target at ``pd`` is at most
    :func:`~.config.scan_lost` (``LOST`` a second as well as a scan: at P_D 0.9, 4 from 0.1 s to
    1 s apart, 5 at 20 Hz). In a tracker of several sensors' scans (``sensor_bit``) that is the
    cap of :func:`scan_counts`; a track one sensor detected takes that sensor's own interval
    (``lone_misses``, set in ``mtt-centralized``'s parameters)."""
    lost = scan_lost(dt)
    if lost == LOST:
        return params
    m = int(miss_count(log_miss_of(params.pd), lost))
    return params._replace(delete_misses=m) if m > params.delete_misses else params


def tracker_step(state: TrackerState, scan: SensorScan, params: TrackParams,
                 q_scale: float | np.ndarray = 1.0) -> ScanResult:
    """Process one scan (times must not decrease); ``q_scale`` scales ``Q`` (federated ``beta_i``)."""
    tracks = state.tracks
    if state.t is not None and scan.t < state.t:
        raise ValueError(f"scan at t = {scan.t} is before the tracker's time {state.t}")
    dt = 0.0 if state.t is None else scan.t - state.t
    params = deletion_at(params, dt)
    if params.associator.step is not None:
        return params.associator.step(state, scan, params, q_scale)
    if params.initial_existence is not None and tracks.existence is None:  # an empty set keeping existence
        tracks = tracks._replace(existence=np.zeros(tracks.size))
        state = state._replace(tracks=tracks)
    at_scan, pred = predict_tracks(tracks, dt, params, q_scale)
    gating = gate_scan(pred, scan, params, _modes_at_scan(at_scan, params))
    sees = scan_sees(pred.x, gating, scan, params)
    assoc = associate(state, gating, scan, params, dt, sees)
    role = params.associator
    if role.update is None:
        upd = hard_update(at_scan, pred, gating, assoc, scan, dt, params, q_scale)
    else:
        upd = role.update(at_scan, pred, gating, assoc, scan, dt, params, q_scale)
    updated, live = (m_of_n if role.manage is None else role.manage)(upd.tracks, upd.detected, params, sees)
    det = np.flatnonzero(~assoc.claimed)
    init = initiate(state.starts, updated, live, scan, det, params, state.next_id)
    new, obs_new = init.tracks, init.observations
    if assoc.birth is not None or new.existence is not None:
        born = assoc.birth[det] if assoc.birth is not None else new.existence[:det.size]
        if init.pairs.det.size:  # a pair's track: its start's existence before the scan, predicted to it
            born = expit(paired_log_odds(logit(born), init, logit(jipda.predicted_existence(tracks.existence, dt))))
        new = new._replace(existence=born)
    detected = np.concatenate([upd.detected[live], np.ones(new.size, bool)])
    keep_info = live[upd.detected]
    return ScanResult(TrackerState(_concat(updated.take(live), new), scan.t, state.next_id + new.size, assoc.memory,
                                   init.starts),
                      detected, Observation(*(np.concatenate([u[keep_info], v]) for u, v in zip(upd.observations,
                                                                                                 obs_new))),
                      tracks.ids[~live])


def mht_step(state: TrackerState, scan: SensorScan, params: TrackParams, q_scale: float | np.ndarray = 1.0
             ) -> ScanResult:
    """The scan with ``associator = "mht"`` (:mod:`.mht`): the roles run on the branches its memory
    holds (every track's leaves) instead of the tracks, with two modes per leaf as
    :func:`hard_update` on a track (``process_noise = "imm"``); the tracks are the best global
    hypothesis's, by id. The given tracks' ``x``, ``P`` replace those of the best hypothesis's
    leaves first (a federated tracker's resets; otherwise they are those leaves')."""
    settings, d, m = params.mht, params.dim, scan.dim
    mem = state.memory if state.memory is not None else mht.initial_state(empty_tracks(d), settings.window)
    mp = mht.mht_params(settings, params.pd, params.clutter_density, params.gate[m], m,
                        (params.confirm_hits, params.confirm_window, params.delete_misses))
    leaves, n_det = mem.leaves, scan.z.shape[0]
    best = np.flatnonzero(mem.hyps[0])
    best = best[np.argsort(leaves.ids[best], kind="stable")]
    if np.array_equal(leaves.ids[best], state.tracks.ids):  # the tracks as given (federated resets)
        x, P = leaves.x.copy(), leaves.P.copy()
        x[best], P[best] = state.tracks.x, state.tracks.P
        leaves = leaves._replace(x=x, P=P)
    dt = 0.0 if state.t is None else scan.t - state.t
    at_scan, (x, P) = predict_tracks(leaves, dt, params, q_scale)
    modes = _modes_at_scan(at_scan, params)  # each leaf's modes (process_noise = "imm")
    gating = gate_scan(GaussianState(x, P), scan, params, modes)
    g_rows = g_cols = np.zeros(0, np.int64)
    nu, inc, miss = np.zeros((0, m)), np.zeros(0), mht.miss_increment(mp)
    if gating is not None:
        g_rows, g_cols, nu, _ = gating.pairs
        inc, miss = mht.score_increments(gating.log_likelihood, mp,
                                         None if scan.amplitude is None else scan.amplitude[g_cols])
    br = mht.extend_clusters(mem._replace(leaves=leaves), n_det, g_rows, g_cols, inc, miss, mp)
    hit = br.pair >= 0
    pidx = br.pair[hit]
    cx, cP = x[br.parent], P[br.parent]
    cmodes = None if modes is None else modes.take(br.parent)  # a miss keeps its parent's prediction
    obs = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
    if pidx.size:
        H, x0 = gating.lin.H[g_rows[pidx]], cx[hit]
        cx[hit], cP[hit] = detection_update(x0, cP[hit], cmodes, np.flatnonzero(hit), nu[pidx], H, scan.R)
        obs = Observation(H, np.broadcast_to(scan.R, (pidx.size, m, m)).copy(), nu[pidx] + np.einsum("nij,nj->ni", H, x0))
    sees = scan_sees(x, gating, scan, params)
    old, counted, need = scan_counts(leaves.take(br.parent), hit, params,
                                     None if sees is None else sees.take(br.parent))
    step = np.where(hit, 0.0, miss * counted)  # each branch's score increment (a miss the scan counts)
    step[hit] = inc[pidx]
    score = mem.score[br.parent] + step
    peak = np.maximum(mem.peak[br.parent], score)
    hits, age, misses = old.hits + hit, old.age + counted, np.where(hit, 0, old.misses + counted)
    confirmed, live = mht.manage(mp._replace(delete_misses=need), old.confirmed, score, peak, hits, age, misses)
    children = TrackSet(old.ids, cx, cP, hits, age, misses, confirmed, modes=cmodes, detected_by=old.detected_by)
    fresh = br.births  # a detection that a kept hypothesis of its cluster leaves unused starts a track there
    init = initiate(state.starts, children, live, scan, fresh, params, state.next_id)
    new, obs_new = init.tracks, init.observations
    new_score = mht.birth_scores(mp, None if scan.amplitude is None else scan.amplitude[fresh], fresh.size)
    if init.pairs.det.size:  # a pair's track: its start's leaf's score before the scan and the pair's ratio
        new_score = paired_log_odds(new_score, init, mem.score[br.parent])
    if mp.management == "score":
        new = new._replace(confirmed=new_score >= mp.confirm_score)
    n_child = br.parent.size
    serial = mem.next_branch + np.arange(n_child + new.size)
    lineage = np.concatenate([mem.lineage[br.parent, 1:], serial[:n_child, None]], axis=1)
    grown = mht.MhtState(_concat(children, new), np.concatenate([score, new_score]),
                         np.concatenate([peak, new_score]),
                         np.concatenate([lineage, np.repeat(serial[n_child:, None], settings.window, axis=1)]),
                         np.concatenate([br.holds, br.birth_holds[:, init.source]], axis=1), br.value,
                         int(mem.next_branch + serial.size),
                         np.concatenate([mht.leaf_existence(mem.existence[br.parent], step, dt),
                                         mht.birth_existence(new_score)]),
                         np.concatenate([br.cluster, br.birth_cluster[init.source]]))
    branch_det = np.full(n_child, -1)  # each branch's detection (-1: a miss), then the new tracks'
    branch_det[hit] = g_cols[pidx]
    branch_det = np.concatenate([branch_det, fresh[init.source]])  # a pair's track: its detection's too
    branch_obs = np.full(branch_det.size, -1)  # each branch's row of the observations
    branch_obs[branch_det >= 0] = np.arange(pidx.size + new.size)
    mem, kept = mht.prune(grown, np.concatenate([live, np.ones(new.size, bool)]), mp)
    best = np.flatnonzero(mem.hyps[0])
    best = best[np.argsort(mem.leaves.ids[best], kind="stable")]
    rows = branch_obs[kept[best]]
    all_obs = [np.concatenate([u, v]) for u, v in zip(obs, obs_new)]
    tracks = mem.leaves.take(best)
    tracks = tracks._replace(confirmed=mht.shown(mp.management, tracks.confirmed, mem.existence[best]))
    return ScanResult(TrackerState(tracks, scan.t, state.next_id + new.size, mem, init.starts), rows >= 0,
                      Observation(*(a[rows[rows >= 0]] for a in all_obs)),
                      np.setdiff1d(leaves.ids, mem.leaves.ids))


def mht_decided(then: TrackerState, later: TrackerState, back: int, management: str) -> TrackerState:
    """The MHT's deferred decision (docs/mht.md#the-picture-the-n-scan-back-decision): ``then``, the
    state after a scan, with its tracks replaced by those of the best hypothesis of ``later``, the
    state ``back`` scans on (``1 <= back < window``), each as its ancestor at ``then``'s scan was
    (the filtered ``x``, ``P`` and modes along the branch that hypothesis kept: the leaf of
    ``then`` whose serial is ``lineage[:, -1 - back]``), sorted by id. A track born after
    ``then``'s scan has no such ancestor and is left out. Status as decided: shown
    (:func:`mht.shown`) when ``later``'s leaf is confirmed and the ancestor's existence was at
    least 1/2 (confirmation is a decision the window defers too; the existence is the branch's
    at ``then``'s scan)."""
    past, now = then.memory, later.memory
    if past is None or now is None or not past.leaves.size:
        return then
    best = np.flatnonzero(now.hyps[0])
    ancestor = now.lineage[best, -1 - back]
    own = past.lineage[:, -1]
    order = np.argsort(own, kind="stable")
    at = order[np.minimum(np.searchsorted(own, ancestor, sorter=order), own.size - 1)]
    found = own[at] == ancestor
    rows, leaves = at[found], best[found]
    by_id = np.argsort(past.leaves.ids[rows], kind="stable")
    rows, leaves = rows[by_id], leaves[by_id]
    tracks = past.leaves.take(rows)
    confirmed = mht.shown(management, now.leaves.confirmed[leaves], past.existence[rows])
    return then._replace(tracks=tracks._replace(confirmed=confirmed))


def _whole_scan(*_: object) -> None:
    raise TypeError("mht takes the whole scan (Associator.step), not the tracker's chain")


MHT = Associator("mht", _whole_scan, step=mht_step)
ASSOCIATORS[MHT.name] = MHT
