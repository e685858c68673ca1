"""``[mtt] process_noise = "imm"``: two motion modes per track stay exact where the CV tracks are
(out-of-sequence scans and observations, hand-overs), and the key's rules
(docs/multitarget.md#covariance-consistency-nees)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_mtt_out_of_sequence import own_scans_out_of_sequence, replay, scans

from fedtrack.config import ConfigError
from fedtrack.fusion_center.mtt.central_track import CentralTracks
from fedtrack.local_filters.imm.filter import IMMState, combine
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.models import ModeRates, mode_transition, position_matrix

RATES = ModeRates(1.0 / 60.0, 1.0 / 15.0)


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized"])
def test_imm_pictures_from_out_of_sequence_scans_equal_time_sorted_delivery(tmp_path: Path, algorithm: str) -> None:
    """The scans of test_mtt_out_of_sequence (sensor a's own scans up to two periods late) with
    two modes per track: the pictures equal those of the time-sorted scans to 1e-9 (the trackers'
    re-runs carry each track's modes; the centre's re-fusions each central track's)."""
    arrived, in_time = scans(seed=7)
    assert own_scans_out_of_sequence(arrived, "a") >= 5
    cfg = {"max_lag": 3.0, "picture_delay": 2.5, "pd": 0.95, "clutter_density": 1e-9, "process_noise": "imm"}
    got = replay(tmp_path, "arrived", arrived, algorithm, **cfg)
    want = replay(tmp_path, "sorted", in_time, algorithm, **cfg)
    fixed = replay(tmp_path, "fixed", in_time, algorithm, **{**cfg, "process_noise": "fixed"})
    assert len(got) == len(want) >= 35
    for g, w in zip(got, want):
        assert [tr["id"] for tr in g["tracks"]] == [tr["id"] for tr in w["tracks"]], f"t = {g['t']}"
        for a, b in zip(g["tracks"], w["tracks"]):
            for key in ("x", "P"):
                np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-9 * np.max(np.abs(b[key])))
    assert sum(tr["status"] == "confirmed" for tr in got[-1]["tracks"]) == 5
    # the modes are in use: the pictures are not the fixed-q tracker's
    assert not np.allclose(got[-1]["tracks"][0]["P"], fixed[-1]["tracks"][0]["P"], rtol=1e-3)


def store_with_observations(order: np.ndarray, times: np.ndarray, z: np.ndarray) -> CentralTracks:
    """Two central tracks with modes, each fed every observation, in ``order``."""
    store = CentralTracks(4, 3.0, "continuous", max_lag=1e9, capacity=1, depth=2, modes=RATES)
    for cid in range(2):
        store.start(cid, 0.0, np.array([0.0, 10.0, 0.0, -5.0]), np.diag([100.0, 900.0, 100.0, 900.0]))
    H, R = position_matrix(4), np.array([[100.0, 20.0], [20.0, 64.0]])
    for k in order.tolist():
        ok = store.fuse(store.slots_of([0, 1]), float(times[k]), np.stack([H, H]), np.stack([R, R]), z[k])[0]
        assert ok.all()
    return store


def test_central_tracks_with_modes_fuse_out_of_sequence_observations_as_time_sorted() -> None:
    """Observations arriving shuffled into central tracks with two modes (the ring grows and the
    table too): every kept entry (combined state, each mode's state and probability) equals the
    time-sorted fusion's to 1e-9; a track handed to another table and back is its own."""
    rng = np.random.default_rng(3)
    times = np.round(rng.uniform(0.1, 30.0, 40), 3)
    truth = np.stack([times * 10.0 + 30.0 * np.sin(times / 5.0), -5.0 * times], axis=1)  # a gentle weave
    z = truth[:, None, :] + rng.normal(size=(40, 2, 2)) * 10.0
    shuffled = store_with_observations(rng.permutation(40), times, z)
    ordered = store_with_observations(np.argsort(times, kind="stable"), times, z)
    assert shuffled.reprocessed > 0 and shuffled.depth > 2 and shuffled.capacity > 1
    for cid in range(2):
        got, want = shuffled.entries(cid), ordered.entries(cid)
        assert len(got) == len(want) == 10  # t, x, P, m, H, R, z and the modes' x, P, mu
        for a, b in zip(got, want):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * max(1.0, float(np.max(np.abs(b)))))
        mode_x, mode_P, mu = got[-3:]
        x, P = combine(IMMState(mode_x, mode_P, mu))
        np.testing.assert_allclose(x, got[1], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(P, got[2], rtol=1e-12, atol=1e-9)
        assert 0.0 < mu[-1, 1] < 1.0
    other = CentralTracks(4, 3.0, "continuous", max_lag=1e9, modes=RATES)
    entries = shuffled.entries(0)
    other.place(0, True, entries)
    for a, b in zip(other.entries(0), entries):
        assert np.array_equal(a, b)


def test_mode_transition_over_any_interval_is_the_markov_chain() -> None:
    """``Pi(dt)`` is row-stochastic, the identity at 0, ``Pi(a) Pi(b) = Pi(a + b)``, and tends to
    the long-run probabilities."""
    a, b = mode_transition(0.7, RATES), mode_transition(1.6, RATES)
    np.testing.assert_allclose(a @ b, mode_transition(2.3, RATES), atol=1e-12)
    np.testing.assert_allclose(mode_transition(0.0, RATES), np.eye(2), atol=0)
    np.testing.assert_allclose(mode_transition(np.array([0.7, 1.6]), RATES), np.stack([a, b]), atol=0)
    np.testing.assert_allclose(a.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(mode_transition(1e4, RATES), np.stack([RATES.stationary] * 2), atol=1e-12)


def test_process_noise_key() -> None:
    MttConfig(process_noise="imm").validate()
    assert MttConfig().mode_rates is None
    assert MttConfig(process_noise="imm", maneuver_s=10.0, straight_s=40.0).mode_rates == ModeRates(1 / 40, 1 / 10)
    for bad, message in (({"process_noise": "adaptive"}, "process_noise: must be one of fixed, imm"),
                         ({"process_noise": "imm", "associator": "jipda"}, 'works with associator = "gnn" only'),
                         ({"maneuver_s": 0.0}, "maneuver_s: must be > 0")):
        with pytest.raises(ConfigError, match=message):
            MttConfig(**bad).validate()
