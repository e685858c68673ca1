"""The centre's array store of central tracks: out-of-sequence fusion equals time-sorted fusion."""

from __future__ import annotations

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.central_track import CentralTracks
from fedtrack.local_filters.linear.kalman import GaussianState, update
from fedtrack.local_filters.mtt.models import position_matrix, predict_batch

Q = 0.5


def sorted_kf(x0: np.ndarray, P0: np.ndarray, t0: float, obs: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]
              ) -> tuple[np.ndarray, np.ndarray]:
    """A plain Kalman filter over the observations in time order."""
    x, P, t = x0[None], P0[None], t0
    for ti, H, R, z in sorted(obs, key=lambda o: o[0]):
        x, P = predict_batch(x, P, np.array([ti - t]), Q)
        x, P = update(GaussianState(x, P), z[None], H[None], R[None])[0]
        t = ti
    return x[0], P[0]


def test_out_of_sequence_fusion_equals_time_sorted_fusion_across_ring_growth() -> None:
    """Several tracks, observations of sizes 2 and 3 arriving shuffled (within ``max_lag``): every
    track's state equals a KF over its time-sorted observations; the ring wraps and grows (more
    observations than its first depth) and the table grows (more tracks than its capacity)."""
    rng = np.random.default_rng(5)
    dim, n_tracks, n_obs = 6, 5, 30
    store = CentralTracks(dim, Q, "continuous", max_lag=1e9, capacity=2, depth=4)
    x0 = rng.normal(size=(n_tracks, dim)) * 10.0
    P0 = np.broadcast_to(np.eye(dim) * 100.0, (n_tracks, dim, dim))
    for cid in range(n_tracks):
        store.start(cid, 0.0, x0[cid], P0[cid])
    observations: list[list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in range(n_tracks)]
    times = np.round(rng.uniform(0.1, 20.0, size=n_obs), 3)
    for t in times.tolist():  # arrival order: random, so most arrive out of sequence
        m = int(rng.integers(2, 4))
        H = position_matrix(dim, m)
        R = np.eye(m) * float(rng.uniform(1.0, 9.0))
        z = rng.normal(size=(n_tracks, m)) * 20.0
        cids = rng.permutation(n_tracks)[: int(rng.integers(1, n_tracks + 1))]
        ok, x_at, P_at = store.fuse(store.slots_of(cids.tolist()), t, np.repeat(H[None], cids.size, 0),
                                    np.repeat(R[None], cids.size, 0), z[cids])
        assert ok.all()
        for i, c in enumerate(cids.tolist()):
            observations[c].append((t, H, R, z[c]))
            # the posterior at t: the observations up to t (arrival order among equal times)
            x_ref, P_ref = sorted_kf(x0[c], P0[c], 0.0, [o for o in observations[c] if o[0] <= t])
            np.testing.assert_allclose(x_at[i], x_ref, rtol=0, atol=1e-9 * max(1.0, np.abs(x_ref).max()))
            np.testing.assert_allclose(P_at[i], P_ref, rtol=0, atol=1e-9 * np.abs(P_ref).max())
    assert store.depth > 4 and store.capacity > 2
    slots = store.slots_of(list(range(n_tracks)))
    _, x, P = store.latest(slots)
    for c in range(n_tracks):
        x_ref, P_ref = sorted_kf(x0[c], P0[c], 0.0, observations[c])
        np.testing.assert_allclose(x[c], x_ref, rtol=0, atol=1e-9 * max(1.0, np.abs(x_ref).max()))
        np.testing.assert_allclose(P[c], P_ref, rtol=0, atol=1e-9 * np.abs(P_ref).max())


def test_observations_older_than_max_lag_or_the_checkpoint_are_late() -> None:
    store = CentralTracks(4, Q, "continuous", max_lag=2.0)
    store.start(7, 10.0, np.zeros(4), np.eye(4))
    H, R = position_matrix(4)[None], np.eye(2)[None]
    slots = store.slots_of([7])
    assert not store.fuse(slots, 9.0, H, R, np.zeros((1, 2)))[0][0]  # before the starting state
    assert store.fuse(slots, 14.0, H, R, np.zeros((1, 2)))[0][0]
    assert not store.fuse(slots, 11.5, H, R, np.zeros((1, 2)))[0][0]  # 2.5 s older than the newest
    assert store.fuse(slots, 12.5, H, R, np.zeros((1, 2)))[0][0]
    assert list(store) == [7] and 7 in store and len(store) == 1
    store.delete(7)
    assert list(store) == [] and 7 not in store


def test_a_track_keeps_at_most_max_entries() -> None:
    """Observations that all stay within max_lag (one repeated time stamp) fold the oldest into
    the checkpoint beyond MAX_ENTRIES: the ring stops growing, and the state still equals the KF
    over every observation (folding loses nothing for in-order data)."""
    from fedtrack.fusion_center.mtt.central_track import MAX_ENTRIES

    store = CentralTracks(4, Q, "continuous", max_lag=5.0)
    x0, P0 = np.zeros(4), np.eye(4) * 100.0
    store.start(1, 0.0, x0, P0)
    slots = store.slots_of([1])
    H, R = position_matrix(4), np.eye(2)
    obs = []
    for k in range(MAX_ENTRIES + 40):
        z = np.array([0.01 * k, -0.02 * k])
        assert store.fuse(slots, 1.0, H[None], R[None], z[None])[0][0]
        obs.append((1.0, H, R, z))
    assert store.count[slots[0]] == MAX_ENTRIES and store.depth == MAX_ENTRIES
    x_ref, P_ref = sorted_kf(x0, P0, 0.0, obs)
    _, x, P = store.latest(slots)
    np.testing.assert_allclose(x[0], x_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(P[0], P_ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["plain", "prior", "detector", "modes", "sizes"])
def test_a_batch_of_in_order_and_out_of_sequence_observations_fuses_each_as_alone(kind: str) -> None:
    """A batch of observations after their tracks' newest entries and before them (inserted, the later
    entries fused again), as one out-of-sequence report brings: the track table, the posteriors and
    the count of re-fused observations equal fusing each observation alone, to the bit (with the
    report's prediction as ``prior``, the maneuver detector, two motion modes, 3-D tracks whose kept
    observations are of sizes 2 and 3: steps of the re-fusion with both sizes): the batched steps
    (the in-order one step, the re-fusion's ranked steps) treat each track as alone."""
    import copy
    import pickle

    from fedtrack.local_filters.mtt.models import ModeRates
    from fedtrack.local_filters.vdie.estimation import VdieParams

    rng = np.random.default_rng(11)
    n_tracks, dim = 9, 6 if kind == "sizes" else 4
    store = CentralTracks(dim, Q, "continuous", max_lag=3.0, depth=2,
                          detector=VdieParams(window=6) if kind == "detector" else None,
                          modes=ModeRates(1.0 / 60.0, 1.0 / 15.0) if kind == "modes" else None)
    for c in range(n_tracks):
        store.start(c, 0.0, rng.normal(size=dim) * 10.0, np.eye(dim) * 30.0)
    slots = store.slots_of(list(range(n_tracks)))
    H, R = np.repeat(position_matrix(dim)[None], n_tracks, 0), np.repeat(np.eye(2)[None] * 4.0, n_tracks, 0)
    for t in np.round(np.cumsum(rng.uniform(0.2, 0.5, size=8)), 3).tolist():
        some = rng.random(n_tracks) < 0.7  # each track its own history
        some[0] &= kind != "sizes" or t < 1.2  # (3-D: track 0's ends early, the others' go on)
        m = 3 if kind == "sizes" and rng.random() < 0.5 else 2  # a 3-D position or a 2-D one
        assert store.fuse(slots[some], t, np.repeat(position_matrix(dim, m)[None], int(some.sum()), 0),
                          np.repeat(np.eye(m)[None] * 4.0, int(some.sum()), 0),
                          rng.normal(size=(int(some.sum()), m)) * 5.0)[0].all()
    newest = store.newest_t(slots)
    # after some tracks' newest entries, before the others' (3-D: before several of both sizes)
    t = float(newest.min()) + 0.01 if kind == "sizes" else float(newest.max()) - 0.05
    assert (newest <= t).any() and (newest > t).any()
    z = rng.normal(size=(n_tracks, 2)) * 5.0
    alone = copy.deepcopy(store)
    prior = store.states_at(slots, t) if kind == "prior" else None
    ok, x, P = store.fuse(slots, t, H, R, z, prior)
    for i in range(n_tracks):
        one = slice(i, i + 1)
        ok_i, x_i, P_i = alone.fuse(slots[one], t, H[one], R[one], z[one],
                                    None if prior is None else (prior[0][one], prior[1][one]))
        assert ok_i[0] == ok[i] and np.array_equal(x_i[0], x[i]) and np.array_equal(P_i[0], P[i])
    assert ok.all() and store.reprocessed == alone.reprocessed > 0
    assert pickle.dumps(store) == pickle.dumps(alone)
