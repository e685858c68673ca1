"""Registration by supporting sensors: per group of track pictures with the same ``sensors``,
the least-squares fit of the assigned pairs' errors to an offset, a time offset and a rotation
(:mod:`fedtrack.fusion_center.mtt.evaluation`'s docstring gives the model)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from scipy.linalg import qr, solve_triangular

MIN_PAIRS = 20  # a group of fewer assigned pairs than this (5 per parameter of the registration fit) is not fitted


class Registration(NamedTuple):
    """One group's fit: the estimates and their standard errors (``b'`` x, y [m], ``τ`` [s], ``θ`` [rad])."""

    pairs: int
    estimate: np.ndarray  # (4,) b'x, b'y, tau, theta
    std_error: np.ndarray  # (4,)


def design(truth: np.ndarray) -> np.ndarray:
    """The rows of the model for truth states ``[x, vx, y, vy, ...]`` (n, >= 4): (2 n, 4), x rows
    then y rows interleaved per pair."""
    n = truth.shape[0]
    A = np.zeros((n, 2, 4))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[:, 0, 2], A[:, 1, 2] = truth[:, 1], truth[:, 3]
    A[:, 0, 3], A[:, 1, 3] = -truth[:, 2], truth[:, 0]
    return A.reshape(2 * n, 4)


def fit(truth: np.ndarray, error: np.ndarray) -> Registration | None:
    """The least-squares fit of ``error`` (n, 2: track − truth in x, y) to :func:`design` of
    ``truth``; None for fewer than :data:`MIN_PAIRS` pairs or a degenerate design (every target
    at one velocity or one place)."""
    n = truth.shape[0]
    if n < MIN_PAIRS:
        return None
    A, y = design(truth), error.reshape(2 * n)
    Q, R = qr(A, mode="economic")
    if np.min(np.abs(np.diag(R))) <= 1e-9 * np.max(np.abs(np.diag(R))):
        return None
    beta = solve_triangular(R, Q.T @ y)
    resid = y - A @ beta
    sigma2 = float(resid @ resid) / max(2 * n - 4, 1)
    Rinv = solve_triangular(R, np.eye(4))
    return Registration(n, beta, np.sqrt(sigma2 * np.sum(Rinv ** 2, axis=1)))


def registration_line(sensors: str, row: dict[str, Any]) -> str:
    """One group of ``evaluate``'s ``registration`` as ``evaluate`` prints it."""
    head = f"  {sensors}: {row['pairs']} assigned, {row['false']} false"
    if "offset" not in row:
        return head + " (not fitted: too few pairs or one geometry)"
    (bx, by), (sx, sy) = row["offset"], row["offset_se"]
    return (head + f"; offset ({bx:+.1f} ± {sx:.1f}, {by:+.1f} ± {sy:.1f}) m, time {row['time_offset']:+.3f} ± "
            f"{row['time_offset_se']:.3f} s, rotation {row['rotation_deg']:+.3f} ± {row['rotation_deg_se']:.3f} deg")


def registration(by_sensors: dict[str, list[tuple[np.ndarray, np.ndarray]]],
                 unassigned: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Per group of supporting sensors (most track pictures first): its ``pairs`` (assigned) and
    ``false`` track pictures, and with enough pairs the fit of :mod:`.registration`: ``offset``
    [m], ``time_offset`` [s], ``rotation_deg`` and their ``*_se``."""
    out: dict[str, dict[str, Any]] = {}
    groups = set(by_sensors) | set(unassigned)
    for sensors in sorted(groups, key=lambda g: (-len(by_sensors.get(g, ())) - unassigned.get(g, 0), g)):
        pairs = by_sensors.get(sensors, [])
        row: dict[str, Any] = {"pairs": len(pairs), "false": unassigned.get(sensors, 0)}
        if pairs:
            truth = np.array([xt for xt, _ in pairs])
            track = np.array([xe for _, xe in pairs])
            reg = fit(truth, track[:, [0, 2]] - truth[:, [0, 2]])
            if reg is not None:
                (bx, by, tau, th), (sx, sy, st, sth) = reg.estimate, reg.std_error
                row.update({"offset": [bx, by], "offset_se": [sx, sy], "time_offset": tau, "time_offset_se": st,
                            "rotation_deg": math.degrees(th), "rotation_deg_se": math.degrees(sth)})
        out[sensors] = row
    return out
