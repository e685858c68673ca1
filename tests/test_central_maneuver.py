"""Maneuver detection per central track (paper 004's input estimation on the central filter)."""

from __future__ import annotations

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.central_track import CentralTracks
from fedtrack.local_filters.linear.kalman import GaussianState, update
from fedtrack.local_filters.mtt.maneuver import maneuver_models
from fedtrack.local_filters.mtt.models import position_matrix, predict_batch
from fedtrack.local_filters.vdie.estimation import VdieParams, bank_accumulate, bank_best, bank_empty, bank_push
from fedtrack.local_filters.vdie.input_bank import input_step, new_banks

Q = 0.5


def ca_truth(x0: np.ndarray, a: np.ndarray, t_on: float, t: float) -> np.ndarray:
    """A CV target from ``x0`` at 0 that accelerates by ``a`` (x, y) from ``t_on`` on (state order
    ``[x, vx, y, vy(, z, vz)]``)."""
    x = x0.copy()
    x[0::2] += x0[1::2] * t
    s = max(t - t_on, 0.0)
    for axis in range(2):
        x[2 * axis] += 0.5 * a[axis] * s * s
        x[2 * axis + 1] += a[axis] * s
    return x


@pytest.mark.parametrize("dim", [4, 6])
def test_noise_free_acceleration_is_recovered_exactly_over_irregular_intervals(dim: int) -> None:
    """A filter that starts at the true state sees innovations only from the acceleration, so the
    candidate at its true onset explains them all: u equals the acceleration to round-off and that
    candidate is the most likely, with irregular intervals and (3-D) position observations of
    sizes 2 and 3."""
    rng = np.random.default_rng(3)
    params = VdieParams(window=40)
    store = CentralTracks(dim, Q, "continuous", max_lag=1e9, detector=params)
    x0 = np.zeros(dim)
    x0[1], x0[3] = 12.0, -7.0
    a = np.array([1.5, -0.8])
    store.start(0, 0.0, x0, np.eye(dim) * 50.0)
    slots = store.slots_of([0])
    times = np.cumsum(rng.uniform(0.1, 0.9, size=30))
    t_on = float(times[9])
    for t in times.tolist():
        m = 2 if dim == 4 else int(rng.integers(2, 4))
        H = position_matrix(dim, m)
        z = H @ ca_truth(x0, a, t_on, t)
        assert store.fuse(slots, t, H[None], np.eye(m)[None] * 4.0, z[None])[0][0]
    det = store.maneuvers_at(slots, float(times[-1]))
    assert det.onset[0] == t_on
    np.testing.assert_allclose(det.u[0], a, rtol=0, atol=1e-9)
    assert det.detected(params)[0] and det.count[0] == 20


def test_equals_the_trackers_input_estimator_over_irregular_intervals() -> None:
    """The central detector (innovation form, every candidate's columns at once) and the
    trackers' VDIE bank (bank_accumulate, bank_best: information form) are one estimator: every
    step's most likely candidate, its u and statistic agree to 1e-9 on noisy data over random
    intervals (the banks carry the bias per unit input, so the interval may change)."""
    rng = np.random.default_rng(11)
    window, n_runs = 6, 5
    H = np.broadcast_to(position_matrix(4), (n_runs, 2, 4))
    R = np.broadcast_to(np.eye(2) * 9.0, (n_runs, 2, 2))
    x = rng.normal(size=(n_runs, 4)) * 5.0
    P = np.broadcast_to(np.eye(4) * 20.0, (n_runs, 4, 4)).copy()
    ours = new_banks(n_runs, window, 4, 0.0)
    theirs = bank_push(bank_empty((n_runs,), window, 4), 0.0, None, np.ones(n_runs, bool))
    t = 0.0
    for k in range(1, 25):
        dt = round(float(rng.uniform(0.1, 1.5)), 3)
        t += dt
        cv, _ = maneuver_models(dt, Q, "continuous")
        z = rng.normal(size=(n_runs, 2)) * 3.0 + 0.4 * k * k  # a growing bias: large statistics
        xp, Pp = predict_batch(x, P, np.full(n_runs, dt), Q)
        x, P = update(GaussianState(xp, Pp), z, H, R)[0]
        ours, det = input_step(ours, np.full(n_runs, dt), xp, Pp, H, R, z, t)
        theirs = bank_accumulate(theirs, cv.F, cv.B, False, GaussianState(xp, Pp), GaussianState(x, P))
        best = bank_best(theirs)
        theirs = bank_push(theirs, t, None, np.zeros(n_runs, bool))
        np.testing.assert_array_equal(det.onset, best.onset)
        np.testing.assert_allclose(det.statistic, best.statistic, rtol=1e-9)
        np.testing.assert_allclose(det.u, best.u, rtol=1e-9, atol=1e-12)


def test_out_of_sequence_detection_equals_time_sorted_detection() -> None:
    """Noisy observations of accelerating targets, fused shuffled (out of sequence) and in time
    order: the detector's result after every kept entry is the same to 1e-9."""
    rng = np.random.default_rng(8)
    params = VdieParams(window=10)
    n_tracks = 4
    x0 = rng.normal(size=(n_tracks, 4)) * 10.0
    times = np.round(np.cumsum(rng.uniform(0.1, 0.6, size=40)), 3)
    obs = []
    for t in times.tolist():
        z = np.stack([ca_truth(x0[c], np.array([2.0, -1.0]), 5.0, t)[[0, 2]] for c in range(n_tracks)])
        obs.append((t, z + rng.normal(size=z.shape) * 2.0))
    arrival = sorted(range(len(obs)), key=lambda i: obs[i][0] + rng.uniform(0.0, 1.5))
    stores = []
    for order in (range(len(obs)), arrival):
        store = CentralTracks(4, Q, "continuous", max_lag=3.0, detector=params, depth=2)
        for c in range(n_tracks):
            store.start(c, 0.0, x0[c], np.eye(4) * 30.0)
        slots = store.slots_of(list(range(n_tracks)))
        H, R = np.repeat(position_matrix(4)[None], n_tracks, 0), np.repeat(np.eye(2)[None] * 4.0, n_tracks, 0)
        for i in order:
            assert store.fuse(slots, obs[i][0], H, R, obs[i][1])[0].all()
        stores.append((store, slots))
    (a, slots), (b, _) = stores
    checked = 0
    for t in times[times >= times[-1] - 3.0].tolist():
        da, db = a.maneuvers_at(slots, t), b.maneuvers_at(slots, t)
        np.testing.assert_array_equal(da.onset, db.onset)
        np.testing.assert_allclose(da.statistic, db.statistic, rtol=1e-9)
        np.testing.assert_allclose(da.u, db.u, rtol=1e-9, atol=1e-9)
        checked += int(da.detected(params).sum())
    assert checked > 0  # the comparison covers detections, not only quiet tracks


def test_detection_power_and_false_alarms_over_seeded_runs() -> None:
    """200 seeded runs of one target seen by three sensors (periods 1.0, 0.7, 1.3 s, 10 m noise,
    q = 1): on the straight leg (10-30 s) false alarms stay below paper 004's 3-sigma level
    (0.0027 per observation); a 3 m/s^2 acceleration from 30 s is detected within 10 s in at
    least 95 % of the runs (measured: 0.0001 and 100 %, median delay 6.5 s)."""
    rng = np.random.default_rng(1)
    n, params = 200, VdieParams(window=30)  # the default central_maneuver_window
    store = CentralTracks(4, 1.0, "continuous", max_lag=3.0, detector=params)
    x0 = np.array([0.0, 10.0, 0.0, 5.0])
    for c in range(n):
        store.start(c, 0.0, x0, np.diag([100.0, 900.0, 100.0, 900.0]))
    slots = store.slots_of(list(range(n)))
    times = sorted(set(np.round(np.concatenate([np.arange(0.3, 45, 1.0), np.arange(0.1, 45, 0.7),
                                                np.arange(0.5, 45, 1.3)]), 6).tolist()))
    a, t_on = np.array([1.8, 2.4]), 30.0
    H, R = np.repeat(position_matrix(4)[None], n, 0), np.repeat(np.eye(2)[None] * 100.0, n, 0)
    false_alarms = straight = 0
    delay = np.full(n, np.inf)
    for t in times:
        z = ca_truth(x0, a, t_on, t)[[0, 2]] + rng.normal(size=(n, 2)) * 10.0
        store.fuse(slots, t, H, R, z)
        det = store.maneuvers_at(slots, t).detected(params)
        if 10.0 <= t < t_on:
            false_alarms, straight = false_alarms + int(det.sum()), straight + n
        elif t >= t_on:
            delay = np.where(det & np.isinf(delay), t - t_on, delay)
    assert false_alarms / straight < 0.0027
    assert np.mean(delay <= 10.0) >= 0.95 and np.median(delay) > 1.0  # not at the onset itself


def test_track_to_track_replay_reports_central_maneuvers_without_changing_estimates(tmp_path) -> None:
    """mtt-federated with [mtt] maneuver = "vdie": the central estimates equal those without the
    detector, and the accelerating target's central track carries a maneuver after its onset
    (its estimated acceleration near the true one), none before; evaluate counts the flags."""
    import json

    from fedtrack.fusion_center.mtt.evaluation import evaluate
    from fedtrack.fusion_center.mtt.replay import replay_mtt

    rng = np.random.default_rng(2)
    x0, a, t_on = np.array([0.0, 20.0, 0.0, -5.0]), np.array([0.0, 4.0]), 40.0
    rows, truth = [], []
    for sensor, period, phase in (("s1", 1.0, 0.2), ("s2", 0.7, 0.5), ("s3", 1.3, 0.1)):
        for t in np.arange(phase, 60.0, period).round(6).tolist():
            z = ca_truth(x0, a, t_on, t)[[0, 2]] + rng.normal(size=2) * 5.0
            rows.append({"t": t, "sensor": sensor, "R": [[25.0, 0.0], [0.0, 25.0]], "detections": [{"z": z.tolist()}]})
    rows.sort(key=lambda r: r["t"])
    for t in np.arange(0.0, 61.0):
        truth.append({"t": t, "targets": [{"id": 0, "x": ca_truth(x0, a, t_on, t).tolist()}]})
    measurements = tmp_path / "m.jsonl"
    measurements.write_text("".join(json.dumps(r) + "\n" for r in rows))
    (tmp_path / "truth.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    base = "[mtt]\nq = 1.0\npd = 1.0\nclutter_density = 0.0\ninit_velocity_std = 30.0\n"
    (tmp_path / "cv.toml").write_text(base)
    (tmp_path / "man.toml").write_text(base + 'maneuver = "vdie"\n')
    out = {}
    for name in ("cv", "man"):
        replay_mtt("mtt-federated", measurements, tmp_path / f"{name}.toml", tmp_path / f"{name}.jsonl")
        out[name] = [json.loads(line) for line in (tmp_path / f"{name}.jsonl").read_text().splitlines()]
    flags = []
    for plain, pic in zip(out["cv"], out["man"]):
        assert [t["id"] for t in plain["tracks"]] == [t["id"] for t in pic["tracks"]]
        for p, q in zip(plain["tracks"], pic["tracks"]):
            assert p["x"] == q["x"] and p["P"] == q["P"] and "maneuver" not in p
            if "maneuver" in q:
                flags.append((pic["t"], q["maneuver"]))
    assert flags and all(t > t_on and m["onset"] >= t_on - 3.0 for t, m in flags)
    first = flags[0][1]  # the onset event: its onset and acceleration near the truth's
    assert abs(first["onset"] - t_on) < 3.0 and np.hypot(*(np.array(first["accel"]) - a)) < 1.0
    result = evaluate(tmp_path / "man.jsonl", tmp_path / "truth.jsonl")["maneuvers"]
    assert result["onsets"] >= 1 and result["flagged_while_maneuvering"] > 0.3
    assert result["flagged_while_straight"] == 0.0


def test_truth_motion_classes() -> None:
    """evaluate's truth classes: accelerating from 1 m/s^2 (central difference of the truth
    velocities), straight only after 10 s without any acceleration, in between otherwise."""
    from fedtrack.fusion_center.mtt.evaluation import truth_motion

    x0, a, t_on, t_off = np.array([0.0, 10.0, 0.0, 0.0]), np.array([0.0, 2.0]), 20.0, 25.0
    lines = []
    for t in np.arange(0.0, 50.0):
        x = ca_truth(x0, a, t_on, min(t, t_off))
        x[0::2] += x[1::2] * max(t - t_off, 0.0)  # straight again after t_off
        lines.append((float(t), [{"id": 7, "x": x.tolist()}]))
    motion = truth_motion(lines)
    assert motion[(5.0, 7)] == "between" and motion[(12.0, 7)] == "straight"  # 10 s into the data
    assert motion[(22.0, 7)] == "maneuvering" and motion[(30.0, 7)] == "between"
    assert motion[(36.0, 7)] == "straight" and (0.0, 7) not in motion and (49.0, 7) not in motion
