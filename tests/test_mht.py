"""Track-oriented MHT (issue 25 item 3): Murty's k best assignments against brute force, the
cluster-wise k best extensions, equivalence with gnn at window 1 and k = 1 (test (c)), the
N-scan pruning and branch-cap invariants, and the score terms."""

from __future__ import annotations

import itertools
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.mtt.associators.gnn import k_best_assignments
from fedtrack.local_filters.mtt.associators.mht import (
    best_extensions,
    k_best_sums,
    mht_params,
    score_increments,
    sprt_thresholds,
)
from fedtrack.local_filters.mtt.config import MhtConfig, MttConfig
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.mtt.tracker import initial_state, track_params, tracker_step
from fedtrack.local_filters.pda.association import constants, log_amplitude_ratio
from fedtrack.local_filters.pda.config import PDAParams
from fedtrack.local_filters.radar.measurement import polar_from_cartesian


def brute_force(cost: np.ndarray) -> list[float]:
    """Every finite assignment's cost, ascending."""
    n, m = cost.shape
    totals = (cost[np.arange(n), list(p)].sum() for p in itertools.permutations(range(m), n))
    return sorted(t for t in totals if np.isfinite(t))


def test_k_best_assignments_equal_brute_force() -> None:
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(200):
        n = int(rng.integers(1, 5))
        m = int(rng.integers(n, 7))
        cost = rng.normal(size=(n, m))
        cost[rng.random((n, m)) < 0.3] = np.inf  # forbidden pairs
        k = int(rng.integers(1, 40))
        every = brute_force(cost)
        costs, cols = k_best_assignments(cost, k)
        assert costs.size == min(k, len(every))
        np.testing.assert_allclose(costs, every[:k], rtol=0, atol=1e-12)
        for total, col in zip(costs, cols):  # each one a valid assignment of that cost
            assert len(set(col.tolist())) == n
            assert abs(cost[np.arange(n), col].sum() - total) < 1e-12
        assert len({tuple(c) for c in cols.tolist()}) == costs.size  # no assignment twice
        checked += costs.size
    assert checked > 1000


def test_k_best_assignments_queue_constraints_not_matrices() -> None:
    """Murty's queue keeps each sub-problem as its constraints: the peak memory of a 120 x 240
    problem stays a few copies of its matrix (each queued sub-problem was one: about 120 here)."""
    cost = np.random.default_rng(3).normal(size=(120, 240))
    tracemalloc.start()
    try:
        costs, _ = k_best_assignments(cost, 3)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert costs.size == 3
    assert peak < 8 * cost.nbytes, f"peak {peak / cost.nbytes:.1f} matrices"


def test_k_best_sums_equal_brute_force() -> None:
    rng = np.random.default_rng(2)
    for _ in range(50):
        lists = [np.sort(rng.normal(size=int(rng.integers(1, 5)))) for _ in range(int(rng.integers(1, 5)))]
        k = int(rng.integers(1, 20))
        every = sorted(sum(v) for v in itertools.product(*lists))
        sums, picks = k_best_sums(lists, k)
        np.testing.assert_allclose(sums, every[:k], atol=1e-12)
        np.testing.assert_allclose([sum(lst[i] for lst, i in zip(lists, p)) for p in picks], sums, atol=1e-12)


def test_best_extensions_equal_brute_force() -> None:
    """Rows take one of their pairs or miss (gain 0), each detection at most once: the k best total
    gains over several clusters (one-row ones among them) are the brute force's."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        n_rows, n_det = int(rng.integers(1, 6)), int(rng.integers(1, 7))
        mask = rng.random((n_rows, n_det)) < 0.35
        r, c = np.nonzero(mask)
        gain = rng.normal(size=r.size) * 3
        options = [[-1] + np.flatnonzero(r == i).tolist() for i in range(n_rows)]
        every = []
        for choice in itertools.product(*options):
            taken = [p for p in choice if p >= 0]
            if len({int(c[p]) for p in taken}) == len(taken):
                every.append(sum(gain[p] for p in taken))
        every.sort(reverse=True)
        k = int(rng.integers(1, 15))
        gains, ways = best_extensions(r, c, gain, k)
        np.testing.assert_allclose(gains, every[:k], atol=1e-12)
        for total, way in zip(gains, ways):
            assert len(set(c[way].tolist())) == way.size and len(set(r[way].tolist())) == way.size
            assert abs(gain[way].sum() - total) < 1e-12


def crossing_scans(seed: int, radar: bool = False, steps: int = 40, clutter: float = 20.0
                   ) -> tuple[list[SensorScan], float, list[np.ndarray]]:
    """Six targets converging on a 1 km square (their paths cross), P_D 0.9, uniform clutter
    over a 2 km square (Poisson, ``clutter`` a scan); 1 Hz. Radar: range 10 m, angles 2 mrad,
    clutter uniform in range and azimuth."""
    rng = np.random.default_rng(seed)
    n, side = 6, 2000.0
    start = rng.uniform(-side / 3, side / 3, (n, 2))
    vel = (-start + rng.normal(0, 100, (n, 2))) / steps  # towards the centre: paths cross
    truth, scans = [], []
    sensor = np.array([-8000.0, 500.0, 0.0]) if radar else None
    R = np.diag([100.0, 4e-6, 4e-6]) if radar else 100.0 * np.eye(2)
    for k in range(steps):
        p = start + vel * k
        truth.append(p)
        seen = p[rng.random(n) < 0.9]
        n_false = rng.poisson(clutter)
        if radar:
            pos3 = np.column_stack([seen, np.full(len(seen), 1000.0)])
            z = polar_from_cartesian(pos3 - sensor) + rng.normal(size=(len(seen), 3)) * np.sqrt(np.diag(R))
            false = np.column_stack([rng.uniform(6000, 10000, n_false), rng.uniform(-0.15, 0.15, n_false),
                                     rng.uniform(0.05, 0.2, n_false)])
        else:
            z = seen + rng.normal(0, 10.0, seen.shape)
            false = rng.uniform(-side / 2, side / 2, (n_false, 2))
        z = np.concatenate([z, false])[rng.permutation(len(z) + n_false)]
        scans.append(SensorScan(float(k), "s1", R, z, None, sensor))
    density = clutter / (4000 * 0.3 * 0.15) if radar else clutter / side**2  # per unit of the measurement space
    return scans, density, truth


@pytest.mark.parametrize("motion", ["fixed", "imm"])
@pytest.mark.parametrize("seed,radar", [(0, False), (1, False), (2, False), (3, False), (4, True)])
def test_window_one_k_one_with_gnn_management_is_gnn(seed: int, radar: bool, motion: str) -> None:
    """Issue 25 acceptance (c): with a window of one scan, k = 1 and gnn's track management
    (M-of-N counts, confirmed tracks first), the MHT makes gnn's assignments at every scan and
    its tracks equal gnn's to 1e-9. gnn's cost ``-2 ln(P_D N / lambda (1 - P_D))`` is the MHT's
    pair gain over a miss with a gate that holds every target detection: ``"counts"`` management
    takes P_G = 1 with gnn's rules. With two motion modes per track (``process_noise = "imm"``)
    on both sides, likewise: each branch carries its modes as a gnn track does."""
    scans, density, _ = crossing_scans(seed, radar)
    cfg = MttConfig(clutter_density=density, process_noise=motion)
    dim = 6 if radar else 4
    gnn_params = track_params(cfg, "s1", dim)
    mht_cfg = MttConfig(clutter_density=density, associator="mht", process_noise=motion,
                        mht=MhtConfig(window=1, k=1, max_branches=1, management="counts"))
    params = track_params(mht_cfg, "s1", dim)
    assert mht_params(params.mht, params.pd, params.clutter_density, params.gate[2], 2, 3).pg == 1.0
    gnn, mht = initial_state(dim), initial_state(dim)
    worst, assigned, confirmed = 0.0, 0, 0
    for scan in scans:
        g = tracker_step(gnn, scan, gnn_params)
        h = tracker_step(mht, scan, params)  # mht_step, after the count and deletion rules of the scan
        gnn, mht = g.state, h.state
        a, b = gnn.tracks, mht.tracks
        assert np.array_equal(a.ids, b.ids)
        assert np.array_equal(g.detected, h.detected) and np.array_equal(g.retired, h.retired)
        assert np.array_equal(a.confirmed, b.confirmed) and np.array_equal(a.hits, b.hits)
        assert len(mht.memory.hyps) == 1 and mht.memory.leaves.size == a.size  # one branch per track
        assert (a.modes is None) == (b.modes is None) == (motion == "fixed")
        if b.modes is not None and a.size:  # each track's modes, not only their combination
            worst = max(worst, *(np.abs(u - v).max() for u, v in zip(a.modes, b.modes)))
        # the same detections (in the observations) to the same tracks, the same estimates
        worst = max(worst, np.abs(a.x - b.x).max(initial=0.0), np.abs(a.P - b.P).max(initial=0.0),
                    *(np.abs(u - v).max(initial=0.0) for u, v in zip(g.observations, h.observations)))
        assigned += int((g.detected & (a.age > 1)).sum())
        confirmed += int(a.confirmed.sum())
    assert worst <= 1e-9
    assert assigned > 150 and confirmed > 100  # there were assignments and confirmed tracks to compare


def test_pruning_and_cap_invariants_and_confirmed_targets() -> None:
    """Window 3, k 5, at most 3 branches per track, SPRT management on the crossing scenario with
    clutter: every hypothesis holds at most one leaf per track; the leaves of a track of the best
    hypothesis share its branch two scans back; at most 3 leaves per track; the picture's
    confirmed tracks sit on the targets."""
    scans, density, truth = crossing_scans(7, clutter=30.0)
    cfg = MttConfig(clutter_density=density, associator="mht", mht=MhtConfig(window=3, k=5, max_branches=3))
    params = track_params(cfg, "s1", 4)
    state = initial_state(4)
    several, errors = 0, []
    for scan, p in zip(scans, truth):
        state = tracker_step(state, scan, params).state
        mem = state.memory
        ids = mem.leaves.ids
        for row in mem.hyps:
            assert np.unique(ids[row]).size == row.sum()
        best = np.flatnonzero(mem.hyps[0])
        for leaf in best:
            assert np.all(mem.lineage[ids == ids[leaf], 0] == mem.lineage[leaf, 0])
        assert np.bincount(ids).max(initial=0) <= 3
        several += len(mem.hyps) > 1
        tr = state.tracks
        if scan.t >= 10:
            pos = tr.x[tr.confirmed][:, [0, 2]]
            d = np.linalg.norm(pos[:, None] - p[None], axis=-1)
            errors.append((d.min(axis=1) < 50).mean() if pos.size else 0.0)  # confirmed tracks on a target
            errors.append((d.min(axis=0) < 50).mean() if pos.size else 0.0)  # targets with a confirmed track
    assert several > 20  # the scenario had alternative hypotheses
    assert np.mean(errors) > 0.9


def test_window_auto_from_the_detection_probability() -> None:
    """``window = "auto"`` (the default): ``N = 1 + max(1, ceil(ln 0.01 / ln(1 - P_D)))`` from the
    smallest P_D configured (a sensor's own included); a number is kept; anything else refused."""
    from fedtrack.config import ConfigError
    from fedtrack.local_filters.mtt.config import SensorOverride, auto_window

    assert [auto_window(p) for p in (0.5, 0.8, 0.9, 0.95, 0.99, 1.0)] == [8, 4, 3, 3, 2, 2]
    for pd in (0.5, 0.8, 0.9, 0.95):  # the first N - 1 with (1 - P_D)^(N - 1) <= 0.01
        assert (1 - pd) ** (auto_window(pd) - 1) <= 0.01 + 1e-12 < (1 - pd) ** (auto_window(pd) - 2)
    assert MttConfig(associator="mht").mht_settings.window == 3
    assert MttConfig(associator="mht", sensor={"s2": SensorOverride(pd=0.8)}).mht_settings.window == 4
    assert track_params(MttConfig(associator="mht", pd=0.8), "s1", 4).mht.window == 4
    assert MttConfig(associator="mht", pd=0.8, mht=MhtConfig(window=2)).mht_settings.window == 2
    for bad in ("three", 0):
        with pytest.raises(ConfigError, match="window"):
            MhtConfig(window=bad).validate()


def test_score_terms() -> None:
    """The detection increment is ``ln(P_D N(nu; 0, S) / lambda)`` plus paper 001's amplitude
    log-ratio; the miss ``ln(1 - P_D P_G)``; Wald's thresholds."""
    amp = constants(PDAParams(pd=0.8, clutter_density=1e-5, snr=10.0))
    mp = mht_params(MhtConfig(), 0.8, 1e-5, 9.21, 2, 3)._replace(pg=0.99, amplitude=amp)
    log_n, a = np.array([-9.0, -12.5]), np.array([5.0, 9.0])
    inc, miss = score_increments(log_n, mp, a)
    expect = np.log(0.8) + log_n - np.log(1e-5) + log_amplitude_ratio(a, amp)
    np.testing.assert_allclose(inc, expect, atol=1e-12)
    assert miss == pytest.approx(np.log(1 - 0.8 * 0.99), abs=1e-15)
    hi, lo = sprt_thresholds(1e-4, 1e-2)
    assert hi == pytest.approx(np.log(0.99 / 1e-4)) and lo == pytest.approx(np.log(1e-2 / (1 - 1e-4)))
    with pytest.raises(ValueError):
        sprt_thresholds(0.6, 0.5)


DATA = Path(__file__).parent / "data" / "mtt_reference"
LOCAL_SENSOR = {"pos": "s2", "radar": "r1"}


def replay_pictures(tmp_path: Path, scenario: str, algorithm: str, settings: str) -> list[dict]:
    """``replay`` of a reference scenario (tests/test_mtt_roles.py) with extra ``[mtt]`` settings."""
    cfg = tmp_path / f"{scenario}-{algorithm}-{len(settings)}.toml"
    cfg.write_text((DATA / f"{scenario}.toml").read_text().replace("[mtt]\n", f"[mtt]\n{settings}", 1))
    out = cfg.with_suffix(".jsonl")
    replay_mtt(algorithm, DATA / f"{scenario}-scans.jsonl", cfg, out,
               sensor=LOCAL_SENSOR[scenario] if algorithm == "mtt-local" else None)
    return [json.loads(line) for line in out.read_text().splitlines()]


GNN_MODEL = 'associator = "mht"\nmht = { window = 1, k = 1, management = "counts" }\n'


@pytest.mark.parametrize("scenario,algorithm,motion", [
    *itertools.product(["pos", "radar"], ["mtt-local", "mtt-centralized"], ["fixed"]),
    ("pos", "mtt-centralized", "imm"), ("radar", "mtt-local", "imm")])
def test_tracker_with_mht_window_one_k_one_counts_equals_gnn(tmp_path: Path, scenario: str, algorithm: str,
                                                             motion: str) -> None:
    """Acceptance (c) through the tracker: ``[mtt] associator = "mht"`` with ``[mtt.mht] window = 1,
    k = 1, management = "counts"`` writes gnn's pictures (ids, status, sensors to the letter; x, P
    to 1e-9), for mtt-local and mtt-centralized, position sensors and a radar; with
    ``process_noise = "imm"`` on both, gnn's two-mode pictures."""
    noise = f'process_noise = "{motion}"\n'
    gnn = replay_pictures(tmp_path, scenario, algorithm, noise)
    mht = replay_pictures(tmp_path, scenario, algorithm, noise + GNN_MODEL)
    assert [p["t"] for p in gnn] == [p["t"] for p in mht]
    tracks = 0
    for a, b in zip(gnn, mht):
        assert [t["id"] for t in a["tracks"]] == [t["id"] for t in b["tracks"]]
        for ta, tb in zip(a["tracks"], b["tracks"]):
            assert {k: v for k, v in ta.items() if k not in ("x", "P")} == \
                {k: v for k, v in tb.items() if k not in ("x", "P")}
            np.testing.assert_allclose(tb["x"], ta["x"], rtol=0, atol=1e-9)
            np.testing.assert_allclose(tb["P"], ta["P"], rtol=0, atol=1e-9)
            tracks += 1
    assert tracks > 150


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-centralized"])
def test_tracker_with_mht_defaults_follows_gnns_confirmed_tracks(tmp_path: Path, algorithm: str) -> None:
    """``associator = "mht"`` with its defaults (window 3 at P_D 0.9, k 3, SPRT) runs in the tracker: in the
    second half of the position scenario (few false detections), every confirmed gnn track has a
    confirmed mht track within 30 m and the other way round."""
    gnn = replay_pictures(tmp_path, "pos", algorithm, "")
    mht = replay_pictures(tmp_path, "pos", algorithm, 'associator = "mht"\n')
    matched = 0
    for a, b in list(zip(gnn, mht))[len(gnn) // 2:]:
        pa = np.array([t["pos"][:2] for t in a["tracks"] if t["status"] == "confirmed"]).reshape(-1, 2)
        pb = np.array([t["pos"][:2] for t in b["tracks"] if t["status"] == "confirmed"]).reshape(-1, 2)
        d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
        assert pa.shape == pb.shape and np.all(d.min(axis=1) < 30) and np.all(d.min(axis=0) < 30), a["t"]
        matched += pa.shape[0]
    assert matched > 50


@pytest.mark.parametrize("motion", ["fixed", "imm"])
def test_centralized_mht_out_of_sequence_equals_time_sorted(tmp_path: Path, motion: str) -> None:
    """Acceptance (d) for mht: ``mtt-centralized`` with ``associator = "mht"`` (defaults) on scans
    that arrive out of sequence within ``max_lag`` writes the pictures of the time-sorted scans
    (to 1e-9): the buffer-and-reprocess re-runs the MHT from its memory before the late scan
    (with ``process_noise = "imm"``, from every leaf's modes)."""
    from test_mtt_out_of_sequence import replay, scans

    arrived, in_time = scans(seed=3)
    assert arrived != in_time
    cfg = {"max_lag": 3.0, "picture_delay": 2.5, "pd": 0.95, "clutter_density": 1e-9, "associator": "mht",
           "process_noise": motion}
    got = replay(tmp_path, "arrived", arrived, "mtt-centralized", **cfg)
    want = replay(tmp_path, "sorted", in_time, "mtt-centralized", **cfg)
    assert [p["t"] for p in got] == [p["t"] for p in want]
    tracks = 0
    for a, b in zip(got, want):
        assert [(t["id"], t["status"]) for t in a["tracks"]] == [(t["id"], t["status"]) for t in b["tracks"]]
        for ta, tb in zip(a["tracks"], b["tracks"]):
            np.testing.assert_allclose(ta["x"], tb["x"], rtol=0, atol=1e-9)
            np.testing.assert_allclose(ta["P"], tb["P"], rtol=0, atol=1e-9)
            tracks += ta["status"] == "confirmed"
    assert tracks > 100


def test_scans_without_detections_and_with_amplitudes() -> None:
    """Scans without detections (the tracks miss), detections far from every track (new tracks
    only) and detections with amplitudes (their log-ratio in the score) go through ``mht``; two
    targets 500 m apart end as two tracks whose scores differ by about their detections' amplitude
    log-ratios."""
    params = track_params(MttConfig(associator="mht"), "s1", 4)
    state, R = initial_state(4), 100.0 * np.eye(2)
    amp = [None, None, None, np.array([30.0, 3.0]), np.array([30.0, 3.0]), np.array([30.0, 3.0])]
    zs = [np.zeros((0, 2)), [[0.0, 0.0], [500.0, 0.0]], np.zeros((0, 2)), [[1.0, 1.0], [501.0, 0.0]],
          [[3.0, 2.0], [502.0, 0.0]], [[4.0, 2.0], [503.0, 0.0]]]
    for t, (z, a) in enumerate(zip(zs, amp)):
        res = tracker_step(state, SensorScan(float(t), "s1", R, np.asarray(z, float).reshape(-1, 2), a, None), params)
        state = res.state
        assert res.detected.sum() == len(z) or t < 2
    tr = state.tracks
    assert tr.size == 2
    mem = state.memory
    best = np.flatnonzero(mem.hyps[0])
    score = dict(zip(mem.leaves.ids[best].tolist(), mem.score[best].tolist()))
    near = {int(i): float(x) for i, x in zip(tr.ids, tr.x[:, 0])}
    strong = min(near, key=lambda i: abs(near[i]))  # the track at x = 0 took the high amplitudes
    weak = max(near, key=lambda i: abs(near[i]))
    # amplitude 30 against 3 adds (30 - 3) rho / (1 + rho) per detection, three detections, rho = 20
    assert score[strong] - score[weak] > 3 * 27 * 20 / 21 - 10



def test_an_established_track_keeps_its_detection_against_a_newborn() -> None:
    """The hypothesis value marginalises each track's existence (:func:`value_increments`): of two
    tracks gating one detection, an established one (score 15) takes it from a track born last scan
    (score ``ln odds(B)``, jipda's birth prior) that fits it better by 2 nats; between two
    established tracks the better fit takes it; ``"counts"`` keeps the plain increments."""
    from types import SimpleNamespace

    from fedtrack.local_filters.mtt.associators.mht import MhtState, birth_scores, extend_clusters, value_increments

    mp = mht_params(MhtConfig(), 0.8, 5e-7, 9.21, 2, 3)
    newborn = float(birth_scores(mp, None, 50)[0])
    assert newborn == pytest.approx(np.log(0.1 / 0.9))
    rows, cols, inc = np.array([0, 1]), np.array([0, 0]), np.array([5.0, 7.0])
    miss = float(np.log1p(-mp.pd * mp.pg))
    taker = {}
    for name, scores in (("newborn", [15.0, newborn]), ("established", [15.0, 15.0])):
        leaves = SimpleNamespace(confirmed=np.array([True, False]), ids=np.array([0, 1]))
        state = MhtState(leaves, np.array(scores), np.array(scores), np.zeros((2, 1), np.int64),
                         np.ones((1, 2), bool), np.zeros((1, 1)), 2, np.ones(2), np.zeros(2, np.intp))
        br = extend_clusters(state, 1, rows, cols, inc, miss, mp)
        taker[name] = int(br.parent[br.holds[0] & (br.pair >= 0)][0])
    assert taker == {"newborn": 0, "established": 1}
    counts = mp._replace(management="counts")
    leaf_miss, gain = value_increments(np.array([15.0, newborn]), rows, inc, miss, counts)
    np.testing.assert_allclose(leaf_miss, miss) and np.testing.assert_allclose(gain, inc - miss)


def formation_scans(seed: int, steps: int = 60, clutter: float = 20.0) -> tuple[list[SensorScan], float, list[np.ndarray]]:
    """Three targets side by side 25 m apart (1.7 noise sigmas) flying together at 20 m/s, P_D 0.8,
    uniform clutter over a 2 km square; one sensor at 1 Hz, noise 15 m per axis."""
    rng = np.random.default_rng(seed)
    side, sd = 2000.0, 15.0
    start = np.array([[-600.0, -25.0], [-600.0, 0.0], [-600.0, 25.0]])
    truth, scans = [], []
    for k in range(steps):
        p = start + np.array([20.0, 0.0]) * k
        truth.append(p)
        seen = p[rng.random(3) < 0.8]
        z = np.concatenate([seen + rng.normal(0, sd, seen.shape), rng.uniform(-side / 2, side / 2, (rng.poisson(clutter), 2))])
        scans.append(SensorScan(float(k), "s1", sd**2 * np.eye(2), z[rng.permutation(len(z))], None, None))
    return scans, clutter / side**2, truth


def test_formation_has_no_duplicate_tracks() -> None:
    """The established tracks' precedence (:func:`value_increments`) still lets each member of a
    formation keep its own track: three targets within two noise sigmas, P_D 0.8, mht's defaults
    show no more confirmed tracks near the formation than it has targets in 95 % of the scans and
    a track within 40 m of each target in 90 % (about 1 s)."""
    dup, held, scans_seen = 0, 0, 0
    for seed in range(3):
        scans, density, truth = formation_scans(seed)
        params = track_params(MttConfig(clutter_density=density, associator="mht", pd=0.8), "s1", 4)
        state = initial_state(4)
        for scan, p in zip(scans, truth):
            state = tracker_step(state, scan, params).state
            if scan.t < 15:
                continue
            tr = state.tracks
            pos = tr.x[tr.confirmed][:, [0, 2]]
            d = np.linalg.norm(pos[:, None] - p[None], axis=-1)
            dup += int((d.min(axis=1) < 100).sum() > 3)
            held += int((d.min(axis=0) < 40).sum())
            scans_seen += 1
    assert dup <= 0.05 * scans_seen, (dup, scans_seen)
    assert held >= 0.9 * 3 * scans_seen, (held, scans_seen)


@pytest.mark.parametrize("management", ["score", "counts"])
def test_an_ended_targets_track_leaves_the_picture_by_existence(management: str) -> None:
    """``"score"``: a confirmed track is shown while its existence (IPDA along the branch with
    jipda's survival, :func:`~.mht.leaf_existence`) is at least 1/2. One target seen by a 4 Hz
    sensor for 8 s, then gone; with the centre's deletion after 6 misses the track leaves the
    picture at the miss where the existence recursion, computed here from its value at the last
    detection, first falls below 1/2 (its odds before a scan are at most ``p11 / (1 - p11)``),
    while it is still kept, and is deleted later. ``"counts"`` shows it until it is deleted (gnn)."""
    from fedtrack.local_filters.mtt.associators.jipda import SURVIVAL_PER_SECOND

    cfg = MttConfig(associator="mht", clutter_density=1e-7, delete_misses=6, process_noise="fixed",
                    mht=MhtConfig(management=management))
    params = track_params(cfg, "s1", 4)
    state, R, dt = initial_state(4), 100.0 * np.eye(2), 0.25
    rng = np.random.default_rng(3)
    seen, mu, shown_at, gone_at = 0, None, None, None
    for k in range(80):
        t = k * dt
        z = np.array([[10.0 * t, 5.0 * t]]) + rng.normal(0.0, 10.0, (1, 2)) if t < 8 else np.zeros((0, 2))
        state = tracker_step(state, SensorScan(t, "s1", R, z, None, None), params).state
        tr, mem = state.tracks, state.memory
        if t < 8:
            seen += int(tr.confirmed.sum() == 1)
            best = np.flatnonzero(mem.hyps[0])
            mu = float(mem.existence[best[np.argmax(mem.leaves.confirmed[best])]])
            continue
        if tr.size == 0:
            gone_at = gone_at if gone_at is not None else k
            continue
        # one miss of the branch: survival over dt, then the miss's likelihood ratio 1 - P_D P_G
        mp = mht_params(cfg.mht, params.pd, params.clutter_density, params.gate[2], 2, 6)
        miss = 1.0 - params.pd * mp.pg
        mu_bar = SURVIVAL_PER_SECOND**dt * mu
        mu = mu_bar * miss / (1.0 - mu_bar + mu_bar * miss)
        if management == "score":
            assert bool(tr.confirmed[0]) == (mu >= 0.5), (k, mu)
        else:
            assert tr.confirmed[0]
        if not tr.confirmed[0] and shown_at is None:
            shown_at = k
    assert seen >= 25  # confirmed within a few scans of the first detection
    assert gone_at is not None  # deleted after 6 misses in a row
    if management == "score":
        assert shown_at is not None and shown_at < gone_at, (shown_at, gone_at)
    else:
        assert shown_at is None


def test_the_delayed_picture_is_the_n_scan_back_decision() -> None:
    """With ``picture_delay`` past the window, mht's picture at ``T`` is the decision of the best
    hypothesis ``window - 1`` scans later (:func:`~fedtrack.local_filters.mtt.tracker.mht_decided`):
    each of its tracks as its ancestor at ``T`` was. The formation (three targets within two noise
    sigmas, P_D 0.8, clutter; ``mtt-local``, 1 Hz, pictures at the scan times), six seeds:

    * ``picture_delay = 0``: the replay's pictures are those of the tracker's state at ``T``, bit
      for bit (nothing changes);
    * deferred: every track is one of its own leaves at ``T`` (``x``, ``P`` to the bit: the
      filtered estimate along the kept branch, no later data in it), a track born after ``T`` is
      not there, a third of the pictures or more differ from the state at ``T``, and the mean
      GOSPA of the confirmed tracks is lower than the state at ``T``'s by more than 3 standard
      errors of the seeds' differences (the window's deletions and confirmations reach the
      picture). About 1 s."""
    from fedtrack.fusion_center.mtt.engines import LocalEngine, PictureTracks, tracker_picture
    from fedtrack.fusion_center.mtt.evaluation import set_distance
    from fedtrack.fusion_center.mtt.replay import pictures

    def gospa(picture: PictureTracks, truth: np.ndarray) -> float:
        shown = np.array(picture.confirmed, bool)
        return set_distance(truth, picture.x[shown][:, [0, 2]] if shown.size else np.zeros((0, 2)), 100.0, 2.0).gospa

    gain, differ = [], 0
    for seed in range(6):
        scans, density, truth = formation_scans(seed, steps=40)
        cfg = MttConfig(clutter_density=density, associator="mht", pd=0.8, max_lag=100.0)
        engine = LocalEngine(cfg, 4, sensor="s1")
        at_t = []  # the pictures of the state at T (the rule without the deferral)
        for T, now in pictures(engine, scans, 1.0, 0.0):
            want = tracker_picture(engine.history.state_at(T), T, cfg, ["s1"])
            assert now.ids == want.ids and now.confirmed == want.confirmed
            assert np.array_equal(now.x, want.x) and np.array_equal(now.P, want.P)
            at_t.append(want)
        errors = []
        for k, (p, old) in enumerate(zip(truth[:-2], at_t)):  # window 3: two scans after T
            new, leaves = engine.picture(float(k)), engine.history.state_at(float(k)).memory.leaves
            assert engine.history.state_after(float(k), 2)[1] == 2
            for i, x, P in zip(new.ids, new.x, new.P):
                mine = leaves.ids == i
                assert any(np.array_equal(x, a) and np.array_equal(P, b) for a, b in zip(leaves.x[mine], leaves.P[mine]))
            differ += not (new.ids == old.ids and new.confirmed == old.confirmed and np.array_equal(new.x, old.x))
            errors.append(gospa(new, p) - gospa(old, p))
        gain.append(np.mean(errors))
    assert differ >= 6 * 38 / 3, differ
    se = np.std(gain, ddof=1) / np.sqrt(len(gain))
    assert np.mean(gain) < -3 * se, (gain, se)


def test_live_centre_publishes_the_deferred_pictures_of_the_replay(tmp_path: Path) -> None:
    """``serve mtt-centre`` with ``mtt-centralized`` and ``associator = "mht"``, driven in-process
    through its own dispatch (the path of a Zenoh sample), on the formation with clutter, every
    fifth scan arriving behind the next one: it publishes the pictures ``replay`` writes from the
    scans in that order with the same ``picture_delay`` (ids, status, ``x`` to 1e-9: the same
    engine, the deferred decision included); on the time-sorted scans the delayed pictures are not
    those without the delay (the deferral is on). About 1 s."""
    from test_mtt_out_of_sequence import replay

    from fedtrack.fusion_center.mtt.service import MttCentreService
    from fedtrack.keys import Keys
    from fedtrack.local_filters.mtt.scan import scan_to_measurement
    from fedtrack.wire import TrackPicture, encode
    from fedtrack.zsession import SessionOptions

    scans, density, _ = formation_scans(1, steps=30)
    for k in range(4, len(scans) - 1, 5):  # out of sequence: scan k arrives after scan k + 1
        scans[k], scans[k + 1] = scans[k + 1], scans[k]
    rows = [{"t": s.t, "sensor": s.sensor, "R": s.R.tolist(), "detections": [{"z": z.tolist()} for z in s.z]}
            for s in scans]
    mtt = {"max_lag": 3.0, "picture_delay": 2.5, "pd": 0.8, "clutter_density": density, "associator": "mht"}
    keys, published = Keys("mhtlive"), []
    centre = MttCentreService("mtt-centralized", MttConfig(**mtt), 4, service_id="centre",
                              options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="mhtlive")
    centre._subscriptions = centre.subscriptions()
    centre.publish = lambda key, msg: published.append(msg)  # type: ignore[method-assign]
    for seq, scan in enumerate(scans):
        centre._dispatch(("sample", 0, keys.sensor_meas(scan.sensor), encode(scan_to_measurement(scan, seq, 1))))
    centre.on_stop()
    live = [m for m in published if isinstance(m, TrackPicture) and not m.closing]
    want = replay(tmp_path, "arrived", rows, "mtt-centralized", **mtt)
    assert [p.t for p in live] == [p["t"] for p in want] and len(live) >= 25
    for got, w in zip(live, want):
        assert list(got.ids) == [tr["id"] for tr in w["tracks"]]
        assert list(got.confirmed) == [tr["status"] == "confirmed" for tr in w["tracks"]]
        want_x = np.array([tr["x"] for tr in w["tracks"]]).reshape(-1, 4)
        np.testing.assert_allclose(np.asarray(got.x).reshape(-1, 4), want_x, rtol=1e-12, atol=1e-9)
    assert sum(len(p["tracks"]) for p in want) > 25
    # the deferral is on: on the time-sorted scans the delay alone would change nothing
    in_time = sorted(rows, key=lambda r: r["t"])
    delayed = replay(tmp_path, "sorted", in_time, "mtt-centralized", **mtt)
    undelayed = replay(tmp_path, "now", in_time, "mtt-centralized", **{**mtt, "picture_delay": 0.0})
    assert [[tr["id"] for tr in p["tracks"]] for p in delayed] != [[tr["id"] for tr in p["tracks"]] for p in undelayed]


def test_independent_scenes_keep_their_own_hypotheses() -> None:
    """Hypotheses per cluster (:func:`~fedtrack.local_filters.mtt.associators.mht.extend_clusters`):
    two formation scenes in clutter 100 km apart (no gate holds a detection of the other) tracked
    together give each scene's tracks exactly as tracked alone (x and P of every track, tentative
    ones too, at every scan, to 1e-9): each cluster of interacting tracks keeps its own k best
    hypotheses, not the other scene's. Global hypotheses, k of the whole scene, fail this: the
    other scene's alternatives crowd a scene's out (about 1 s)."""
    (a, density, _), (b, _, _) = formation_scans(0), formation_scans(1)
    far = np.array([1e5, 0.0])
    both = [sa._replace(z=np.concatenate([sa.z, sb.z + far])) for sa, sb in zip(a, b)]
    params = track_params(MttConfig(clutter_density=density, associator="mht", pd=0.8), "s1", 4)

    def run(scans: list[SensorScan]) -> list[np.ndarray]:
        state, out = initial_state(4), []
        for scan in scans:
            state = tracker_step(state, scan, params).state
            tr = state.tracks
            flat = np.concatenate([tr.x, tr.P.reshape(tr.size, -1)], axis=1)
            out.append(flat[np.lexsort(flat[:, ::-1].T)])
        return out

    alone_a, alone_b, together = run(a), run(b), run(both)
    worst, several = 0.0, 0
    for xa, xb, xt in zip(alone_a, alone_b, together):
        shifted = xb.copy()
        shifted[:, 0] += far[0]
        expect = np.concatenate([xa, shifted])
        assert xt.shape == expect.shape
        worst = max(worst, np.abs(xt - expect[np.lexsort(expect[:, ::-1].T)]).max(initial=0.0))
        several += xa.shape[0] > 3
    assert worst <= 1e-9 * 1e5  # positions near 1e5 m: 1e-9 relative
    assert several > 10  # the scenes had tentative tracks besides the formation's


@pytest.mark.parametrize("associator", ["gnn", "mht"])
def test_a_local_report_retires_every_track_it_no_longer_holds(associator: str) -> None:
    """A local tracker's reports (to a track-to-track centre): a track of one report that the next
    does not hold is in the next one's ``retired``. With mht that includes a track that only left
    the best hypothesis (it may come back): the centre then unmaps it instead of keeping a local
    track it no longer hears of on its central track, which a new local track of the same target
    then duplicated (decentralized default scenario: 86.2 -> 55.1 m mean GOSPA)."""
    from fedtrack.local_filters.mtt.local import local_step, new_local_tracker

    scans, density, _ = formation_scans(2, steps=40)
    cfg = MttConfig(associator=associator, clutter_density=density, pd=0.8)
    tracker, before, left_alive = new_local_tracker(scans[0]), np.zeros(0, np.int64), 0
    for scan in scans:
        tracker, report = local_step(tracker, scan, cfg)
        gone = np.setdiff1d(before, report.ids)
        assert np.isin(gone, report.retired).all()
        if associator == "mht":  # left the best hypothesis, still a track of the tracker's memory
            left_alive += int(np.isin(gone, tracker.state.memory.leaves.ids).sum())
        before = report.ids
    assert left_alive > 0 or associator == "gnn"
