"""Linear Kalman filter as pure functions over immutable, batchable state records.

Every function accepts arrays with any number of leading batch axes (Monte Carlo
runs, targets, candidate hypotheses): ``x`` is ``(..., n)`` and ``P`` is
``(..., n, n)``. Matrices that do not vary over the batch (``F``, ``Q``, ``H``,
``R``) may be passed unbatched and broadcast. No inverses are formed: gains and
quadratic forms use linear solves or Cholesky factors.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

LOG_2PI = float(np.log(2.0 * np.pi))


class GaussianState(NamedTuple):
    """Mean ``x`` (..., n) and covariance ``P`` (..., n, n)."""

    x: np.ndarray
    P: np.ndarray


class Innovation(NamedTuple):
    """Innovation ``nu = z - H x_pred`` (..., m) and its covariance ``S`` (..., m, m)."""

    nu: np.ndarray
    S: np.ndarray


def logsumexp(a: np.ndarray, axis: int = -1, keepdims: bool = False) -> np.ndarray:
    """``log sum exp a`` along ``axis``, stable (a third of scipy's cost for small arrays); all ``-inf`` gives ``-inf``."""
    if a.shape[axis] == 0:
        out = np.full(np.sum(a, axis=axis, keepdims=True).shape, -np.inf)
        return out if keepdims else np.squeeze(out, axis=axis)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return out if keepdims else np.squeeze(out, axis=axis)


_HALF = np.array(0.5)  # a 0-d array multiplies a 4x4 in 0.5 us, the Python float in 0.7 us


def symmetrize(P: np.ndarray) -> np.ndarray:
    """``(P + P')/2`` over the last two axes.

    The transpose is copied first: adding a transposed 4x4 view takes 1.3 us, the copy and a
    contiguous add 0.9 us (the method, not ``np.swapaxes``, whose wrapper costs 3x more).
    """
    return _HALF * (P + P.swapaxes(-1, -2).copy())


def mat_vec(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``A v`` broadcast over leading axes (a plain product when neither is batched)."""
    if A.ndim == 2:
        return A.dot(v) if v.ndim == 1 else v.dot(A.T)
    if A.shape[-1] > 3:
        return np.matmul(A, v[..., None])[..., 0]
    out = A[..., 0] * v[..., :1]  # a short row: a sum of scaled columns (a third of matmul's time)
    for j in range(1, A.shape[-1]):
        out += A[..., j] * v[..., j:j + 1]
    return out


def batched_product(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``X Y`` over leading axes, fast for stacks of small matrices.

    A constant (2-D) factor folds the stack into one BLAS product (10,000 4x4 products by a
    constant: 0.14 ms instead of 0.8 ms); two stacks go to ``np.matmul`` (numpy 2.4: 1,000
    products 4x2 by 2x4 in 52 us, where summing outer products took 125 us).
    """
    if Y.ndim == 2:
        if X.ndim == 2:
            return X.dot(Y)
        return X.reshape(-1, X.shape[-1]).dot(Y).reshape(X.shape[:-1] + Y.shape[-1:])
    if X.ndim == 2:  # C Y = (Y' C')'
        return batched_product(Y.swapaxes(-1, -2), X.T).swapaxes(-1, -2)
    return np.matmul(X, Y)


def transpose(A: np.ndarray) -> np.ndarray:
    return A.swapaxes(-1, -2)


def predict(state: GaussianState, F: np.ndarray, Q: np.ndarray,
            u_effect: np.ndarray | None = None) -> GaussianState:
    """Time update: ``x = F x (+ B u)``, ``P = F P F' + Q`` (paper 004 eqs. (5), (7))."""
    mm = np.ndarray.dot if F.ndim == 2 and state.P.ndim == 2 else batched_product
    x = mat_vec(F, state.x)
    if u_effect is not None:
        x = x + u_effect
    P = mm(mm(F, state.P), F.swapaxes(-1, -2)) + Q
    return GaussianState(x, symmetrize(P))


def innovation_covariance(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``S = H P H' + R``, symmetric."""
    return symmetrize(np.matmul(np.matmul(H, P), transpose(H)) + R)


def innovation(state: GaussianState, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> Innovation:
    """``nu = z - H x``, ``S = H P H' + R``."""
    return Innovation(z - mat_vec(H, state.x), innovation_covariance(state.P, H, R))


class KalmanUpdate(NamedTuple):
    """Posterior, the innovation it used and the gain ``K`` (..., n, m)."""

    state: GaussianState
    innovation: Innovation
    gain: np.ndarray


def solve_spd(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``S^-1 B`` for symmetric positive definite ``S`` (..., m, m) and ``B`` (..., m, k).

    For m <= 3 by the adjugate over the determinant (Cramer's rule; a LAPACK solve costs 6 us
    on one small matrix, the closed form 1.5-3 us, in Python floats when ``S`` is one matrix);
    a solve for larger m, and wherever a determinant is not positive.
    """
    m = S.shape[-1]
    if m == 2 and S.ndim == 2:  # the commonest case first: one 2-D position measurement
        (a, b), (_, d) = S.tolist()
        det = a * d - b * b
        if det > 0.0:
            r = 1.0 / det
            return np.array([[d * r, -b * r], [-b * r, a * r]]).dot(B)
    if m == 1:
        return B / S
    if m > 3:
        return np.linalg.solve(S, B)
    one = S.ndim == 2
    e = S.tolist() if one else [[S[..., i, j] for j in range(m)] for i in range(m)]
    adj, det = _symmetric_adjugate(e)
    if not (det > 0.0 if one else np.all(det > 0.0)):
        return np.linalg.solve(S, B)
    r = 1.0 / det
    inv = [[c * r for c in row] for row in adj]
    if one:
        return np.array(inv).dot(B)
    out = np.empty(np.broadcast_shapes(S.shape[:-2], B.shape[:-2]) + B.shape[-2:])
    for i in range(m):  # row i of S^-1 B, elementwise over the stack
        out[..., i, :] = inv[i][0][..., None] * B[..., 0, :]
        for j in range(1, m):
            out[..., i, :] += inv[i][j][..., None] * B[..., j, :]
    return out


def spd_inverse_logdet(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``S^-1`` and ``ln det S`` of a stack of symmetric positive definite matrices (N, m, m).

    For m of 2 or 3 by the adjugate over the determinant (1,000 2 x 2: 18 us against 350 us for
    a Cholesky factorization and its inverse); by Cholesky for larger m or where a leading minor
    is not positive (which then raises ``LinAlgError``, as it should).
    """
    m = S.shape[-1]
    if 2 <= m <= 3:
        adj, det = _symmetric_adjugate([[S[..., i, j] for j in range(m)] for i in range(m)])
        minors = [S[..., 0, 0], det] if m == 2 else [S[..., 0, 0], adj[2][2], det]  # Sylvester's criterion
        if all(np.all(minor > 0.0) for minor in minors):
            inv = np.stack([np.stack(row, axis=-1) for row in adj], axis=-2) / det[..., None, None]
            return inv, np.log(det)
    L = np.linalg.cholesky(S)
    L_inv = np.linalg.solve(L, np.broadcast_to(np.eye(m), S.shape))
    return np.matmul(transpose(L_inv), L_inv), 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)


def _symmetric_adjugate(e: list) -> tuple[list, object]:
    """Adjugate and determinant of a symmetric 2x2 or 3x3 matrix given by its entries (floats or arrays)."""
    if len(e) == 2:
        (a, b), (_, d) = e
        return [[d, -b], [-b, a]], a * d - b * b
    (a, b, c), (_, d, f), (_, _, g) = e
    A11, A12, A13 = d * g - f * f, c * f - b * g, b * f - c * d
    A22, A23, A33 = a * g - c * c, b * c - a * f, a * d - b * b
    return [[A11, A12, A13], [A12, A22, A23], [A13, A23, A33]], a * A11 + b * A12 + c * A13


def update_residual(state: GaussianState, nu: np.ndarray, H: np.ndarray, R: np.ndarray) -> KalmanUpdate:
    """Measurement update in Joseph form given the innovation ``nu`` (``z - h(x)`` for an EKF).

    ``S = H P H' + R``, ``K = P H' S^-1`` (``K' = S^-1 H P``, P and S symmetric),
    ``x+ = x + K nu``, ``P+ = (I - K H) P (I - K H)' + K R K'``.
    """
    P = state.P
    mm = np.ndarray.dot if P.ndim == 2 and H.ndim == 2 and R.ndim == 2 else batched_product
    HP = mm(H, P)
    S = symmetrize(mm(HP, H.swapaxes(-1, -2)) + R)
    K = solve_spd(S, HP).swapaxes(-1, -2)
    x = state.x + mat_vec(K, nu)
    A = _identity(P.shape[-1]) - mm(K, H)
    P = mm(mm(A, P), A.swapaxes(-1, -2)) + mm(mm(K, R), K.swapaxes(-1, -2))
    return KalmanUpdate(GaussianState(x, symmetrize(P)), Innovation(nu, S), K)


def update(state: GaussianState, z: np.ndarray, H: np.ndarray,
           R: np.ndarray) -> tuple[GaussianState, Innovation]:
    """Measurement update in Joseph form (:func:`update_residual` with ``nu = z - H x``).

    Returns the posterior and the innovation it used.
    """
    post = update_residual(state, z - mat_vec(H, state.x), H, R)
    return post.state, post.innovation


@lru_cache(maxsize=16)
def _identity(n: int) -> np.ndarray:
    eye = np.eye(n)
    eye.setflags(write=False)
    return eye


def log_likelihood(inn: Innovation) -> np.ndarray:
    """``log N(nu; 0, S)`` via a Cholesky factor (log space, no inverse)."""
    L = np.linalg.cholesky(inn.S)
    w = np.linalg.solve(L, inn.nu[..., None])[..., 0]
    m = inn.nu.shape[-1]
    log_det = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * (np.sum(w * w, axis=-1) + log_det + m * LOG_2PI)


def normalized_innovation_squared(inn: Innovation) -> np.ndarray:
    """``nu' S^-1 nu``."""
    return np.einsum("...i,...i->...", inn.nu, np.linalg.solve(inn.S, inn.nu[..., None])[..., 0])


def nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared ``e' P^-1 e``."""
    return np.einsum("...i,...i->...", err, np.linalg.solve(P, err[..., None])[..., 0])


def information(state: GaussianState) -> tuple[np.ndarray, np.ndarray]:
    """Information matrix ``Y = P^-1`` and vector ``y = P^-1 x`` (by solves with ``P``)."""
    n = state.P.shape[-1]
    eye = np.broadcast_to(np.eye(n), state.P.shape)
    Y = np.linalg.solve(state.P, eye)
    y = np.linalg.solve(state.P, state.x[..., None])[..., 0]
    return symmetrize(Y), y


def from_information(Y: np.ndarray, y: np.ndarray) -> GaussianState:
    """Inverse of :func:`information`: ``P = Y^-1``, ``x = P y``."""
    n = Y.shape[-1]
    P = symmetrize(np.linalg.solve(Y, np.broadcast_to(np.eye(n), Y.shape)))
    x = np.linalg.solve(Y, y[..., None])[..., 0]
    return GaussianState(x, P)
