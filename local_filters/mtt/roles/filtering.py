"""Roles 1 and 4 of a scan, each track's filter: predicted to the scan (CV, :mod:`..models`; or each
track in its own model with ``[mtt] maneuver = "vdie"``, :mod:`..maneuver`; or two motion modes with
``process_noise = "imm"``) and updated with its detections: one by the EKF in Joseph form, exact
Kalman for position sensors (:func:`hard_update`), or ``jipda``'s mixture (:func:`jipda_update`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, update_residual
from fedtrack.local_filters.mtt import detector, maneuver
from fedtrack.local_filters.mtt.association import Association
from fedtrack.local_filters.mtt.associators import jipda
from fedtrack.local_filters.mtt.models import Modes, modes_predict, modes_update, predict_batch
from fedtrack.local_filters.mtt.roles.gating import Gating
from fedtrack.local_filters.mtt.roles.tracks import Observation, TrackParams, TrackSet
from fedtrack.local_filters.mtt.scan import SensorScan


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


def predict_tracks(tracks: TrackSet, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0
                   ) -> tuple[TrackSet, GaussianState]:
    """Role 1 for the roles after it: the tracks with their modes (two per track) predicted ``dt``
    ahead, mixed once for both results, and every track's prediction (:func:`predict`)."""
    if params.modes is None or tracks.modes is None or not tracks.size:
        return tracks, predict(tracks, dt, params, q_scale)
    modes, pred = modes_predict(tracks.modes, dt, params.q, params.noise_model, params.modes, q_scale)
    return tracks._replace(modes=modes), pred


def modes_at_scan(tracks: TrackSet, params: TrackParams) -> Modes | None:
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
    modes = modes_at_scan(tracks, params)
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


def jipda_update(tracks: TrackSet, pred: GaussianState, gating: Gating | None, assoc: Association,
                 scan: SensorScan, dt: float, params: TrackParams, q_scale: float | np.ndarray = 1.0) -> Updated:
    """Role 4 for ``jipda``: each track's PDA mixture over its gated detections (:func:`jipda.update`;
    with two modes per track, each mode's with its own weights: :func:`jipda.imm_update`); a track
    that more likely than not exists and was detected is reported with its equivalent observation
    from the combined prediction (:func:`jipda.equivalent_observation`)."""
    d, m, n = params.dim, scan.dim, tracks.size
    existence = assoc.existence
    modes = modes_at_scan(tracks, params)
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
