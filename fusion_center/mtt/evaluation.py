"""Multi-target tracking metrics: GOSPA (with its parts), OSPA, id switches, fragmentations, RMSE, NEES.

* GOSPA with ``alpha = 2`` (Rahmathullah, García-Fernández, Svensson, "Generalized optimal
  sub-pattern assignment metric", FUSION 2017): for truth positions ``X`` (n) and track
  positions ``Y`` (m), ``GOSPA^p = min over assignments of sum d(x, y)^p + c^p / 2 (n + m - 2|A|)``
  where only pairs with ``d < c`` are assigned. It splits into ``localisation`` (the sum over
  assigned pairs), ``missed`` (``c^p / 2`` per unassigned truth) and ``false`` (``c^p / 2``
  per unassigned track): ``GOSPA = (localisation + missed + false)^(1/p)``. The parts are
  reported in that p-th power scale so that they add up.
* OSPA (Schuhmacher, Vo, Vo, "A consistent metric for performance evaluation of multi-object
  filters", IEEE TSP 2008): ``(1/max(n, m) (min sum min(d, c)^p + c^p |m - n|))^(1/p)``.
* Both assignments use ``scipy.optimize.linear_sum_assignment`` on ``min(d, c)^p``.
* Per truth, the sequence of assigned track ids gives **id switches** (the id changes from one
  assigned picture to the next assigned one) and **fragmentations** (an assigned stretch ends
  and a later one starts).
* ``--horizontal``: GOSPA, OSPA and the RMSE on x, y only (a picture on the Earth, where a radar's
  altitude is far worse than its horizontal position); the **altitude error** (RMSE and mean of
  track minus truth z over the assigned pairs, when both are 3-D) is reported on its own.
* Position RMSE over assigned pairs. **NEES** ``e' P^-1 e`` over the assigned pairs whose state
  sizes agree (a 2-D track against a 3-D truth: the truth's ``[x, vx, y, vy]``, the prefix of its
  ``[x, vx, y, vy, z, vz]``), in two parts with their degrees of freedom: the full ``state`` (4 or 6) and the
  ``position`` alone (its block of ``P``: 2 or 3); per part the mean, the fraction inside the
  two-sided 95% chi-square band of its dof (a consistent filter puts 95% of its pairs there)
  and the fraction below it (``P`` too large; the rest, above, ``P`` too small),
  and both while the truth accelerates and while it moves straight (below), where a CV filter
  errs in opposite directions (docs/multitarget.md#covariance-consistency-nees).
* **Maneuver flags** (a track with a ``maneuver`` field, or in the CA model): the fraction of
  assigned pairs flagged while the truth target accelerates by at least ``MANEUVER_ACCEL``
  (its acceleration from the velocities of the truth lines around the picture) and while it
  moves straight (below ``STRAIGHT_ACCEL`` over the last ``STRAIGHT_FOR_S`` seconds: a
  windowed detector's flag lingers for a while after a maneuver), and the number of **onsets**
  (a track flagged in a picture and not in its previous one); only when a detector ran (the
  pictures' ``detector`` is not ``"none"``; a file that does not say: when some track is
  flagged), "not applicable" (None) otherwise.
* **Registration by supporting sensors**: the track pictures grouped by their ``sensors``, per
  group how many were assigned and how many false, and the least-squares fit of the assigned
  pairs' x, y errors to ``track − truth ≈ b' + τ v + θ J p`` (:func:`fit`): a sensor with a
  constant bias ``b``, a frame rotated by a small ``θ`` about its site ``s`` or time stamps ``δ``
  late puts a target at ``p`` moving at ``v`` near ``p + b + θ J (p − s) − δ v`` (``J`` the
  rotation by 90°), so the fit gives the offset ``b' = b − θ J s`` [m], the time offset
  ``τ = −δ`` [s] and the rotation ``θ`` about the origin. Its standard errors are the least-squares
  ones from the residual scatter, lower bounds (a track's consecutive pairs are correlated).

Only confirmed tracks are evaluated unless ``all_tracks``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.linalg import qr, solve_triangular
from scipy.optimize import linear_sum_assignment
from scipy.special import chdtri

from fedtrack.fusion_center.mtt.earthmap import TRUTH_GREY, plot_map, track_colours
from fedtrack.geodetic import load_frame
from fedtrack.jsonl import InputError, check_output, is_number, output_file, picture_rows, read_jsonl
from fedtrack.local_filters.linear.kalman import nees

MANEUVER_ACCEL = 1.0  # m/s^2: a truth target accelerating at least this much is maneuvering
STRAIGHT_ACCEL = 0.01  # m/s^2: below this it moves straight at constant speed ...
STRAIGHT_FOR_S = 10.0  # s: ... when it did over this long (the detectors' windows)
#: --c, --p: c^p below 10^300 keeps the p-th power parts, sums of up to c^p per target and track, finite in
#: float64 (max 1.8e308) for up to 1e8 of them
MAX_POWER_EXPONENT = 300


class SetDistance(NamedTuple):
    gospa: float
    localisation: float
    missed: float
    false: float
    ospa: float
    pairs: list[tuple[int, int]]  # (truth index, track index) with d < c


def set_distance(truth: np.ndarray, tracks: np.ndarray, c: float, p: float) -> SetDistance:
    """GOSPA (alpha = 2) and OSPA between position sets ``truth`` (n, k) and ``tracks`` (m, k)."""
    n, m = len(truth), len(tracks)
    half = c**p / 2.0
    if n == 0 or m == 0:
        gospa_p = half * (n + m)
        return SetDistance(gospa_p ** (1 / p), 0.0, half * n, half * m, 0.0 if n == m else c, [])
    d = np.linalg.norm(truth[:, None, :] - tracks[None, :, :], axis=-1)
    cost = np.minimum(d, c) ** p
    ri, ci = linear_sum_assignment(cost)
    close = d[ri, ci] < c
    loc = float(np.sum(d[ri, ci][close] ** p))
    k = int(np.sum(close))
    missed, false = half * (n - k), half * (m - k)
    ospa = (float(np.sum(cost[ri, ci])) + c**p * abs(m - n)) / max(n, m)
    pairs = [(int(r), int(q)) for r, q, ok in zip(ri, ci, close) if ok]
    return SetDistance((loc + missed + false) ** (1 / p), loc, missed, false, ospa ** (1 / p), pairs)


def id_changes(sequence: list[int | None]) -> tuple[int, int]:
    """``(switches, fragmentations)`` of one truth's assigned-track sequence (None: unassigned)."""
    switches = fragments = 0
    last: int | None = None
    gap = False
    for tid in sequence:
        if tid is None:
            gap = last is not None
            continue
        if last is not None and tid != last:
            switches += 1
        if gap:
            fragments += 1
            gap = False
        last = tid
    return switches, fragments


def _load(path: Path, key: str) -> list[tuple[float, list[dict[str, Any]]]]:
    out = []
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        for j, item in enumerate(picture_rows(obj, key, where)):
            if not isinstance(item, dict) or "id" not in item:
                raise InputError(f"{where}: {key}[{j}] needs \"id\" and \"x\"")
            x = item.get("x")
            if not isinstance(x, list) or len(x) not in (4, 6) or not all(is_number(v) for v in x):
                raise InputError(f"{where}: {key}[{j}].x must be a state [x, vx, y, vy] or [x, vx, y, vy, z, vz] "
                                 f"of finite numbers")
            P = item.get("P")
            if P is not None and (not isinstance(P, list) or len(P) != len(x)
                                  or not all(isinstance(r, list) and len(r) == len(x) and all(is_number(v) for v in r)
                                             for r in P)):
                raise InputError(f"{where}: {key}[{j}].P must be a {len(x)}x{len(x)} matrix of finite numbers, "
                                 "like x")
        out.append((float(obj["t"]), obj[key]))
    return out


def file_head(path: Path) -> dict[str, Any]:
    """The replay's ``algorithm`` and ``detector`` as the first picture of a tracks file gives them
    (absent from files other tools wrote)."""
    for _, obj in read_jsonl(path):
        return {key: obj[key] for key in ("algorithm", "detector") if isinstance(obj.get(key), str)}
    return {}


def _positions(x: list[float]) -> np.ndarray:
    return np.asarray(x, float)[0::2][: len(x) // 2]


def _stack(states: list[list[float]]) -> np.ndarray:
    """Positions (n, k) of states; (0, 3) when there are none."""
    return np.array([_positions(x) for x in states]) if states else np.zeros((0, 3))


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


def evaluate(tracks_path: Path, truth_path: Path, c: float = 100.0, p: float = 2.0,
             all_tracks: bool = False, horizontal: bool = False) -> dict[str, Any]:
    """Every metric of the module docstring over the pictures that have a truth line at their time
    (``horizontal``: positions are x, y only; the altitude error is reported on its own either way)."""
    truth_lines = _load(truth_path, "targets")
    head = file_head(tracks_path)
    truth = {round(t, 6): items for t, items in truth_lines}
    motion = truth_motion(truth_lines)
    flags = {"maneuvering": [0, 0], "straight": [0, 0]}  # [pairs, flagged]
    was_flagged: dict[Any, bool] = {}
    onsets = 0
    series: list[dict[str, float]] = []
    sequences: dict[Any, list[int | None]] = {}
    sq_err: list[float] = []
    errors: list[np.ndarray] = []
    covariances: list[np.ndarray] = []
    motions: list[str | None] = []
    alt_err: list[float] = []
    by_sensors: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}  # a track's sensors -> (truth, track) states
    unassigned: dict[str, int] = {}  # a track's sensors -> its pictures assigned to no truth (false)
    skipped = 0
    for t, items in _load(tracks_path, "tracks"):
        targets = truth.get(round(t, 6))
        if targets is None:
            skipped += 1
            continue
        shown = [tr for tr in items if all_tracks or tr.get("status", "confirmed") == "confirmed"]
        for tr in shown:
            now = flagged(tr)
            onsets += now and not was_flagged.get(tr["id"], False)
            was_flagged[tr["id"]] = now
        X, Y = _stack([g["x"] for g in targets]), _stack([tr["x"] for tr in shown])
        k = 2 if horizontal else min(X.shape[1], Y.shape[1])
        dist = set_distance(X[:, :k], Y[:, :k], c, p)
        series.append({"t": t, "gospa": dist.gospa, "localisation": dist.localisation, "missed": dist.missed,
                       "false": dist.false, "ospa": dist.ospa, "truths": len(X), "tracks": len(Y)})
        assigned = dict(dist.pairs)
        for j in set(range(len(shown))) - set(assigned.values()):
            group = ",".join(shown[j].get("sensors", [])) or "-"
            unassigned[group] = unassigned.get(group, 0) + 1
        for i, g in enumerate(targets):
            j = assigned.get(i)
            sequences.setdefault(g["id"], []).append(None if j is None else shown[j]["id"])
            if j is None:
                continue
            sq_err.append(float(np.sum((X[i, :k] - Y[j, :k]) ** 2)))
            if X.shape[1] > 2 and Y.shape[1] > 2:
                alt_err.append(float(Y[j, 2] - X[i, 2]))
            kind = motion.get((round(t, 6), g["id"]))
            if kind in flags:
                flags[kind][0] += 1
                flags[kind][1] += flagged(shown[j])
            xt, xe = np.asarray(g["x"], float), np.asarray(shown[j]["x"], float)
            by_sensors.setdefault(",".join(shown[j].get("sensors", [])) or "-", []).append((xt[:4], xe[:4]))
            if xe.size == 4 and xt.size == 6:  # a 2-D tracker against a 3-D truth: its horizontal state
                xt = xt[:4]
            if "P" in shown[j] and xt.shape == xe.shape:
                P = np.asarray(shown[j]["P"], float)
                try:
                    np.linalg.cholesky(P)
                except np.linalg.LinAlgError:
                    raise InputError(f"{tracks_path}: the picture at t = {t:g}: track {shown[j]['id']}'s P is "
                                     "not positive definite (a covariance must be)") from None
                errors.append(xt - xe)
                covariances.append(P)
                motions.append(kind)
    if not series:
        raise InputError(f"{tracks_path}: no picture has a truth line at its time in {truth_path}")
    switches = fragments = 0
    for seq in sequences.values():
        s, f = id_changes(seq)
        switches, fragments = switches + s, fragments + f
    detector = head.get("detector")
    applicable = detector != "none" if detector is not None else any(was_flagged.values())
    mean = {key: float(np.mean([row[key] for row in series])) for key in ("gospa", "localisation", "missed",
                                                                          "false", "ospa")}
    return {
        "algorithm": head.get("algorithm"),
        "c": c, "p": p, "alpha": 2, "pictures": len(series), "pictures_without_truth": skipped,
        "mean": mean, "id_switches": switches, "fragmentations": fragments,
        "position_rmse": math.sqrt(float(np.mean(sq_err))) if sq_err else None, "horizontal": horizontal,
        "altitude_rmse": math.sqrt(float(np.mean(np.square(alt_err)))) if alt_err else None,
        "altitude_bias": float(np.mean(alt_err)) if alt_err else None,
        "nees": nees_parts(errors, covariances, motions),
        "registration": registration(by_sensors, unassigned),
        "maneuvers": {"detector": detector, "applicable": applicable, "onsets": onsets if applicable else None,
                      "maneuver_accel": MANEUVER_ACCEL, "straight_accel": STRAIGHT_ACCEL,
                      "straight_for_s": STRAIGHT_FOR_S,
                      **{f"{kind}_pairs": n for kind, (n, _) in flags.items()},
                      **{f"flagged_while_{kind}": hit / n if n and applicable else None
                         for kind, (n, hit) in flags.items()}},
        "series": series,
    }


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


def check_figure_format(out: Path) -> None:
    """An InputError naming ``out`` unless matplotlib writes its suffix's format (none: PNG)."""
    from matplotlib.figure import Figure

    formats = Figure().canvas.get_supported_filetypes()
    if out.suffix and out.suffix[1:].lower() not in formats:
        raise InputError(f"{out}: --plot writes a figure; its suffix {out.suffix!r} is not a format matplotlib "
                         f"writes (use one of {', '.join('.' + f for f in sorted(formats))})")


def plot(result: dict[str, Any], tracks_path: Path, truth_path: Path, out: Path,
         events: dict[str, float] | None = None, label: str | None = None) -> None:
    """Tracks over truth (x-y), where their maneuvers were flagged, and GOSPA with its parts over
    time, with ``events`` (label -> time, such as a sensor joining) marked; the title names the
    algorithm (``label``, else the file's) and the tracks file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 6))
    fig.suptitle(f"{label or result.get('algorithm') or 'algorithm not recorded (--label)'}: {tracks_path.name}")
    colours = track_colours()
    paths: dict[Any, list[np.ndarray]] = {}
    maneuvering: list[np.ndarray] = []
    for _, targets in _load(truth_path, "targets"):
        for g in targets:
            paths.setdefault(("truth", g["id"]), []).append(_positions(g["x"])[:2])
    for _, items in _load(tracks_path, "tracks"):
        for tr in items:
            if tr.get("status", "confirmed") == "confirmed":
                paths.setdefault(("track", tr["id"]), []).append(_positions(tr["x"])[:2])
                if flagged(tr):
                    maneuvering.append(_positions(tr["x"])[:2])
    n_tracks = 0
    for (kind, _), pts in paths.items():
        a = np.array(pts)
        if kind == "truth":
            ax1.plot(a[:, 0], a[:, 1], color=TRUTH_GREY, lw=2.5, zorder=1)
        else:
            ax1.plot(a[:, 0], a[:, 1], color=colours[n_tracks % len(colours)], lw=1.0, zorder=2)
            n_tracks += 1
    if maneuvering:
        m = np.array(maneuvering)
        ax1.scatter(m[:, 0], m[:, 1], s=9, c="red", marker="x", lw=0.8, zorder=3, label="maneuver flagged")
        ax1.legend(loc="upper right", fontsize=8)
    ax1.set_title("confirmed tracks (colours) over truth (grey)")
    ax1.set_xlabel("x [m]")
    ax1.set_ylabel("y [m]")
    ax1.set_aspect("equal", adjustable="datalim")
    t = [r["t"] for r in result["series"]]
    p = result["p"]
    ax2.plot(t, [r["gospa"] for r in result["series"]], "k-", lw=1.5, label="GOSPA")
    for key, style in (("localisation", "b--"), ("missed", "r:"), ("false", "g-.")):
        ax2.plot(t, [r[key] ** (1 / p) for r in result["series"]], style, lw=1.0, label=f"{key} (p-th root)")
    for label, when in (events or {}).items():
        ax2.axvline(when, color="0.4", lw=1.0, ls="--")
        ax2.annotate(label, (when, 0.97), xycoords=("data", "axes fraction"), rotation=90, ha="right", va="top",
                     fontsize=8, color="0.3")
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("[m]")
    ax2.set_title(f"GOSPA (c = {result['c']:g} m, p = {p:g}, alpha = 2): mean {result['mean']['gospa']:.1f} m")
    ax2.legend()
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    with output_file(out, "wb") as fh:
        fig.savefig(fh, dpi=110, format=out.suffix[1:].lower() or "png")
    plt.close(fig)


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


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack evaluate", description="GOSPA, OSPA, id switches, "
                                     "fragmentations, RMSE, NEES and maneuver flags of a track picture file against "
                                     "truth")
    parser.add_argument("--tracks", required=True, type=Path, metavar="T.jsonl",
                        help="track pictures ({\"t\", \"tracks\": [...]} a line, as replay --algorithm mtt-* writes)")
    parser.add_argument("--truth", required=True, type=Path, metavar="U.jsonl",
                        help="truth ({\"t\", \"targets\": [...]} a line, as simulate multitarget writes)")
    parser.add_argument("--c", type=float, default=100.0, help="cut-off distance [m] (default: %(default)s)")
    parser.add_argument("--p", type=float, default=2.0, help="order (default: %(default)s)")
    parser.add_argument("--alpha", type=float, default=2.0, help="GOSPA alpha; only 2 is supported "
                        "(default: %(default)s)")
    parser.add_argument("--all-tracks", action="store_true", help="evaluate tentative tracks too "
                        "(default: confirmed tracks only)")
    parser.add_argument("--horizontal", action="store_true", help="GOSPA, OSPA and RMSE on x, y only (the "
                        "altitude error is reported on its own either way; default: every axis the states share)")
    parser.add_argument("--json", type=Path, metavar="OUT.json",
                        help="write the full result (with the per-picture series; default: none)")
    parser.add_argument("--plot", type=Path, metavar="OUT.png",
                        help="PNG: tracks over truth and GOSPA over time (default: no plot)")
    parser.add_argument("--config", type=Path, metavar="C.toml", help="with --plot: a config whose [frame] puts the "
                        "tracks on the Earth; the map (longitude / latitude, sensor sites marked) goes to PLOT's "
                        "name + -map.png (default: none, no map)")
    parser.add_argument("--label", help="the plot title's algorithm (default: the tracks file's \"algorithm\")")
    args = parser.parse_args(argv)
    if args.alpha != 2:
        parser.error("--alpha: only alpha = 2 (the decomposable GOSPA) is supported")
    if not (0 < args.c < math.inf and 1 <= args.p < math.inf):
        parser.error("--c must be finite and > 0, --p finite and >= 1")
    if args.p * math.log10(args.c) >= MAX_POWER_EXPONENT:
        parser.error(f"--c {args.c:g} --p {args.p:g}: c^p overflows (the p-th power parts are sums of up to c^p a "
                     f"target or track): need p log10(c) < {MAX_POWER_EXPONENT}")
    for path in (args.json, args.plot):
        if path is not None:
            check_output(path)
    if args.plot is not None:
        check_figure_format(args.plot)
    if args.config is not None and args.plot is None:
        parser.error("--config applies with --plot (its [frame] draws the map beside the figure)")
    frame = load_frame(args.config)  # before the evaluation: a bad config fails at start
    result = evaluate(args.tracks, args.truth, args.c, args.p, args.all_tracks, args.horizontal)
    map_png = args.plot.with_name(args.plot.stem + "-map.png") if frame is not None else None
    if args.json:  # the files first: a reader that stops early (| head) does not cost them
        with output_file(args.json) as fh:
            fh.write(json.dumps(result))
    if args.plot:
        plot(result, args.tracks, args.truth, args.plot, label=args.label)
    if map_png is not None:
        plot_map(args.tracks, args.truth, frame, map_png, label=args.label or result["algorithm"])
    m = result["mean"]
    print(f"pictures {result['pictures']} (without truth: {result['pictures_without_truth']})"
          + (f" of {result['algorithm']}" if result["algorithm"] else ""))
    print(f"mean GOSPA {m['gospa']:.2f} m (c = {args.c:g}, p = {args.p:g}, alpha = 2"
          f"{', x-y' if args.horizontal else ''}): localisation "
          f"{m['localisation']:.1f}, missed {m['missed']:.1f}, false {m['false']:.1f} (p-th power parts)")
    print(f"mean OSPA {m['ospa']:.2f} m; id switches {result['id_switches']}; fragmentations "
          f"{result['fragmentations']}")
    rmse = result["position_rmse"]
    print(f"position RMSE {rmse:.2f} m" if rmse is not None else "position RMSE -")
    for row in result["nees"]:
        print(nees_line(row))
    if not result["nees"]:
        print("NEES -: no assigned pair with a covariance and the truth's state size")
    if result["altitude_rmse"] is not None:
        print(f"altitude error over the assigned pairs: RMSE {result['altitude_rmse']:.2f} m, mean "
              f"{result['altitude_bias']:+.2f} m (track - truth)")
    if result["registration"]:
        print("by supporting sensors: track pictures assigned and false; registration (track - truth = offset + "
              "time offset x velocity + rotation about the origin, least squares over the assigned pairs; "
              "docs/multitarget.md#registration-errors-untuned6-session):")
        for sensors, reg in result["registration"].items():
            print(registration_line(sensors, reg))
    man = result["maneuvers"]
    if not man["applicable"]:
        print("maneuver flags: not applicable (no maneuver detector ran: the pictures' detector is "
              f"{man['detector'] or 'not given and no track is flagged'})")
    else:
        rate = {k: "-" if man[f"flagged_while_{k}"] is None else f"{100 * man[f'flagged_while_{k}']:.1f}%"
                for k in ("maneuvering", "straight")}
        print(f"maneuver flags: {rate['maneuvering']} of {man['maneuvering_pairs']} assigned pairs while the target "
              f"accelerates (>= {MANEUVER_ACCEL:g} m/s^2), {rate['straight']} of {man['straight_pairs']} while it "
              f"moves straight (< {STRAIGHT_ACCEL:g} m/s^2 for {STRAIGHT_FOR_S:g} s); {man['onsets']} onsets")
    for path in (args.json, args.plot, map_png):
        if path is not None:
            print(f"wrote {path}")
    return 0
