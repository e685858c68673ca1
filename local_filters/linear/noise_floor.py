"""A sensor's noise floor: the least measurement noise its class has (``[mtt.sensor.<id>] noise_floor``).

A sensor that claims a smaller ``R`` than its class can measure weighs its detections above everyone
else's in a fusion: a compromised tracker claiming ``R`` = 1 m² at the centre's predictions, a step off
them, drags every central track it shares (docs/multitarget.md, "A sensor pulling the tracks"). A centre
raises such a claim to the floor ``F = diag(floor²)`` by the least factor ``c >= 1`` with ``c R - F``
positive semi-definite, ``c = lambda_max(R^-1 F)`` (the generalized eigenvalue; the claimed shape kept):
after it the sensor weighs no more than a sensor of its class, whatever it claims.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

RAISE_TOL = 1e-9  # a claim at the floor to rounding (c <= 1 + RAISE_TOL) is left as it is


def _scaled_factors(R: np.ndarray, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R / s`` with ``s`` each ``R``'s largest variance, and ``s c`` (``c = lambda_max(R^-1 F)``): the largest
    eigenvalue of ``(L^-1 D)(L^-1 D)'``, ``L L' = R / s``, ``D = diag(floor)`` (solves, no inverse). Scaled so that
    a claim of subnormal size (``R`` = 1e-310 I, which the wire's relative check passes) cannot overflow ``c`` to
    inf and its NaN comparisons let the claim through unraised."""
    s = np.max(np.diagonal(R, axis1=-2, axis2=-1), axis=-1)
    Rs = R / s[..., None, None]
    A = np.linalg.solve(np.linalg.cholesky(Rs), np.broadcast_to(np.diag(floor), R.shape))
    return Rs, s, np.linalg.eigvalsh(A @ np.swapaxes(A, -1, -2))[..., -1]


def floor_factors(R: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``lambda_max(R^-1 F)`` of each ``R`` (K, m, m; positive definite) against ``F = diag(floor²)``
    (inf where it exceeds the floats: a claim that far below the floor)."""
    _, s, sc = _scaled_factors(R, floor)
    with np.errstate(over="ignore"):
        return sc / s


def raise_to_floor(R: np.ndarray, floor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each ``R`` (K, m, m) below the floor (``floor``: m standard deviations) scaled up to it by
    :func:`floor_factors` (``c R`` computed as ``(s c)(R / s)``: finite for any claim); returns the covariances
    and which were raised (the others unchanged). A report whose observations all claim one ``R`` (a position
    sensor's plots) is judged on it once."""
    if len(R) > 1 and bool((R == R[0]).all()):
        one, raised = _raise_one(R[0].tobytes(), floor.tobytes(), R.shape[-1], R.dtype.str, floor.dtype.str)
        return (np.repeat(one, len(R), axis=0) if raised else R), np.full(len(R), raised)
    Rs, s, sc = _scaled_factors(R, floor)
    raised = sc > s * (1.0 + RAISE_TOL)
    if not raised.any():
        return R, raised
    out = R.copy()
    out[raised] = Rs[raised] * sc[raised, None, None]
    return out, raised


@lru_cache(maxsize=256)
def _raise_one(R: bytes, floor: bytes, m: int, R_type: str, floor_type: str) -> tuple[np.ndarray, bool]:
    """:func:`raise_to_floor` of one ``R`` (its bytes, m x m, dtype ``R_type``) against ``floor`` (its bytes, dtype
    ``floor_type``), remembered (read-only): a sensor's plots claim the same ``R`` report after report, and each
    region's centre judges it."""
    one, raised = raise_to_floor(np.frombuffer(R, R_type).reshape(1, m, m), np.frombuffer(floor, floor_type))
    one.flags.writeable = False
    return one, bool(raised[0])
