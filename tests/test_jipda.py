"""JIPDA with amplitude and existence (local_filters/mtt/associators/jipda.py): exactness against the Kalman
filter and the single-target IPDA-AI, exact enumeration against brute force, the LM-IPDA
approximation's error, the equivalent observation, and existence-based track management."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.special import chdtri
from support import assert_same_pictures

from fedtrack.config import ConfigError
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.linear.kalman import (
    LOG_2PI,
    GaussianState,
    innovation_covariance,
    mat_vec,
    predict,
    update_residual,
)
from fedtrack.local_filters.mtt.association import AssociationInput
from fedtrack.local_filters.mtt.associators import events, jipda
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.models import Linearized, linearize, motion
from fedtrack.local_filters.mtt.roles.gating import gate as chi2_gate
from fedtrack.local_filters.pda.association import (
    PDAParams,
    constants,
    existence_predict,
    existence_update,
    gate,
    log_amplitude_ratio,
    pda_ai_hypothesise,
    pda_update,
    singer_model,
)


def position_lin(x: np.ndarray, H: np.ndarray) -> Linearized:
    return Linearized(mat_vec(H, x), np.broadcast_to(H, (x.shape[0],) + H.shape), ())


def gated(pred: GaussianState, z: np.ndarray, lin: Linearized, R: np.ndarray, c) -> jipda.Pairs:
    """The tracker's chi-square gate at ``c.gamma`` and each pair's ``ln N(nu; 0, S)``."""
    g, logdet = chi2_gate(z, lin, innovation_covariance(pred.P, lin.H, R), c.gamma)
    return jipda.Pairs(g.rows, g.cols, g.nu, g.d2, -0.5 * (g.d2 + logdet[g.rows] + R.shape[0] * LOG_2PI))


def run_scan(pred: GaussianState, mu_bar: np.ndarray, z: np.ndarray, amp, lin: Linearized, R: np.ndarray, c,
             max_events: int = jipda.MAX_EVENTS):
    pairs = gated(pred, z, lin, R, c)
    log_a = np.zeros(len(z)) if amp is None else log_amplitude_ratio(amp, c)
    assoc = jipda.associate(len(z), pairs, log_a, mu_bar, c, max_events)
    return jipda.update(pred, lin, R, pairs, assoc, c), assoc, pairs


def test_one_target_pd1_no_clutter_equals_kalman() -> None:
    rng = np.random.default_rng(1)
    R = np.array([[100.0, 20.0], [20.0, 64.0]])
    c = jipda.jipda_constants(1.0, 0.0, float(chdtri(2, 1e-9)), 2)
    mot = motion(4, 1.0, 1.0)
    truth = np.array([0.0, 30.0, 0.0, -10.0])
    x, P = np.array([[5.0, 0.0, -5.0, 0.0]]), np.diag([100.0, 900.0, 100.0, 900.0])[None]
    kf = GaussianState(x[0].copy(), P[0].copy())
    mu = np.array([0.5])
    mus = []
    for _ in range(30):
        truth = mot.F @ truth + rng.multivariate_normal(np.zeros(4), mot.Q)
        z = (truth[[0, 2]] + rng.multivariate_normal(np.zeros(2), R))[None]
        x, P = predict(GaussianState(x, P), mot.F, mot.Q)
        kf = predict(kf, mot.F, mot.Q)
        mu_bar = existence_predict(mu, jipda.survival(1.0, 1.0, 0.98), 0.0)
        post, assoc, _ = run_scan(GaussianState(x, P), mu_bar, z, None, linearize(x, None), R, c)
        kf = update_residual(kf, z[0] - kf.x[[0, 2]], linearize(kf.x[None], None).H[0], R).state
        x, P, mu = post.x, post.P, assoc.existence
        mus.append(mu[0])
        np.testing.assert_allclose(x[0], kf.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(P[0], kf.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(P[0], P[0].T)
    assert assoc.beta0[0] < 1e-300 and assoc.beta[0] == 1.0
    assert np.all(np.diff(mus) >= -1e-15) and mus[-1] > 1.0 - 1e-12


def test_separated_targets_equal_single_target_ipda_ai() -> None:
    """Targets 50 km apart in clutter with amplitudes: JIPDA equals IPDA-AI run per target."""
    rng = np.random.default_rng(2)
    params = PDAParams(pd=0.8, clutter_density=2e-5, snr=10.0, gate=9.21, sigma_a=0.05, tau_s=100.0)
    c = constants(params)
    T = 5.0
    model = singer_model(T, params.sigma_a, params.tau_s)
    H, R = model.H, 225.0 * np.eye(2)
    p11, p21 = 0.98, 0.0
    n = 4
    truth = np.zeros((n, 6))
    truth[:, 0], truth[:, 3] = 50_000.0 * np.arange(n), 1000.0
    truth[:, 1], truth[:, 4] = 8.0, -5.0
    P0 = np.diag([225.0, 25.0, 0.05**2, 225.0, 25.0, 0.05**2])
    joint = GaussianState(truth + rng.normal(size=(n, 6)) * np.sqrt(np.diag(P0)), np.broadcast_to(P0, (n, 6, 6)).copy())
    single = [GaussianState(joint.x[i].copy(), joint.P[i].copy()) for i in range(n)]
    mu = np.full(n, 0.3)
    mu_single = mu.copy()
    missed = 0
    for _ in range(25):
        truth = truth @ model.F.T
        dets, amps = [], []
        for i in range(n):
            if rng.random() < params.pd:
                dets.append(truth[i, [0, 3]] + rng.normal(size=2) * 15.0)
                amps.append(c.tau + rng.exponential(1.0 + params.snr))
            else:
                missed += 1
            k = rng.poisson(params.clutter_density * 800.0**2)
            dets += list(truth[i, [0, 3]] + rng.uniform(-400.0, 400.0, size=(k, 2)))
            amps += list(c.tau + rng.exponential(1.0, size=k))
        z, amp = np.array(dets), np.array(amps)
        pred = predict(joint, model.F, model.Q)
        joint, assoc, pairs = run_scan(pred, existence_predict(mu, p11, p21), z, amp, position_lin(pred.x, H), R, c)
        assert np.bincount(pairs.cols).max() == 1  # no detection in two gates
        mu = assoc.existence
        for i in range(n):  # paper 001's IPDA-AI on the full scan
            p = predict(single[i], model.F, model.Q)
            g = gate(p, z, np.ones(len(z), dtype=bool), H, R, c)
            hyp = pda_ai_hypothesise(g, log_amplitude_ratio(amp, c), c)
            single[i] = pda_update(p, g, hyp, c)
            mu_single[i] = existence_update(mu_single[i], hyp.log_lr, p11, p21)
        np.testing.assert_allclose(joint.x, np.array([s.x for s in single]), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(joint.P, np.array([s.P for s in single]), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(mu, mu_single, rtol=1e-9, atol=1e-12)
    assert missed > 0 and np.all(mu > 0.9)


def brute_force(n: int, n_det: int, gated: np.ndarray, log_target: np.ndarray, mu_bar: np.ndarray,
                pd: float, pg: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Existence and P(i made j | exists) over every joint hypothesis, each track being absent,
    present and undetected in its gate, or present and the origin of one gated detection."""
    options = [["absent", "missed"] + [j for j in range(n_det) if gated[i, j]] for i in range(n)]
    exist, took, total = np.zeros(n), np.zeros((n, n_det)), 0.0
    for hyp in itertools.product(*options):
        taken = [h for h in hyp if not isinstance(h, str)]
        if len(taken) != len(set(taken)):
            continue
        w = 1.0
        for i, h in enumerate(hyp):
            w *= (1.0 - mu_bar[i] if h == "absent" else mu_bar[i] * (1.0 - pd * pg) if h == "missed"
                  else mu_bar[i] * np.exp(log_target[i, h]) / lam)
        total += w
        for i, h in enumerate(hyp):
            if h != "absent":
                exist[i] += w
            if not isinstance(h, str):
                took[i, h] += w
    return exist / total, took / exist[:, None]


def random_cluster(rng: np.random.Generator, n: int, n_det: int, density: float = 0.7):
    gated = rng.random((n, n_det)) < density
    gated[np.arange(n), rng.integers(0, n_det, n)] = True
    rows, cols = np.nonzero(gated)
    log_n = rng.normal(-9.0, 1.5, size=rows.size)
    pairs = jipda.Pairs(rows, cols, np.zeros((rows.size, 2)), np.zeros(rows.size), log_n)
    return gated, pairs, rng.uniform(0.05, 0.99, n), rng.normal(0.0, 1.0, n_det)


def test_exact_enumeration_equals_brute_force() -> None:
    rng = np.random.default_rng(3)
    c = constants(PDAParams(pd=0.85, clutter_density=1e-4, snr=5.0))
    checked = 0
    for _ in range(40):
        n, n_det = int(rng.integers(1, 5)), int(rng.integers(1, 6))
        gated, pairs, mu_bar, log_a = random_cluster(rng, n, n_det)
        out = jipda.associate(n_det, pairs, log_a, mu_bar, c)
        assert np.all(out.exact)
        log_target = np.full((n, n_det), -np.inf)
        log_target[pairs.rows, pairs.cols] = np.log(c.pd) + pairs.log_n + log_a[pairs.cols]
        mu, beta = brute_force(n, n_det, gated, log_target, mu_bar, c.pd, c.pg, c.lam)
        np.testing.assert_allclose(out.existence, mu, rtol=1e-10)
        np.testing.assert_allclose(out.beta, beta[pairs.rows, pairs.cols], rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(out.beta0 + np.bincount(pairs.rows, out.beta, minlength=n), 1.0, rtol=1e-12)
        checked += n > 1
    assert checked > 20


def test_a_certain_tracks_existence_stays_a_probability() -> None:
    """Tracks of predicted existence 1 (or within a rounding of it): the posterior existence stays
    in [0, 1] (the marginals' sum exceeded 1 by 2e-16 and made the next scan's existence NaN), and
    a second scan at the same time (a survival of 1) on it is finite, exact or by LM-IPDA."""
    rng = np.random.default_rng(5)
    c = constants(PDAParams(pd=0.9, clutter_density=1e-6, snr=5.0))
    for trial in range(200):
        n, n_det = int(rng.integers(1, 6)), int(rng.integers(1, 7))
        gated, pairs, _, log_a = random_cluster(rng, n, n_det)
        mu_bar = np.where(rng.random(n) < 0.5, 1.0, 1.0 - 10.0 ** rng.uniform(-17.0, -8.0, n))
        max_events = 1 if trial % 2 else jipda.MAX_EVENTS  # LM-IPDA or exact
        out = jipda.associate(n_det, pairs, log_a, mu_bar, c, max_events=max_events)
        assert np.all((out.existence >= 0.0) & (out.existence <= 1.0)), out.existence
        again = jipda.associate(n_det, pairs, log_a, out.existence, c, max_events=max_events)
        assert np.all(np.isfinite(again.existence)) and np.all(np.isfinite(again.beta))


def test_event_table_counts_every_partial_matching() -> None:
    for a, b in [(1, 4), (2, 3), (3, 3), (4, 2), (3, 6)]:
        table = events.joint_events(a, b)
        assert table.shape == (events.event_count(a, b), a)
        assert len({tuple(r) for r in table.tolist()}) == table.shape[0]
        for r in table:
            used = r[r < b]
            assert used.size == np.unique(used).size


def test_k_best_with_every_event_is_exact() -> None:
    """Murty's k best events, with k the number of events, are all of them: the exact marginals."""
    rng = np.random.default_rng(8)
    c = constants(PDAParams(pd=0.9, clutter_density=1e-5, snr=0.0))
    for n, n_det in [(2, 3), (3, 3), (4, 3), (3, 5)]:
        _, pairs, mu_bar, log_a = random_cluster(rng, n, n_det, density=0.8)
        exact = jipda.associate(n_det, pairs, log_a, mu_bar, c, max_events=10**9)
        kbest = jipda.associate(n_det, pairs, log_a, mu_bar, c, max_events=0, k_best=events.event_count(n, n_det))
        np.testing.assert_allclose(kbest.existence, exact.existence, rtol=1e-12)
        np.testing.assert_allclose(kbest.beta, exact.beta, rtol=1e-10, atol=1e-14)


def approximation_error(rng: np.random.Generator, n: int, n_det: int, runs: int) -> tuple[float, float]:
    """Mean over random clusters of the largest error in existence, with the default approximation."""
    c = constants(PDAParams(pd=0.9, clutter_density=1e-5, snr=0.0))
    err_mu, err_beta = [], []
    for _ in range(runs):
        _, pairs, mu_bar, _ = random_cluster(rng, n, n_det, density=0.8)
        zero = np.zeros(n_det)
        exact = jipda.associate(n_det, pairs, zero, mu_bar, c, max_events=10**9)
        approx = jipda.associate(n_det, pairs, zero, mu_bar, c, max_events=0)
        assert np.all(exact.exact) and not np.all(approx.exact)
        err_mu.append(np.max(np.abs(exact.existence - approx.existence)))
        err_beta.append(np.max(np.abs(exact.beta - approx.beta)))
    return float(np.mean(err_mu)), float(np.mean(err_beta))


def test_top_events_are_murtys_k_best(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bounded search finds the same k most likely events, in the same order, as Murty's
    partitioning, and the cluster marginals agree to round-off, with and without the fallback;
    the clusters searched as one padded batch give each cluster's events and marginals alone, bit
    for bit."""
    from fedtrack.local_filters.mtt.associators.gnn import k_best_assignments

    rng = np.random.default_rng(11)
    clusters = []
    for _ in range(40):
        a, b = int(rng.integers(2, 11)), int(rng.integers(2, 13))
        log_pair = np.where(rng.random((a, b)) < 0.5, rng.normal(0.0, 3.0, (a, b)), -np.inf)
        log_miss = np.log(rng.uniform(0.05, 0.9, a))
        cost = np.full((a, b + a), np.inf)
        cost[:, :b] = -log_pair
        cost[np.arange(a), b + np.arange(a)] = -log_miss
        totals, murty_events = k_best_assignments(cost, 50)
        found = events.top_events(log_pair[None], log_miss[None], 50)
        assert not found.overflow[0] and np.all(found.cluster == 0)
        np.testing.assert_array_equal(found.event, np.minimum(murty_events, b))
        np.testing.assert_allclose(found.score, -totals, rtol=0, atol=1e-9)
        searched = events.k_best_clusters(log_pair[None], log_miss[None], 50)[0]
        with monkeypatch.context() as m:
            m.setattr(events, "FRONTIER_MAX", 0)  # every cluster to Murty
            murty = events.k_best_clusters(log_pair[None], log_miss[None], 50)[0]
        np.testing.assert_allclose(searched, murty, rtol=0, atol=1e-12)
        assert np.allclose(searched.sum(axis=1), 1.0)
        clusters.append((log_pair, log_miss, found, searched))
    # beyond 64 detections the used detections are Python integers, not 64-bit masks
    log_pair = np.where(rng.random((4, 70)) < 0.1, rng.normal(0.0, 3.0, (4, 70)), -np.inf)
    log_miss = np.log(rng.uniform(0.05, 0.9, 4))
    cost = np.full((4, 74), np.inf)
    cost[:, :70] = -log_pair
    cost[np.arange(4), 70 + np.arange(4)] = -log_miss
    totals, murty_events = k_best_assignments(cost, 50)
    found = events.top_events(log_pair[None], log_miss[None], 50)
    np.testing.assert_array_equal(found.event, np.minimum(murty_events, 70))
    np.testing.assert_allclose(found.score, -totals, rtol=0, atol=1e-9)
    a = max(lp.shape[0] for lp, *_ in clusters)
    b = max(lp.shape[1] for lp, *_ in clusters)
    batch, miss = np.full((len(clusters), a, b), -np.inf), np.zeros((len(clusters), a))  # padded
    for i, (lp, lm, *_) in enumerate(clusters):
        batch[i, :lp.shape[0], :lp.shape[1]], miss[i, :lm.size] = lp, lm
    found, W = events.top_events(batch, miss, 50), events.k_best_clusters(batch, miss, 50)
    for i, (lp, _, alone, marginals) in enumerate(clusters):
        mine = found.cluster == i
        event = np.where(found.event[mine] == b, lp.shape[1], found.event[mine])
        assert np.array_equal(found.score[mine], alone.score) and np.array_equal(event[:, :lp.shape[0]], alone.event)
        assert np.all(event[:, lp.shape[0]:] == lp.shape[1])  # a padding track is always missed
        assert np.array_equal(W[i, :lp.shape[0], :lp.shape[1]], marginals[:, :-1])
        assert np.array_equal(W[i, :lp.shape[0], b], marginals[:, -1])


def test_approximations_error_at_the_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    """k-best (100 events) and LM-IPDA against exact enumeration on random clusters of the largest
    enumerated shape, 6 x 5 (docs/jipda.md)."""
    assert events.event_count(6, 5) <= jipda.MAX_EVENTS < events.event_count(6, 6)
    k_mu, k_beta = approximation_error(np.random.default_rng(4), 6, 5, 10)
    monkeypatch.setattr(jipda, "K_BEST_MAX_TRACKS", 0)
    lm_mu, lm_beta = approximation_error(np.random.default_rng(4), 6, 5, 10)
    assert 1e-4 < k_mu < 0.05 and 1e-4 < k_beta < 0.1  # measured 0.016, 0.032
    assert 1e-3 < lm_mu < 0.3 and 1e-3 < lm_beta < 0.5  # measured 0.15, 0.24
    assert k_mu < lm_mu / 3


def test_equivalent_observation_gives_the_pda_mean() -> None:
    rng = np.random.default_rng(5)
    c = jipda.jipda_constants(0.9, 1e-5, 9.21, 2, snr=10.0)
    R = 100.0 * np.eye(2)
    x = np.array([[0.0, 10.0, 0.0, 5.0], [60.0, -10.0, 0.0, 0.0], [5000.0, 0.0, 0.0, 0.0]])
    P = np.broadcast_to(np.diag([400.0, 100.0, 400.0, 100.0]), (3, 4, 4)).copy()
    z = np.array([[10.0, 5.0], [40.0, -10.0], [30.0, 8.0], [-1e4, 0.0]])
    amp = c.tau + rng.exponential(3.0, size=len(z))
    lin = linearize(x, None)
    pred = GaussianState(x, P)
    post, assoc, pairs = run_scan(pred, np.array([0.9, 0.5, 0.7]), z, amp, lin, R, c)
    reported, (oH, oR, oz) = jipda.equivalent_observation(pred, lin, R, pairs, assoc)
    assert reported.tolist() == [True, True, False]
    assert np.bincount(pairs.cols, minlength=len(z))[:3].max() == 2  # tracks 0 and 1 share detections
    for k, i in enumerate(np.flatnonzero(reported)):
        kf = update_residual(GaussianState(x[i], P[i]), oz[k] - oH[k] @ x[i], oH[k], oR[k]).state
        np.testing.assert_allclose(kf.x, post.x[i], rtol=1e-10, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(post.P) > 0.0)
    # track 2 sees nothing: existence decays as eq (8) with an empty gate
    np.testing.assert_allclose(assoc.existence[2], existence_update(
        np.array(0.7), np.log1p(-c.pd * c.pg), 1.0, 0.0), rtol=1e-12)
    free = jipda.unclaimed(len(z), pairs.cols, assoc)
    assert free[3] == 1.0 and np.all(free[:3] < 1.0)
    # a track reports when it more likely than not exists and made a detection, mu (1 - beta_0) >= 1/2:
    # the same scan with a clutter-born track 0 (existence 0.001) leaves it silent though its gate holds z_0
    _, faint, faint_pairs = run_scan(pred, np.array([0.001, 0.5, 0.7]), z, amp, lin, R, c)
    silent, _ = jipda.equivalent_observation(pred, lin, R, faint_pairs, faint)
    hit = faint.existence * faint.beta0 < faint.existence  # some detection given existence
    assert hit[0] and 1.0 - faint.beta0[0] >= 0.5 and faint.existence[0] * (1.0 - faint.beta0[0]) < 0.5
    assert silent.tolist() == (faint.existence * (1.0 - faint.beta0) >= 0.5).tolist() and not silent[0]


def test_derived_rules() -> None:
    rules = jipda.derived_rules(0.9, 0.999)

    def odds(p: float) -> float:
        return p / (1.0 - p)

    assert odds(rules.confirm) == pytest.approx(odds(0.1) / 0.01)
    assert odds(rules.delete) == pytest.approx(odds(0.1) * (1.0 - 0.9 * 0.999) ** 3)  # 3 misses: 0.1 % <= 1 % < 2 misses
    low = jipda.derived_rules(0.5, 0.999)  # 7 misses in a row: 0.8 % <= 1 % < 6 misses
    assert odds(low.delete) == pytest.approx(odds(0.1) * (1.0 - 0.5 * 0.999) ** 7)
    mu = np.array([0.95, 0.5, 0.49, 1e-4, 0.9])
    confirmed, keep = jipda.manage(mu, np.array([False, True, True, True, False]), rules)
    # reached the threshold; confirmed and still at least 1/2; below 1/2: back to tentative; not yet
    assert confirmed.tolist() == [True, True, False, False, False] and keep.tolist() == [True] * 3 + [False, True]
    odds_b = odds(jipda.birth_existence(np.array([1.0, 0.25]), 1))
    np.testing.assert_allclose(odds_b, [odds(0.1), 0.25 * odds(0.1)], rtol=1e-12)
    np.testing.assert_allclose(odds(jipda.birth_existence(np.array([1.0]), 30)), odds(0.1) / 30, rtol=1e-12)


@pytest.mark.parametrize("dt, misses", [(1.0, 3), (1.0 / 3.0, 4)])
def test_an_ended_targets_track_leaves_the_picture(dt: float, misses: int) -> None:
    """A track detected at every scan (dt apart) whose target then ends stays confirmed while its
    existence is at least 1/2 and goes back to tentative at miss K = ceil(ln(p11 / (1 - p11)) /
    ln(1 / (1 - P_D P_G))), p11 = exp(-dt / MEAN_LIFETIME) (docs/jipda.md): 3 at one 1-s sensor
    (gnn deletes after 3), 4 at a centre of three (gnn's centre after 6); deleted later."""
    pd, lam, gate_d2 = 0.9, 1e-7, float(chdtri(2, 1e-3))
    pg = jipda.scan_constants(pd, lam, gate_d2, 2).pg
    p11 = jipda.survival(dt, 1.0, jipda.SURVIVAL_PER_SECOND)
    assert p11 == pytest.approx(np.exp(-dt / jipda.MEAN_LIFETIME), rel=1e-12)
    assert misses == np.ceil(np.log(p11 / (1.0 - p11)) / -np.log1p(-pd * pg))
    rules = jipda.derived_rules(pd, pg)
    log_n = np.array([-np.log(2.0 * np.pi * 400.0)])  # a detection on the track, S = 400 I m^2
    mu, confirmed, shown, kept = np.array([0.1]), np.array([False]), [], []
    for k in range(40):
        hit = k < 20
        one = np.zeros(int(hit), np.int64)
        out = jipda.associate_scan(AssociationInput(1, int(hit), one, one, log_n[:int(hit)], 2, confirmed, mu, pd,
                                                    lam, None, None, gate_d2, dt))
        mu = out.existence
        confirmed, keep = jipda.manage(mu, confirmed, rules)
        if not hit:
            shown.append(bool(confirmed[0]))
            kept.append(bool(keep[0]))
    assert shown[:misses + 1] == [True] * (misses - 1) + [False, False]
    assert kept[misses] and not all(kept)  # hidden first, deleted later


def test_clutter_births_rarely_confirm() -> None:
    """Ville's bound: tracks born on clutter (isolated, clutter only) confirm with probability at most
    FALSE_CONFIRM; seeded Monte Carlo, 3 standard errors."""
    rng = np.random.default_rng(6)
    lam, pd, R = 2e-5, 0.9, 100.0 * np.eye(2)
    c = jipda.jipda_constants(pd, lam, float(chdtri(2, 1e-3)), 2)
    rules = jipda.derived_rules(pd, c.pg)
    n = 2000
    mot = motion(4, 1.0, 1.0)
    x = np.zeros((n, 4))
    x[:, 0] = 10_000.0 * np.arange(n)
    P = np.broadcast_to(np.diag([100.0, 900.0, 100.0, 900.0]), (n, 4, 4)).copy()
    mu = np.full(n, rules.birth)
    ever, alive = np.zeros(n, dtype=bool), np.ones(n, dtype=bool)
    for _ in range(8):
        x, P = predict(GaussianState(x, P), mot.F, mot.Q)
        k = rng.poisson(lam * 2000.0**2, size=n)
        z = np.repeat(x[:, [0, 2]], k, axis=0) + rng.uniform(-1000.0, 1000.0, size=(k.sum(), 2))
        post, assoc, _ = run_scan(GaussianState(x, P), existence_predict(mu, 0.98, 0.0), z, None,
                                  linearize(x, None), R, c)
        x, P, mu = post.x, post.P, assoc.existence
        confirmed, keep = jipda.manage(mu, ever, rules)
        ever |= confirmed & alive
        alive &= keep
    rate = ever.mean()
    assert rate <= jipda.FALSE_CONFIRM + 3.0 * np.sqrt(jipda.FALSE_CONFIRM * (1 - jipda.FALSE_CONFIRM) / n)
    assert not alive.all()  # clutter tracks die


REFERENCE = Path(__file__).parent / "data" / "mtt_reference"


def jipda_replay(tmp_path: Path, scenario: str, algorithm: str, scans: Path | None = None,
                 extra: str = "", process_noise: str = "fixed") -> list[dict]:
    """The reference scenario's pictures with jipda; ``process_noise`` stated (these tests check CV
    tracks unless told otherwise, whatever the key's default)."""
    cfg = tmp_path / f"{scenario}.toml"
    cfg.write_text((REFERENCE / f"{scenario}.toml").read_text().replace(
        "[mtt]\n", f'[mtt]\nassociator = "jipda"\nprocess_noise = "{process_noise}"\n{extra}', 1))
    out = tmp_path / f"{scenario}-{algorithm}-{process_noise}-{'sorted' if scans else 'arrival'}.jsonl"
    replay_mtt(algorithm, scans or REFERENCE / f"{scenario}-scans.jsonl", cfg, out,
               sensor={"pos": "s2", "radar": "r1"}[scenario] if algorithm == "mtt-local" else None)
    return [json.loads(line) for line in out.read_text().splitlines()]


@pytest.mark.parametrize("scenario, algorithm", [(s, a) for s in ("pos", "radar")
                                                 for a in ("mtt-local", "mtt-centralized")])
def test_jipda_tracker_pictures_carry_existence(tmp_path: Path, scenario: str, algorithm: str) -> None:
    pictures = jipda_replay(tmp_path, scenario, algorithm)
    rows = [tr for pic in pictures for tr in pic["tracks"]]
    assert rows and all(0.0 <= tr["existence"] <= 1.0 for tr in rows)
    last = [tr for tr in pictures[-1]["tracks"] if tr["status"] == "confirmed"]
    assert len(last) >= 2 and all(tr["existence"] > 0.5 for tr in last)
    rules = jipda.derived_rules(0.9, 0.999)
    assert all(tr["existence"] >= rules.delete * 0.98**2 for tr in rows)  # deleted below the threshold


@pytest.mark.parametrize("process_noise", ["fixed", "imm"])
def test_jipda_centralized_out_of_sequence_equals_time_sorted(tmp_path: Path, process_noise: str) -> None:
    """Acceptance (d) for jipda: out-of-sequence scans within max_lag give the time-sorted pictures;
    with two motion modes per track too (IMM-jipda: the re-runs carry each track's modes)."""
    lines = (REFERENCE / "pos-scans.jsonl").read_text().splitlines()
    times = [json.loads(line)["t"] for line in lines]
    assert times != sorted(times)  # the scenario has out-of-sequence scans
    sorted_scans = tmp_path / "sorted.jsonl"
    sorted_scans.write_text("\n".join(line for _, line in sorted(zip(times, lines), key=lambda p: p[0])) + "\n")
    wait = "picture_delay = 3.0\n"  # = max_lag: a picture waits for every scan up to its time
    arrival = jipda_replay(tmp_path, "pos", "mtt-centralized", extra=wait, process_noise=process_noise)
    ordered = jipda_replay(tmp_path, "pos", "mtt-centralized", sorted_scans, extra=wait, process_noise=process_noise)
    assert all("existence" in tr for p in arrival for tr in p["tracks"])
    assert_same_pictures(arrival, ordered)  # times, ids, statuses; x, P and existence to 1e-9


def test_jipda_refuses_maneuver_handling() -> None:
    with pytest.raises(ConfigError, match="maneuver"):
        MttConfig(associator="jipda", maneuver="vdie").validate()
    MttConfig(associator="jipda").validate()
