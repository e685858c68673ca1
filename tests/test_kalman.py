"""Kalman core: batching, Joseph form, steady state against paper 004's numbers."""

import numpy as np
import pytest

from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    Innovation,
    log_likelihood,
    predict,
    solve_spd,
    update,
)
from fedtrack.local_filters.linear.models import ca_model, ca_to_cv, cv_model, cv_to_ca

R = np.array([[100.0, 5.0], [5.0, 100.0]])


def steady_state_pos_std(n_sensors: int) -> float:
    m = cv_model(1.0, 0.25)
    H = np.vstack([m.H] * n_sensors)
    RR = np.kron(np.eye(n_sensors), R)
    s = GaussianState(np.zeros(4), np.eye(4) * 1e4)
    for _ in range(300):
        s = predict(s, m.F, m.Q)
        s, _ = update(s, np.zeros(2 * n_sensors), H, RR)
    return float(np.sqrt(s.P[0, 0]))


def test_steady_state_matches_paper_table1():
    # errata: two sensors 3.96 m (Table 1 at t = 30), one sensor 5.20 m
    assert steady_state_pos_std(2) == pytest.approx(3.96, abs=0.01)
    assert steady_state_pos_std(1) == pytest.approx(5.20, abs=0.01)


def test_batched_equals_loop():
    rng = np.random.default_rng(3)
    m = ca_model(1.0, 0.5)
    B = 7
    x = rng.normal(size=(B, 6))
    A = rng.normal(size=(B, 6, 6))
    P = A @ A.transpose(0, 2, 1) + 6 * np.eye(6)
    z = rng.normal(size=(B, 2))
    batch = update(predict(GaussianState(x, P), m.F, m.Q), z, m.H, R)[0]
    for b in range(B):
        single = update(predict(GaussianState(x[b], P[b]), m.F, m.Q), z[b], m.H, R)[0]
        np.testing.assert_allclose(batch.x[b], single.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(batch.P[b], single.P, rtol=1e-12, atol=1e-12)


def test_joseph_update_equals_standard_form_and_is_symmetric():
    rng = np.random.default_rng(0)
    m = cv_model(1.0, 0.25)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    s = GaussianState(rng.normal(size=4), P)
    post, inn = update(s, rng.normal(size=2), m.H, R)
    K = P @ m.H.T @ np.linalg.inv(inn.S)
    np.testing.assert_allclose(post.P, (np.eye(4) - K @ m.H) @ P, rtol=1e-10, atol=1e-10)
    assert np.array_equal(post.P, post.P.T)


def test_log_likelihood_matches_scipy():
    from scipy.stats import multivariate_normal

    nu = np.array([1.5, -2.0])
    S = np.array([[4.0, 1.0], [1.0, 3.0]])
    expected = multivariate_normal(mean=np.zeros(2), cov=S).logpdf(nu)
    assert float(log_likelihood(Innovation(nu, S))) == pytest.approx(expected, rel=1e-12)


def test_cv_ca_round_trip():
    rng = np.random.default_rng(1)
    x = rng.normal(size=4)
    A = rng.normal(size=(4, 4))
    P = A @ A.T
    xs, Ps = cv_to_ca(x, P, np.array([3.0, 4.0]), np.eye(2) * 2.0, np.zeros((4, 2)))
    assert xs[2] == 3.0 and xs[5] == 4.0
    xb, Pb = ca_to_cv(xs, Ps)
    np.testing.assert_array_equal(xb, x)
    np.testing.assert_array_equal(Pb, P)


@pytest.mark.parametrize("m", [1, 2, 3])
@pytest.mark.parametrize("batch", [(), (7,), (3, 5)])
def test_solve_spd_equals_a_lapack_solve(m, batch):
    """The closed forms (m = 1, 2) and the fallback agree with ``np.linalg.solve`` to round-off."""
    rng = np.random.default_rng(m)
    A = rng.normal(size=batch + (m, m))
    S = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(m)
    B = rng.normal(size=batch + (m, 4))
    np.testing.assert_allclose(solve_spd(S, B), np.linalg.solve(S, B), rtol=1e-10, atol=1e-12)


def test_solve_spd_falls_back_to_lapack_on_a_singular_matrix():
    """A 2x2 with zero determinant is not divided by: LAPACK's error is raised, as before."""
    with pytest.raises(np.linalg.LinAlgError):
        solve_spd(np.ones((2, 2)), np.ones((2, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        solve_spd(np.ones((4, 2, 2)), np.ones((4, 2, 3)))


@pytest.mark.parametrize("m", [2, 3, 4])
def test_spd_inverse_logdet_equals_linalg(m: int) -> None:
    """Closed form (m <= 3) or Cholesky: the inverse and log-determinant of LAPACK, also for
    badly scaled matrices (a radar's metres and radians); a matrix that is not positive definite
    raises as Cholesky does."""
    from fedtrack.local_filters.linear.kalman import spd_inverse_logdet

    rng = np.random.default_rng(m)
    A = rng.normal(size=(50, m, m))
    scale = np.array([10.0, 0.002, 0.002, 1.0])[:m]
    S = (A @ A.swapaxes(1, 2) + np.eye(m)) * np.outer(scale, scale)
    inv, logdet = spd_inverse_logdet(S)
    np.testing.assert_allclose(inv * np.outer(scale, scale), np.linalg.inv(S) * np.outer(scale, scale),
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(S)[1], rtol=1e-12, atol=1e-9)
    S[3] = -np.eye(m)
    with pytest.raises(np.linalg.LinAlgError):
        spd_inverse_logdet(S)
