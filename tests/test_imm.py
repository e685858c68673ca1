"""IMM estimators of paper 000: exact equalities, activation/termination logic, numerical health."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fedtrack.config import ConfigError, parse_dataclass
from fedtrack.local_filters.imm.config import IMMConfig, paper_transition
from fedtrack.local_filters.imm.filter import (
    AO_VSIMM,
    AS_PRINTED,
    DROP_NEW,
    DROP_OLD,
    FSIMM,
    GROUP_PROBABILITY,
    KEEP_UNION,
    NO_GROUP,
    VSIMM,
    Cycle,
    IMMState,
    Thresholds,
    activation,
    active_models,
    combine,
    group_log_likelihood,
    initial_state,
    make_bank,
    mix,
    mode_inputs,
    model_cycle,
    posterior,
    step,
    termination,
)
from fedtrack.local_filters.linear.kalman import GaussianState, predict, symmetrize, update
from fedtrack.local_filters.linear.models import cv_model
from fedtrack.sensors.imm_scenarios import X0, acceleration_profile, simulate

R = 400.0 * np.eye(2)
P0 = np.diag([400.0, 900.0, 400.0, 900.0])
ALL = ((FSIMM, GROUP_PROBABILITY), (VSIMM, GROUP_PROBABILITY), (AO_VSIMM, GROUP_PROBABILITY),
       (VSIMM, AS_PRINTED))


def start(bank, algorithm: str, runs: int, rng: np.random.Generator, group: int = 0):
    x0 = X0 + rng.standard_normal((runs, 4)) * np.sqrt(np.diag(P0))
    return initial_state(bank, algorithm, group, x0, np.broadcast_to(P0, (runs, 4, 4)))


def test_one_model_imm_equals_kalman_filter():
    acc = np.array([[3.0, -2.0]])
    bank = make_bank(("a",), acc, np.ones((1, 1)), ((0,),), ("G",))
    model = cv_model(1.0, 100.0)
    truth = simulate("S1", 1, np.random.default_rng(5), steps=80)
    for algorithm in (FSIMM, VSIMM, AO_VSIMM):
        s = initial_state(bank, algorithm, 0, X0[None], P0[None])
        kf = GaussianState(X0, P0)
        for k in range(80):
            s, out = step(bank, algorithm, s, model, truth.z[:, k], R, Thresholds())
            kf, _ = update(predict(kf, model.F, model.Q, u_effect=model.G @ acc[0]), truth.z[0, k], model.H, R)
            np.testing.assert_allclose(out.est.x[0], kf.x, rtol=0, atol=1e-9 * np.abs(kf.x).max())
            np.testing.assert_allclose(out.est.P[0], kf.P, rtol=1e-9, atol=1e-9)
            assert out.mu[0, 0] == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("algorithm", [VSIMM, AO_VSIMM])
def test_single_group_of_all_models_equals_fsimm(algorithm):
    paper = IMMConfig()
    one = parse_dataclass(IMMConfig, {"groups": [{"name": "all", "models": [m.name for m in paper.models]}]})
    fs_bank, vs_bank = paper.bank(), one.bank()
    model = cv_model(1.0, paper.q)
    truth = simulate("S2", 6, np.random.default_rng(7), steps=200)
    fs = start(fs_bank, FSIMM, 6, np.random.default_rng(8))
    vs = start(vs_bank, algorithm, 6, np.random.default_rng(8))
    for k in range(200):
        fs, a = step(fs_bank, FSIMM, fs, model, truth.z[:, k], R, paper.thresholds())
        vs, b = step(vs_bank, algorithm, vs, model, truth.z[:, k], R, one.thresholds())
        np.testing.assert_allclose(b.est.x, a.est.x, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(b.est.P, a.est.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b.mu, a.mu, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.acc, a.acc, rtol=0, atol=1e-9)


@pytest.mark.parametrize("algorithm,rule", [(VSIMM, GROUP_PROBABILITY), (AO_VSIMM, GROUP_PROBABILITY),
                                            (VSIMM, AS_PRINTED)])
def test_batched_runs_equal_runs_one_at_a_time(algorithm, rule):
    """Runs in different active groups are batched together; the result must not depend on it."""
    cfg = IMMConfig()
    bank, th = cfg.bank(), cfg.thresholds()._replace(rule=rule)
    model = cv_model(1.0, cfg.q)
    runs = 6
    truth = simulate("S2", runs, np.random.default_rng(11), steps=120)
    batch = start(bank, algorithm, runs, np.random.default_rng(12))
    singles = [initial_state(bank, algorithm, 0, batch.x[r:r + 1, 0], batch.P[r:r + 1, 0]) for r in range(runs)]
    groups_seen = set()
    for k in range(120):
        batch, out = step(bank, algorithm, batch, model, truth.z[:, k], R, th)
        groups_seen |= set(zip(out.old.tolist(), out.new.tolist()))
        for r in range(runs):
            singles[r], one = step(bank, algorithm, singles[r], model, truth.z[r:r + 1, k], R, th)
            np.testing.assert_allclose(out.est.x[r], one.est.x[0], rtol=1e-12, atol=1e-8)
            np.testing.assert_allclose(out.mu[r], one.mu[0], rtol=0, atol=1e-10)
            assert (out.old[r], out.new[r]) == (one.old[0], one.new[0])
    assert len(groups_seen) >= 3  # the batch really did mix active configurations


@pytest.mark.parametrize("algorithm", [AO_VSIMM, VSIMM])
def test_activation_reinitializes_like_a_cycle_from_the_old_group(algorithm):
    """At an activation the estimate equals one IMM cycle from M_o (k-1) to the new set (eqs. (2)-(6))."""
    cfg = IMMConfig()
    bank, th = cfg.bank(), cfg.thresholds()
    model = cv_model(1.0, cfg.q)
    u = mode_inputs(model, bank.acc)
    runs = 10
    truth = simulate("S1", runs, np.random.default_rng(21), steps=200)
    s = start(bank, algorithm, runs, np.random.default_rng(22))
    checked = 0
    for k in range(200):
        prev = s
        s, out = step(bank, algorithm, s, model, truth.z[:, k], R, th)
        fired = (prev.new == NO_GROUP) & ((out.old != prev.old) | (out.new != NO_GROUP))
        for r in np.flatnonzero(fired):
            src = active_models(bank, int(prev.old[r]), NO_GROUP)
            dst = active_models(bank, int(out.old[r]), int(out.new[r]))
            before = IMMState(prev.x[r:r + 1, src], prev.P[r:r + 1, src], prev.mu[r:r + 1, src])
            post = posterior(model_cycle(before, bank.Pi[np.ix_(src, dst)], u[dst], model,
                                         truth.z[r:r + 1, k], R))
            np.testing.assert_allclose(out.est.x[r], combine(post).x[0], rtol=1e-12, atol=1e-8)
            np.testing.assert_allclose(out.mu[r, dst], post.mu[0], rtol=0, atol=1e-12)
            assert out.models_run[r] == src.size + len(set(dst) - set(src))
            checked += 1
    assert checked >= 5


def test_activation_rules_1_and_2():
    bank = IMMConfig().bank()
    m1_group = active_models(bank, 0, NO_GROUP)  # M1 = m1..m5, sorted
    m2_group = active_models(bank, 1, NO_GROUP)  # M2 = m1, m2, m6, m9, m10

    def decide(idx, best, mu_best, current):
        log_lik = np.full((1, idx.size), -10.0)
        log_lik[0, best] = -1.0
        mu = np.full((1, idx.size), (1.0 - mu_best) / (idx.size - 1))
        mu[0, best] = mu_best
        c = Cycle(GaussianState(np.zeros((1, idx.size, 4)), np.zeros((1, idx.size, 4, 4))),
                  np.zeros((1, idx.size)), log_lik)
        return int(activation(bank, idx[None], np.array([current]), c, IMMState(c.post.x, c.post.P, mu), 0.4)[0])

    assert decide(m1_group, 2, 0.5, 0) == 2  # rule (1): m3 in M1 -> activate M3
    assert decide(m1_group, 2, 0.35, 0) == NO_GROUP  # probability condition fails
    assert decide(m1_group, 0, 0.9, 0) == NO_GROUP  # m1 is M1's own centre
    assert decide(m2_group, 0, 0.6, 1) == 0  # rule (2): m1 in M2 -> activate M1
    assert decide(m2_group, 2, 0.9, 1) == NO_GROUP  # m6 is no group's centre


def test_termination_rules():
    # union of three models: old group {0, 1}, new group {0, 2}; model 2 explains the data
    in_old = np.array([True, True, False])
    in_new = np.array([True, False, True])
    log_pred = np.log(np.array([[0.3, 0.4, 0.3]]))
    log_lik = np.array([[-8.0, -9.0, -2.0]])
    c = Cycle(GaussianState(np.zeros((1, 3, 4)), np.zeros((1, 3, 4, 4))), log_pred, log_lik)
    post = posterior(c)
    direct = np.log((0.3 * np.exp(-8.0) + 0.3 * np.exp(-2.0)) / 0.6)
    assert group_log_likelihood(c, in_new)[0] == pytest.approx(direct, rel=1e-12)
    lr, d = termination(c, post, in_old, in_new, np.zeros(1), Thresholds(rule=GROUP_PROBABILITY))
    assert post.mu[0, 2] > 0.93 and lr[0] > 0 and d[0] == DROP_OLD
    _, d = termination(c, post, in_old, in_new, np.zeros(1), Thresholds(rule=AS_PRINTED))
    assert d[0] == DROP_NEW  # the printed rule drops the group that fits
    _, d = termination(c, post, in_old, in_new, np.full(1, -50.0), Thresholds(rule=GROUP_PROBABILITY))
    assert d[0] == KEEP_UNION  # probability says new, accumulated likelihood ratio says old
    swapped = Cycle(c.post, log_pred, log_lik[:, [0, 2, 1]])  # the old group's own model fits
    _, d = termination(swapped, posterior(swapped), in_old, in_new, np.zeros(1), Thresholds())
    assert d[0] == DROP_NEW


@pytest.mark.parametrize("scenario", ["S1", "S2"])
def test_probabilities_sum_to_one_without_nan_or_underflow_over_500_steps(scenario):
    cfg = IMMConfig()
    bank = cfg.bank()
    model = cv_model(1.0, cfg.q)
    runs = 8
    truth = simulate(scenario, runs, np.random.default_rng(31), steps=500)
    for algorithm, rule in ALL:
        th = cfg.thresholds()._replace(rule=rule)
        s = start(bank, algorithm, runs, np.random.default_rng(32))
        for k in range(500):
            s, out = step(bank, algorithm, s, model, truth.z[:, k], R, th)
            assert np.all(np.isfinite(out.mu)) and np.all(np.isfinite(out.est.x))
            np.testing.assert_allclose(out.mu.sum(axis=1), 1.0, rtol=0, atol=1e-12)
            for r in range(runs):
                running = (np.arange(bank.size) if out.old[r] == NO_GROUP
                           else active_models(bank, int(out.old[r]), int(out.new[r])))
                assert np.all(out.mu[r, running] > 0.0), (algorithm, k, r)  # no underflow to 0
            assert np.all(np.linalg.eigvalsh(out.est.P) > 0.0)
        err = out.est.x[:, [0, 2]] - truth.x[:, -1, [0, 2]]
        assert np.all(np.abs(err) < 200.0)  # still tracking after 500 steps


def test_errata_transition_matrix():
    Pi = paper_transition()
    np.testing.assert_allclose(Pi.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    assert Pi[0, 0] == pytest.approx(116 / 120) and Pi[0, 1] == pytest.approx(1 / 120)
    assert Pi[1, 0] == 0.02 and Pi[1, 1] == 0.95 and Pi[1, [5, 8, 9]].tolist() == [0.01] * 3
    assert Pi[2, [5, 6, 10]].tolist() == [0.01] * 3 and Pi[3, [6, 7, 11]].tolist() == [0.01] * 3
    assert Pi[4, [7, 8, 12]].tolist() == [0.01] * 3
    assert Pi[5, 1] == Pi[5, 2] == pytest.approx(1 / 30) and Pi[8, 1] == Pi[8, 4] == pytest.approx(1 / 30)
    assert Pi[9, 1] == 0.1 and Pi[12, 4] == 0.1 and Pi[12, 12] == 0.9
    # every model of every group is reachable from the groups it can be activated from
    bank = IMMConfig().bank()
    for g, members in enumerate(bank.groups):
        for h in range(len(bank.groups)):
            if bank.centre[members[0]] == g and members[0] in bank.groups[h] and h != g:
                src = active_models(bank, h, NO_GROUP)
                assert np.all(bank.Pi[np.ix_(src, list(members))].sum(axis=0) > 0)


def test_scenario_profiles_and_truth_model():
    a1 = acceleration_profile("S1")
    assert a1.shape == (200, 2)
    assert a1[29].tolist() == [0, 0] and a1[30].tolist() == [18, 3] and a1[54].tolist() == [38, -2]
    assert acceleration_profile("S2")[55].tolist() == [0, 31] and acceleration_profile("S2")[199].tolist() == [2, -18]
    np.testing.assert_array_equal(acceleration_profile("S2", 450)[200:400], acceleration_profile("S2"))
    with pytest.raises(ValueError, match="S3"):
        acceleration_profile("S3")
    # with (almost) no noise the truth integrates the mode input G a_k from x0 = 20 km, 340 m/s per axis
    tr = simulate("S1", 2, np.random.default_rng(0), steps=60, q=1e-18, R=1e-18 * np.eye(2))
    m = cv_model(1.0, 1.0)
    x = X0.copy()
    for k in range(60):
        x = m.F @ x + m.G @ a1[k]
    np.testing.assert_allclose(tr.x[:, -1], np.broadcast_to(x, (2, 4)), rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(tr.z[:, -1], tr.x[:, -1, [0, 2]], atol=1e-6)
    again = simulate("S1", 2, np.random.default_rng(3))
    np.testing.assert_array_equal(again.z, simulate("S1", 2, np.random.default_rng(3)).z)
    big = simulate("S1", 4000, np.random.default_rng(4), steps=2)  # process noise std 10 per axis
    w = (big.x[:, 1, 1] - big.x[:, 0, 1]) / 1.0 - a1[0, 0]
    assert np.std(w) == pytest.approx(10.0, rel=0.05)


def test_config_errors_name_the_key(tmp_path: Path):
    from fedtrack.local_filters.imm.config import load_imm_config

    def fails(text: str, match: str) -> None:
        p = tmp_path / "c.toml"
        p.write_text(text)
        with pytest.raises(ConfigError, match=match):
            load_imm_config(p)

    fails("[imm]\ntresholds = 1\n", r"c\.toml: unknown config key imm\.tresholds")
    fails("tresholds = 1\n", r"c\.toml: unknown config key tresholds")
    fails('[[imm.models]]\nname = "a"\nacceleration = [0, 0]\nspeed = 3\n', r"unknown config key imm\.models\[0\]\.speed")
    fails('[[imm.models]]\nname = "a"\nacceleration = [0, 0]\n', "imm.transition: expected a 1x1")
    fails('[imm]\ntransition = [[0.5, 0.6], [0.5, 0.5]]\n[[imm.models]]\nname = "a"\nacceleration = [0, 0]\n'
          '[[imm.models]]\nname = "b"\nacceleration = [1, 0]\n[[imm.groups]]\nname = "G"\nmodels = ["a", "b"]\n',
          "transition: row 0")
    fails('[[imm.groups]]\nname = "G"\nmodels = ["m1", "m99"]\n', "unknown model 'm99'")
    fails('[imm]\ntermination_rule = "backwards"\n', "imm.termination_rule")
    fails('[imm]\nactivation_threshold = 1.5\n', "imm.activation_threshold")


def test_example_config_loads_and_runs():
    from fedtrack.local_filters.imm.config import load_imm_config

    cfg = load_imm_config(Path(__file__).resolve().parents[1] / "deploy" / "imm-3model.toml")
    bank = cfg.bank()
    assert bank.size == 3 and len(bank.groups) == 2
    s = initial_state(bank, AO_VSIMM, cfg.initial_group_index(), X0[None], P0[None])
    truth = simulate("S1", 1, np.random.default_rng(2), steps=60)
    for k in range(60):
        s, out = step(bank, AO_VSIMM, s, cv_model(1.0, cfg.q), truth.z[:, k], R, cfg.thresholds())
    assert out.mu.sum() == pytest.approx(1.0, abs=1e-12)


def test_fractional_transition_needs_no_schur_pade_per_call(monkeypatch) -> None:
    """A fractional ``Pi^s`` comes from the matrix's eigen-decomposition, made once: equal to
    scipy's Schur-Pade power (clipped and renormalized) to 1e-12, and that 25 ms routine is not
    called per measurement (20 Hz IMM replay ran at 14-30 ms a step, 0.25 ms at 1 Hz)."""
    import scipy.linalg
    from scipy.linalg import fractional_matrix_power

    from fedtrack.local_filters.imm.filter import transition_over

    Pi = IMMConfig().bank().Pi
    expected = {}
    for s in (0.05, 0.3, 2.5):
        ref = np.clip(np.real(fractional_matrix_power(Pi, s)), 0.0, None)
        expected[s] = ref / ref.sum(axis=1, keepdims=True)

    def refuse(*_args, **_kwargs):
        raise AssertionError("Schur-Pade fractional power called for a diagonalizable matrix")

    monkeypatch.setattr(scipy.linalg, "fractional_matrix_power", refuse)
    for s, ref in expected.items():
        np.testing.assert_allclose(transition_over(Pi, s), ref, rtol=0, atol=1e-12)
    # a defective matrix (a Jordan block: a chain's generator exponentiated) goes through scipy
    monkeypatch.undo()
    generator = np.array([[-1.0, 1.0, 0.0], [0.0, -1.0, 1.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(transition_over(scipy.linalg.expm(generator), 0.5),
                               scipy.linalg.expm(0.5 * generator), atol=1e-9)


def test_transitions_scale_with_the_interval() -> None:
    """``Pi^(dt/T)``: unchanged at the nominal interval, squared over two, a stochastic root over half."""
    from fedtrack.local_filters.imm.filter import transition_over
    from fedtrack.local_filters.imm.tracker import IMMTracker

    Pi = IMMConfig().bank().Pi
    assert transition_over(Pi, 1.0) is Pi
    np.testing.assert_allclose(transition_over(Pi, 2.0), Pi @ Pi, rtol=1e-12)
    np.testing.assert_array_equal(transition_over(Pi, 0.0), np.eye(len(Pi)))
    half = transition_over(Pi, 0.5)
    assert np.all(half >= 0) and np.allclose(half.sum(axis=1), 1.0)
    np.testing.assert_allclose(half @ half, Pi, atol=1e-3)  # clipping makes the root approximate
    # a tracker sampled at 2 s equals one whose matrix is given per 2 s, Pi^2, at the nominal interval
    z = [np.array([300.0 * k, 20.0 * k * k]) for k in range(8)]
    R = np.eye(2) * 1e4
    irregular = IMMTracker(IMMConfig(), "fsimm")
    squared = IMMTracker(dataclasses.replace(IMMConfig(), transition=tuple(map(tuple, Pi @ Pi)),
                                             transition_interval=2.0), "fsimm")
    for k, zk in enumerate(z):
        a, b = irregular.update(2.0 * k, zk, R), squared.update(2.0 * k, zk, R)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9)
        assert a.mode_probabilities == pytest.approx(b.mode_probabilities, rel=1e-9)


@pytest.mark.parametrize("lead", [(1,), (500,), (3, 70)])
def test_two_mode_mix_and_combine_equal_the_einsum_sums_bitwise(lead) -> None:
    """The two-mode path (batch last, no einsum) gives the general path's sums bit for bit."""
    rng = np.random.default_rng(7)
    for n in (4, 6):
        x = rng.standard_normal(lead + (2, n)) * 300.0
        A = rng.standard_normal(lead + (2, n, n))
        s = IMMState(x, A @ np.swapaxes(A, -1, -2) * 50.0, rng.dirichlet([1.0, 1.0], size=lead))
        p = rng.uniform(0.0, 0.3, size=lead + (2,))
        Pi = np.stack([np.stack([1.0 - p[..., 0], p[..., 0]], -1), np.stack([p[..., 1], 1.0 - p[..., 1]], -1)], -2)
        w = Pi * s.mu[..., :, None]
        c = w.sum(axis=-2)
        w = w / c[..., None, :]
        x0 = np.einsum("...ji,...jn->...in", w, s.x)
        d = s.x[..., :, None, :] - x0[..., None, :, :]
        P0 = np.einsum("...ji,...jab->...iab", w, s.P) + np.einsum("...ji,...jia,...jib->...iab", w, d, d)
        mixed, log_pred = mix(s, Pi)
        assert mixed.x.tobytes() == x0.tobytes() and mixed.P.tobytes() == symmetrize(P0).tobytes()
        assert log_pred.tobytes() == np.log(c).tobytes()
        xc = np.einsum("...i,...in->...n", s.mu, s.x)
        e = s.x - xc[..., None, :]
        Pc = np.einsum("...i,...iab->...ab", s.mu, s.P + e[..., :, None] * e[..., None, :])
        est = combine(s)
        assert est.x.tobytes() == xc.tobytes() and est.P.tobytes() == symmetrize(Pc).tobytes()
