"""Covariance consistency and maneuver flags: the truth's motion per picture (accelerating or
straight), the NEES of assigned pairs in parts with their chi-square bands, a track's maneuver flag."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import chdtri

from fedtrack.local_filters.linear.kalman import nees

MANEUVER_ACCEL = 1.0  # m/s^2: a truth target accelerating at least this much is maneuvering
STRAIGHT_ACCEL = 0.01  # m/s^2: below this it moves straight at constant speed ...
STRAIGHT_FOR_S = 10.0  # s: ... when it did over this long (the detectors' windows)


def truth_motion(lines: list[tuple[float, list[dict[str, Any]]]]) -> dict[tuple[float, Any], str]:
    """``(t, id) -> "maneuvering" | "straight" | "between"``: ``|a|`` (m/s^2, horizontal) from the
    truth velocities of the lines before and after ``t`` (central difference; not at the first
    and last line of a target) at least ``MANEUVER_ACCEL``, or below ``STRAIGHT_ACCEL`` at
    every line of the last ``STRAIGHT_FOR_S`` seconds."""
    accel: dict[Any, list[tuple[float, float]]] = {}
    for (t0, before), (t1, _), (t2, after) in zip(lines, lines[1:], lines[2:]):
        v0 = {g["id"]: g["x"] for g in before}
        for g in after:
            if g["id"] in v0 and len(g["x"]) >= 4:
                dv = np.asarray(g["x"], float)[[1, 3]] - np.asarray(v0[g["id"]], float)[[1, 3]]
                accel.setdefault(g["id"], []).append((round(t1, 6), float(np.hypot(*dv)) / (t2 - t0)))
    out: dict[tuple[float, Any], str] = {}
    for tid, series in accel.items():
        last_turn = -math.inf  # the last time the target accelerated
        for t, a in series:
            if a >= STRAIGHT_ACCEL:
                last_turn = t
            out[(t, tid)] = ("maneuvering" if a >= MANEUVER_ACCEL else "straight"
                             if t - last_turn >= STRAIGHT_FOR_S and t - series[0][0] >= STRAIGHT_FOR_S
                             else "between")
    return out


def nees_parts(errors: list[np.ndarray], covariances: list[np.ndarray], motions: list[str | None]
               ) -> list[dict[str, Any]]:
    """NEES of the pairs (``errors`` truth minus estimate, ``covariances`` the estimate's ``P``),
    per part (``state``, ``position``) and state size: pairs, dof, mean, the two-sided 95%
    chi-square band and the fractions inside it and below it (``P`` larger than the error; the
    rest is above: ``P`` too small), overall and per truth motion."""
    out = []
    for dim in sorted({e.size for e in errors}):
        idx = [k for k, e in enumerate(errors) if e.size == dim]
        e, P = np.array([errors[k] for k in idx]), np.array([covariances[k] for k in idx])
        kinds = np.array([motions[k] for k in idx], dtype=object)
        pos = np.arange(0, dim, 2)
        for part, sel in (("state", np.arange(dim)), ("position", pos)):
            v = nees(e[:, sel], P[:, sel[:, None], sel[None, :]])
            lo, hi = float(chdtri(sel.size, 0.975)), float(chdtri(sel.size, 0.025))
            inside, below = (v >= lo) & (v <= hi), v < lo
            row: dict[str, Any] = {"part": part, "dof": int(sel.size), "pairs": int(v.size), "mean": float(v.mean()),
                                   "band_95": [lo, hi], "inside_95": float(inside.mean()),
                                   "below_95": float(below.mean())}
            for kind in ("maneuvering", "straight"):
                m = kinds == kind
                row[kind] = {"pairs": int(m.sum()), "mean": float(v[m].mean()) if m.any() else None,
                             "inside_95": float(inside[m].mean()) if m.any() else None,
                             "below_95": float(below[m].mean()) if m.any() else None}
            out.append(row)
    return out


def flagged(track: dict[str, Any]) -> bool:
    """A track whose maneuver is detected: a central track's ``maneuver``, or a track in CA."""
    return "maneuver" in track or track.get("model") == "ca"


def nees_line(row: dict[str, Any]) -> str:
    """One line of a :func:`nees_parts` row: dof, mean, the fractions inside the 95% band and on
    either side of it, and both while the truth accelerates and while it moves straight."""
    names = {("state", 4): "x, vx, y, vy", ("state", 6): "x, vx, y, vy, z, vz", ("position", 2): "x, y",
             ("position", 3): "x, y, z"}
    lo, hi = row["band_95"]
    by = "; ".join(f"{label} {row[k]['mean']:.2f}, {100 * row[k]['inside_95']:.1f}% of {row[k]['pairs']} "
                   f"({100 * row[k]['below_95']:.1f}% below)"
                   for k, label in (("maneuvering", "while accelerating"), ("straight", "straight"))
                   if row[k]["pairs"])
    above = 1.0 - row["inside_95"] - row["below_95"]
    return (f"NEES {row['part']} ({names.get((row['part'], row['dof']), row['part'])}; {row['dof']} dof): mean "
            f"{row['mean']:.2f} (consistent: {row['dof']}), {100 * row['inside_95']:.1f}% of {row['pairs']} "
            f"assigned pairs inside the 95% band [{lo:.2f}, {hi:.2f}] (consistent: 95%; below it "
            f"{100 * row['below_95']:.1f}%: P too large, above {100 * above:.1f}%: P too small)"
            + (f"; {by}" if by else ""))
