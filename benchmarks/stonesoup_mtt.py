"""Stone Soup's multi-target GNN tracker and its JPDA tracker on a ``replay`` input: the anchors
of issues 12 and 25's GOSPA comparisons (Stone Soup comes only from the ``bench`` extra).

Our configuration of it, as close to fedtrack's ``mtt`` trackers as Stone Soup allows:

* motion: ``ConstantVelocity(noise_diff_coeff = [mtt] q)`` per axis (the same continuous
  white-noise acceleration model as fedtrack's default ``noise_model``);
* measurement: each line's own ``R`` through a ``LinearGaussian`` position model, or for a radar
  scan ``CartesianToElevationBearingRange`` about its ``sensor_position`` (our ``[r, az, el]``,
  azimuth from x, is its ``[elevation, bearing, range]`` reordered, ``R`` with it); with a radar in
  the input the state is 3-D (a third ``ConstantVelocity`` for z);
* ``KalmanPredictor`` / ``KalmanUpdater`` (``ExtendedKalmanUpdater`` with a radar, the same on the
  linear models), in the Joseph form kept symmetric as ours (``use_joseph_cov``,
  ``force_symmetric_covariance``; since 2026-11-26: its default update lost positive definiteness
  on the recorded-traffic radars); ``DistanceHypothesiser`` with the Mahalanobis distance gated at
  the square root of the chi-square(m) quantile of ``gate_probability`` (m = 2, or 3 with a
  radar: one gate serves every sensor); ``GNNWith2DAssignment``;
* ``MultiMeasurementInitiator`` with ``min_points = confirm_hits`` from a prior with zero
  velocity and ``init_velocity_std`` (and z = 0 with ``init_z_std``); a tentative track is dropped after
  ``confirm_window - confirm_hits + 1`` scans without an update, a confirmed one after the
  sensor's ``MttConfig.misses_to_delete`` (``delete_misses``, more below P_D 0.9, and at its
  median scan interval below 1 s, where ours take the interval of each scan;
  ``UpdateTimeStepsDeleter``: fedtrack's rules, counted in scans), or on the
  scans of several sensors after ``max(delete_misses, CENTRAL_MISSES x sensors)`` in a row,
  ``mtt-centralized``'s rule (``fusion_center/mtt/engines.py::central_params``; before
  2026-11-26 Stone Soup kept 3 there, which dropped live targets more often and dead targets'
  tracks sooner than ours: docs/bench.md, the assocbench section);
* ``"gnn"``: ``MultiTargetTracker``; ``"jpda"``: ``PDAHypothesiser`` (``[mtt]``
  ``clutter_density``, ``pd``, ``prob_gate = gate_probability``, ``include_all``) wrapped in
  ``DistanceGater(Mahalanobis(), gate_threshold = gate)``, the GNN's gate above, so both trackers
  (and ours) see the same detections per track, and ``prob_gate`` is that gate's probability
  (with a radar, the 3-dof gate holds a little more of a position sensor's 2-D detections);
  the joint association probabilities by ``JPDAwithEHM``, Stone Soup's exact JPDA per cluster of
  tracks sharing detections (its plain ``JPDA`` enumerates the product of every track's
  hypotheses, about 1e13 joint events a scan on the default scenario, and never finished; on
  10 targets the two give the same pictures to 1e-11); in ``MultiTargetMixtureTracker``, which
  reduces each track's mixture to one Gaussian and counts a scan as an update when some
  detection outweighs the miss (what its deleter counts); its initiator is the GNN one above
  (as in Stone Soup's JPDA tutorial);
* Stone Soup has no out-of-sequence handling: it gets the scans sorted by time (as if it had
  waited for every late scan), which favours it.

The track picture at every ``period`` holds each track's last state predicted to ``t``, in the
format of ``replay`` (all Stone Soup tracks are confirmed ones), so ``fedtrack evaluate``
scores it like ours.
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import chdtri

from fedtrack.fusion_center.mtt.centre.track_life import CENTRAL_MISSES

EPOCH = datetime.datetime(2000, 1, 1)


def _stamp(t: float) -> datetime.datetime:
    return EPOCH + datetime.timedelta(seconds=t)


def read_scans(measurements: Path, sensors: set[str] | None) -> list[dict[str, Any]]:
    """The input lines of ``sensors`` (all when None), sorted by time."""
    scans = []
    with measurements.open() as fh:
        for line in fh:
            row = json.loads(line)
            if sensors is None or row["sensor"] in sensors:
                scans.append(row)
    scans.sort(key=lambda r: r["t"])
    return scans


def scan_interval(scans: list[dict[str, Any]]) -> float:
    """The median time between successive scans (sorted by time; 0 with fewer than two)."""
    t = np.array([row["t"] for row in scans])
    return float(np.median(np.diff(t))) if t.size > 1 else 0.0


def stonesoup_tracker(scans: list[dict[str, Any]], mtt: Any, out: Path, association: str = "gnn") -> dict[str, Any]:
    """Run Stone Soup's ``association`` (``"gnn"`` or ``"jpda"``) tracker over ``scans``; write the
    pictures to ``out``; return counts."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDAwithEHM
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.gater.distance import DistanceGater
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.measurement.nonlinear import CartesianToElevationBearingRange
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetMixtureTracker, MultiTargetTracker
    from stonesoup.types.angle import Bearing, Elevation
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater, KalmanUpdater

    radar = any("sensor_position" in row for row in scans)
    dim = 6 if radar else 4
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(mtt.q)] * (dim // 2))
    default_model = LinearGaussian(ndim_state=dim, mapping=(0, 2), noise_covar=np.eye(2))
    predictor = KalmanPredictor(transition)
    # the Joseph form, kept symmetric, as ours: its default form lost positive definiteness on the
    # Paris radars (584 covariances of 22 tracks from t = 415 s; docs/bench.md, the assocbench section)
    updater = (ExtendedKalmanUpdater if radar else KalmanUpdater)(default_model, use_joseph_cov=True,
                                                                  force_symmetric_covariance=True)
    gate = float(np.sqrt(chdtri(3 if radar else 2, 1.0 - mtt.gate_probability)))
    gnn = GNNWith2DAssignment(DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=gate))
    v2 = mtt.init_velocity_std**2
    prior = GaussianState(np.zeros((dim, 1)), np.diag([1.0, v2, 1.0, v2, mtt.init_z_std**2, v2][:dim]))
    initiator = MultiMeasurementInitiator(
        prior, UpdateTimeStepsDeleter(mtt.confirm_window - mtt.confirm_hits + 1), gnn, updater,
        min_points=mtt.confirm_hits)
    ids = sorted({row["sensor"] for row in scans})
    deleter = UpdateTimeStepsDeleter(max(mtt.delete_misses, CENTRAL_MISSES * len(ids)) if len(ids) > 1
                                     else mtt.misses_to_delete(ids[0], scan_interval(scans)) if ids
                                     else mtt.delete_misses)
    if association == "gnn":
        tracker = MultiTargetTracker(initiator, deleter, None, gnn, updater)
    elif association == "jpda":
        # every detection hypothesised, then the GNN's gate (one gate for every sensor, as ours)
        pda = PDAHypothesiser(predictor, updater, clutter_spatial_density=mtt.clutter_density, prob_detect=mtt.pd,
                              prob_gate=mtt.gate_probability, include_all=True)
        jpda = JPDAwithEHM(DistanceGater(pda, Mahalanobis(), gate_threshold=gate))
        tracker = MultiTargetMixtureTracker(initiator, deleter, None, jpda, updater)
    else:
        raise ValueError(f"association {association!r}: gnn or jpda")
    models: dict[str, Any] = {}
    ids: dict[Any, int] = {}
    pictures = 0

    def picture(T: float) -> dict[str, Any]:
        rows = []
        for track in tracker.tracks:
            state = predictor.predict(track.state, timestamp=_stamp(T)) if track.timestamp < _stamp(T) else track.state
            x, P = np.asarray(state.state_vector, float).ravel(), np.asarray(state.covar, float)
            rows.append({"id": ids.setdefault(track, len(ids)), "pos": x[0::2].tolist(), "vel": x[1::2].tolist(),
                         "x": x.tolist(), "P": P.tolist(), "status": "confirmed", "sensors": []})
        return {"t": T, "tracks": sorted(rows, key=lambda r: r["id"])}

    def scan_detections(row: dict[str, Any]) -> set[Any]:
        where = row.get("sensor_position")
        key = json.dumps([row["R"], where])
        when = _stamp(row["t"])
        if where is None:
            model = models.setdefault(key, LinearGaussian(ndim_state=dim, mapping=(0, 2),
                                                          noise_covar=np.asarray(row["R"])))
            return {Detection(np.asarray(d["z"], float).reshape(2, 1), timestamp=when, measurement_model=model)
                    for d in row["detections"]}
        order = [2, 1, 0]  # our [r, az, el] -> Stone Soup's [elevation, bearing, range]
        model = models.setdefault(key, CartesianToElevationBearingRange(
            ndim_state=6, mapping=(0, 2, 4), noise_covar=np.asarray(row["R"])[np.ix_(order, order)],
            translation_offset=StateVector(where)))
        return {Detection(StateVector([Elevation(d["z"][2]), Bearing(d["z"][1]), d["z"][0]]), timestamp=when,
                          measurement_model=model) for d in row["detections"]}

    def times() -> Iterator[float]:
        T = np.ceil(scans[0]["t"] / mtt.period) * mtt.period if scans else 0.0
        while True:
            yield float(T)
            T += mtt.period

    next_picture = times()
    T = next(next_picture)
    with out.open("w") as fh:
        for row in scans:
            while row["t"] > T + 1e-9:
                fh.write(json.dumps(picture(T)) + "\n")
                pictures += 1
                T = next(next_picture)
            tracker.update_tracker(_stamp(row["t"]), scan_detections(row))
        if scans:
            fh.write(json.dumps(picture(T)) + "\n")
            pictures += 1
    return {"scans": len(scans), "pictures": pictures, "tracks_started": len(ids)}
