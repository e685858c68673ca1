"""PDA-AI / HPDA maths (paper 001): exact limits, independent references, Monte Carlo ranks."""

from math import comb, exp, factorial

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update
from fedtrack.local_filters.pda.association import (
    PDAParams,
    amplitude_ranks,
    associate,
    constants,
    existence_update,
    gate,
    hpda_hypothesise,
    hpda_update,
    log_amplitude_ratio,
    log_rank_probability,
    pda_ai_hypothesise,
    pda_update,
    singer_model,
    two_point_init,
)
from fedtrack.sensors.sonar import ScenarioConfig, SonarConfig, sonar_scans, truth_states

R = 225.0 * np.eye(2)
MODEL = singer_model(25.0, 0.01, 500.0)


def random_state(rng: np.random.Generator, batch: tuple[int, ...] = ()) -> GaussianState:
    A = rng.normal(size=batch + (6, 6))
    P = A @ np.swapaxes(A, -1, -2) * 20.0 + 50.0 * np.eye(6)
    return GaussianState(rng.normal(size=batch + (6,)) * 10.0, P)


def test_singer_discretization_matches_closed_form_and_quadrature():
    T, sa, ts = 25.0, 0.01, 500.0
    m = singer_model(T, sa, ts)
    a = T / ts
    # per-axis transition of the Singer model and its stationary acceleration variance
    assert m.F[0, 2] == pytest.approx(ts**2 * (a - 1.0 + np.exp(-a)), rel=1e-10)
    assert m.F[2, 2] == pytest.approx(np.exp(-a), rel=1e-13)
    assert m.Q[2, 2] == pytest.approx(sa**2 * (1.0 - np.exp(-2.0 * a)), rel=1e-10)
    Ac = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / ts]])
    L = np.array([0.0, 0.0, 1.0])
    def integrand(s: float) -> np.ndarray:
        f = expm(Ac * s) @ L
        return 2.0 * sa**2 / ts * np.outer(f, f)

    q_ref, _ = quad_vec(integrand, 0.0, T, epsabs=0.0, epsrel=1e-13)
    np.testing.assert_allclose(m.Q[:3, :3], q_ref, rtol=1e-9)
    np.testing.assert_array_equal(m.Q[:3, 3:], 0.0)
    np.testing.assert_allclose(m.Q[3:, 3:], m.Q[:3, :3], rtol=0, atol=0)


def test_gate_constants():
    c = constants(PDAParams())
    assert c.pg == pytest.approx(0.99, abs=1e-4)
    g2 = c.gamma / 2.0
    assert c.c_gamma == pytest.approx((1 - exp(-g2) * (1 + g2)) / (1 - exp(-g2)), rel=1e-12)
    assert np.exp(-c.tau / 21.0) == pytest.approx(0.9, rel=1e-12)


def textbook_pda(state: GaussianState, zs: np.ndarray, pd: float, lam: float, gamma: float,
                 pg: float, cg: float) -> tuple[np.ndarray, np.ndarray]:
    """Bar-Shalom's parametric PDA with the missed-gate term, written with explicit inverses."""
    H = MODEL.H
    x, P = state
    S = H @ P @ H.T + R
    Si = np.linalg.inv(S)
    K = P @ H.T @ Si
    nus = [z - H @ x for z in zs]
    nus = [v for v in nus if v @ Si @ v <= gamma]
    e = [pd * np.exp(-0.5 * v @ Si @ v) / np.sqrt(np.linalg.det(2 * np.pi * S)) for v in nus]
    b = lam * (1 - pd * pg)
    den = b + sum(e)
    beta = [ei / den for ei in e]
    beta0 = b / den
    nu = sum((bi * v for bi, v in zip(beta, nus)), np.zeros(2))
    spread = sum((bi * np.outer(v, v) for bi, v in zip(beta, nus)), np.zeros((2, 2))) - np.outer(nu, nu)
    miss = pd * pg * (1 - cg) / (1 - pd * pg)
    Pn = beta0 * (P + miss * K @ S @ K.T) + (1 - beta0) * (P - K @ S @ K.T) + K @ spread @ K.T
    return x + K @ nu, Pn


def test_pda_ai_without_amplitude_information_equals_textbook_pda():
    rng = np.random.default_rng(1)
    p = PDAParams(pd=0.8, clutter_density=2e-4, snr=0.0)  # rho = 0: f1 = f0, A = 1
    c = constants(p)
    for _ in range(5):
        st = random_state(rng)
        zs = MODEL.H @ st.x + rng.normal(size=(7, 2)) * 40.0
        amp = c.tau + rng.exponential(size=7)
        np.testing.assert_array_equal(log_amplitude_ratio(amp, c), 0.0)
        g = gate(st, zs, np.ones(7, dtype=bool), MODEL.H, R, c)
        assert 0 < g.inside.sum() < 7
        post = pda_update(st, g, pda_ai_hypothesise(g, log_amplitude_ratio(amp, c), c), c)
        x_ref, P_ref = textbook_pda(st, zs, p.pd, p.clutter_density, p.gate, c.pg, c.c_gamma)
        np.testing.assert_allclose(post.x, x_ref, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(post.P, P_ref, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("algorithm", ["pda", "hpda"])
def test_no_clutter_unit_pd_equals_kalman(algorithm: str):
    rng = np.random.default_rng(2)
    p = PDAParams(pd=1.0, clutter_density=1e-300, snr=20.0)  # lambda = 0 exactly is 0/0 in alpha
    c = constants(p)
    truth = np.array([0.0, 3.0, 0.0, 0.0, -2.0, 0.0])
    st = kf = two_point_init(np.zeros(2), np.array([75.0, -50.0]), 25.0, R, 0.01)
    for _ in range(30):
        truth = MODEL.F @ truth
        z = MODEL.H @ truth + rng.normal(size=2)  # well inside the gate
        pred = predict(st, MODEL.F, MODEL.Q)
        g = gate(pred, z[None, :], np.ones(1, dtype=bool), MODEL.H, R, c)
        assert g.inside.all()
        amp = np.array([c.tau + 5.0])
        if algorithm == "pda":
            st = pda_update(pred, g, pda_ai_hypothesise(g, log_amplitude_ratio(amp, c), c), c)
        else:
            st = hpda_update(pred, g, hpda_hypothesise(g, amp, c))
        kf, _ = update(predict(kf, MODEL.F, MODEL.Q), z, MODEL.H, R)
        np.testing.assert_allclose(st.x, kf.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(st.P, kf.P, rtol=1e-9, atol=1e-12)


def test_rank_probability_equals_paper_formulas():
    rho = 20.0
    for m in range(1, 9):
        pa = 1 + sum((-1) ** i * comb(m - 1, i) / ((i + 1) + i * rho) for i in range(1, m))
        got = np.exp(log_rank_probability(np.arange(1, m + 1), np.full(m, m), rho))
        assert got[0] == pytest.approx(pa, rel=1e-12)  # P_A(m)
        assert got[-1] == pytest.approx(1.0 / (m + (m - 1) * rho), rel=1e-12)  # l = m
        for l in range(2, m):  # gamma(l, m)
            prod = np.prod([(j - 1) * (1 + rho) + 1 for j in range(1, l)])
            assert got[l - 1] == pytest.approx(prod / (factorial(l - 1) * (1 + rho) ** (l - 1)) * pa, rel=1e-10)
        assert got.sum() == pytest.approx(1.0, rel=1e-12)


def test_rank_probability_monte_carlo():
    """Rank of the target amplitude among m = 5 thresholded detections, rho = 20."""
    rng = np.random.default_rng(7)
    c = constants(PDAParams(pd=0.9, snr=20.0))
    n, m = 200_000, 5
    amp = np.concatenate([c.tau + rng.exponential(21.0, size=(n, 1)),
                          c.tau + rng.exponential(1.0, size=(n, m - 1))], axis=1)
    rank = amplitude_ranks(amp, np.ones_like(amp, dtype=bool))[:, 0]
    p_formula = np.exp(log_rank_probability(np.arange(1, m + 1), np.full(m, m), 20.0))
    for l in range(1, m + 1):
        frac = np.mean(rank == l)
        se = np.sqrt(p_formula[l - 1] * (1 - p_formula[l - 1]) / n)
        assert abs(frac - p_formula[l - 1]) < 3 * se, (l, frac, p_formula[l - 1], se)


def reference_beta(l: int, m: int, a: float, N: float, VG: float, p: PDAParams) -> float:
    """beta_l from the corrected eqs (11), (13), (14), term by term."""
    c = constants(p)
    pd, pg, lam, rho, tau = p.pd, c.pg, p.clutter_density, p.snr, c.tau
    pfa = np.exp(-tau)
    G0 = np.exp(-a) / pfa
    f1r = np.exp(-a / (1 + rho)) / (1 + rho) / pd
    f0r = np.exp(-a) / pfa

    def mu_f(k: int) -> float:
        return (lam * VG) ** k / factorial(k) * np.exp(-lam * VG)

    fT = comb(m - 1, l - 1) * N / pg * G0 ** (l - 1) * (1 - G0) ** (m - l) * f1r * pd * pg * mu_f(m - 1)
    fF = factorial(m) / (factorial(l - 1) * factorial(m - l)) * f0r * G0 ** (l - 1) * (1 - G0) ** (m - l) \
        * (1 - pd * pg) * mu_f(m)
    if l >= 2:
        fF += factorial(m - 1) / (factorial(l - 2) * factorial(m - l)) * f0r * pg * np.exp(-a / (1 + rho)) \
            * G0 ** (l - 2) * (1 - G0) ** (m - l) * mu_f(m - 1)
    if l <= m - 1:
        fF += factorial(m - 1) / (factorial(l - 1) * factorial(m - l - 1)) * f0r * pg \
            * (pd - np.exp(-a / (1 + rho))) * G0 ** (l - 1) * (1 - G0) ** (m - l - 1) * mu_f(m - 1)
    return fT / (fT + fF / VG)


def test_hpda_beta_matches_term_by_term_equations():
    rng = np.random.default_rng(4)
    p = PDAParams(pd=0.9, clutter_density=3e-4, snr=20.0)
    c = constants(p)
    for _ in range(10):
        st = random_state(rng)
        m = int(rng.integers(1, 6))
        zs = MODEL.H @ st.x + rng.normal(size=(m, 2)) * 15.0
        amp = c.tau + rng.exponential(rng.choice([1.0, 21.0]), size=m)
        g = gate(st, zs, np.ones(m, dtype=bool), MODEL.H, R, c)
        inside = np.flatnonzero(g.inside)
        if inside.size == 0:
            continue
        ranks = amplitude_ranks(amp, g.inside)
        VG = np.exp(g.log_vg)
        ref = np.array([reference_beta(int(ranks[j]), inside.size, amp[j], np.exp(g.log_n[j]), VG, p)
                        for j in inside])
        h = hpda_hypothesise(g, amp, c)
        assert h.index == inside[np.argmax(ref)]
        assert h.beta == pytest.approx(ref.max(), rel=1e-9)


def test_hpda_alpha_is_the_mixture_of_its_two_clutter_cases_and_m0_limit():
    rng = np.random.default_rng(5)
    p = PDAParams(pd=0.8, clutter_density=1e-4)
    c = constants(p)
    st = random_state(rng)
    far = MODEL.H @ st.x + 1e6
    g = gate(st, far[None, :], np.ones(1, dtype=bool), MODEL.H, R, c)
    h = hpda_hypothesise(g, np.array([c.tau + 1.0]), c)
    assert not h.found and h.beta == 0.0
    pdpg = p.pd * c.pg
    assert h.alpha == pytest.approx((1 - pdpg * c.c_gamma) / (1 - pdpg), rel=1e-12)
    post = hpda_update(st, g, h)
    pda = pda_update(st, g, pda_ai_hypothesise(g, np.zeros(1), c), c)
    np.testing.assert_allclose(post.P, pda.P, rtol=1e-12)
    np.testing.assert_array_equal(post.x, st.x)


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_batched_padded_equals_one_at_a_time(algorithm: str):
    rng = np.random.default_rng(6)
    c = constants(PDAParams(pd=0.9, clutter_density=2e-4))
    B, M = 6, 5
    st = random_state(rng, (B,))
    z = (st.x @ MODEL.H.T)[:, None, :] + rng.normal(size=(B, M, 2)) * 30.0
    amp = c.tau + rng.exponential(3.0, size=(B, M))
    valid = np.arange(M) < rng.integers(0, M + 1, size=B)[:, None]
    g = gate(st, z, valid, MODEL.H, R, c)
    post, lr = associate(algorithm, st, g, amp, c)
    for b in range(B):
        keep = valid[b]
        s1 = GaussianState(st.x[b], st.P[b])
        g1 = gate(s1, z[b][keep], np.ones(keep.sum(), dtype=bool), MODEL.H, R, c)
        p1, lr1 = associate(algorithm, s1, g1, amp[b][keep], c)
        np.testing.assert_allclose(post.x[b], p1.x, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(post.P[b], p1.P, rtol=1e-12, atol=1e-9)
        assert lr[b] == pytest.approx(float(lr1), rel=1e-12, abs=1e-12)


def test_existence_update_equals_printed_recursion():
    rng = np.random.default_rng(8)
    mu = rng.uniform(0.01, 0.99, size=50)
    lr = rng.lognormal(0.0, 2.0, size=50)  # 1 - delta
    delta = 1.0 - lr
    p11, p21 = 0.98, 0.01
    mu_bar = p11 * mu + p21 * (1 - mu)
    ref = (1 - delta) * mu_bar / (1 - delta * mu_bar)
    np.testing.assert_allclose(existence_update(mu, np.log(lr), p11, p21), ref, rtol=1e-12)


def test_existence_ratio_under_clutter_only():
    """Under clutter alone E[1 - delta] = 1 for IPDA-AI's eq (9); HPDA's eq (16) evaluates
    the ratio at the *selected* (most target-like) detection, which biases it upward.

    rho = 0.5 keeps the amplitude ratio's variance finite (it is infinite for rho >= 1).
    """
    rng = np.random.default_rng(9)
    p = PDAParams(pd=0.9, clutter_density=5e-4, snr=0.5)
    c = constants(p)
    n = 20000
    st = GaussianState(np.zeros((n, 6)), np.broadcast_to(np.diag([400.0, 1, 1e-4, 400, 1, 1e-4]), (n, 6, 6)))
    half = np.sqrt(c.gamma * (400.0 + 225.0))
    count = rng.poisson(p.clutter_density * (2 * half) ** 2, size=n)
    M = int(count.max())
    z = rng.uniform(-half, half, size=(n, M, 2))
    amp = c.tau + rng.exponential(1.0, size=(n, M))
    valid = np.arange(M) < count[:, None]
    g = gate(st, z, valid, MODEL.H, R, c)
    ipda = np.exp(pda_ai_hypothesise(g, log_amplitude_ratio(amp, c), c).log_lr)
    assert abs(ipda.mean() - 1.0) < 3 * ipda.std() / np.sqrt(n)
    hpda = np.exp(hpda_hypothesise(g, amp, c).log_lr)
    assert hpda.mean() - 1.0 > 3 * hpda.std() / np.sqrt(n)


def test_truth_and_sonar_scans():
    sc = ScenarioConfig()
    t, x = truth_states(sc)
    assert t[-1] == 1500.0 and len(t) == 61
    a = -0.001 * 9.80665
    np.testing.assert_allclose(x[-1, [0, 3]], [5000 + 4 * 1500, 4000 + 0.5 * a * 700**2], rtol=1e-12)
    cfg = SonarConfig(pd=0.9, clutter_density=1e-4, region_half_width=300.0, blackout_scans=2)
    lines = list(sonar_scans(cfg, 3))
    assert len(lines) == 61
    counts = np.array([len(ln["detections"]) for ln in lines])
    assert abs(counts.mean() - (0.9 + 36.0)) < 4 * np.sqrt(37.0 / 61)
    # during the blackout no detection sits on the target (clutter within 1 m: p ~ 3e-4)
    for ln in lines[:2]:
        pos = np.array(ln["truth"])[[0, 3]]
        assert all(np.linalg.norm(np.array(d["z"]) - pos) > 1.0 for d in ln["detections"])
    # afterwards the strongest detection is the target's with probability P_D P_A(m), m ~ 37
    hits = [np.linalg.norm(np.array(max(ln["detections"], key=lambda d: d["amplitude"])["z"])
                           - np.array(ln["truth"])[[0, 3]]) < 75.0 for ln in lines[2:]]
    p = 0.9 * np.exp(log_rank_probability(np.array(1), np.array(37), 20.0))
    assert abs(np.mean(hits) - p) < 3 * np.sqrt(p * (1 - p) / len(hits))
    amps = np.concatenate([[d["amplitude"] for d in ln["detections"]] for ln in lines])
    assert amps.min() >= cfg.tau
    assert list(sonar_scans(cfg, 3))[5] == lines[5]  # seeded


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_candidate_detections_give_the_full_scans_association(algorithm: str) -> None:
    """Gathering each track's candidate detections (k-d tree) changes nothing but the cost."""
    from fedtrack.local_filters.pda.association import candidates, original_index, scan_evidence

    rng = np.random.default_rng(3)
    p = PDAParams(clutter_density=1e-4)
    c = constants(p)
    model = singer_model(25.0, p.sigma_a, p.tau_s)
    n, m = 30, 80
    x = np.zeros((n, 6))
    x[:, [0, 3]] = rng.uniform(-300, 300, (n, 2))
    P = np.diag([400.0, 1.0, 1e-4, 400.0, 1.0, 1e-4]) * rng.uniform(0.2, 5.0, (n, 1, 1))
    st = GaussianState(x, P)
    z = rng.uniform(-400, 400, (m, 2))
    amp = c.tau + rng.exponential(3.0, m)
    R = 225.0 * np.eye(2)
    full = gate(st, np.broadcast_to(z, (n, m, 2)), np.ones((n, m), bool), model.H, R, c)
    index, valid = candidates(st, z, model.H, R, c)
    assert index.shape[1] < m and np.all(np.sum(valid, axis=1) >= np.sum(full.inside, axis=1))
    small = gate(st, z[index], valid, model.H, R, c)
    a, lr_a = associate(algorithm, st, full, np.broadcast_to(amp, (n, m)), c)
    b, lr_b = associate(algorithm, st, small, amp[index], c)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(b.P, a.P, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(lr_b, lr_a, rtol=1e-12, atol=1e-12)
    ev_a, ev_b = scan_evidence(full, np.broadcast_to(amp, (n, m)), c), scan_evidence(small, amp[index], c)
    np.testing.assert_array_equal(original_index(ev_b.dominant, index), ev_a.dominant)
