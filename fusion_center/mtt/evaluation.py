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
* Position RMSE over assigned pairs; NEES of the full state over assigned pairs whose state
  sizes agree, its mean and the fraction inside the two-sided 95% chi-square band.
* **Maneuver flags** (a track with a ``maneuver`` field, or in the CA model): the fraction of
  assigned pairs flagged while the truth target accelerates by at least ``MANEUVER_ACCEL``
  (its acceleration from the velocities of the truth lines around the picture) and while it
  moves straight (below ``STRAIGHT_ACCEL`` over the last ``STRAIGHT_FOR_S`` seconds: a
  windowed detector's flag lingers for a while after a maneuver), and the number of **onsets**
  (a track flagged in a picture and not in its previous one).

Only confirmed tracks are evaluated unless ``all_tracks``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.special import chdtri

from fedtrack.fusion_center.mtt.earthmap import plot_map
from fedtrack.geodetic import load_frame
from fedtrack.jsonl import InputError, read_jsonl

MANEUVER_ACCEL = 1.0  # m/s^2: a truth target accelerating at least this much is maneuvering
STRAIGHT_ACCEL = 0.01  # m/s^2: below this it moves straight at constant speed ...
STRAIGHT_FOR_S = 10.0  # s: ... when it did over this long (the detectors' windows)


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
        if not isinstance(obj.get("t"), (int, float)) or not isinstance(obj.get(key), list):
            raise InputError(f"{where}: expected {{\"t\": number, \"{key}\": [...]}}")
        for j, item in enumerate(obj[key]):
            if not isinstance(item, dict) or not isinstance(item.get("x"), list) or "id" not in item:
                raise InputError(f"{where}: {key}[{j}] needs \"id\" and \"x\"")
        out.append((float(obj["t"]), obj[key]))
    return out


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


def flagged(track: dict[str, Any]) -> bool:
    """A track whose maneuver is detected: a central track's ``maneuver``, or a track in CA."""
    return "maneuver" in track or track.get("model") == "ca"


def evaluate(tracks_path: Path, truth_path: Path, c: float = 100.0, p: float = 2.0,
             all_tracks: bool = False, horizontal: bool = False) -> dict[str, Any]:
    """Every metric of the module docstring over the pictures that have a truth line at their time
    (``horizontal``: positions are x, y only; the altitude error is reported on its own either way)."""
    truth_lines = _load(truth_path, "targets")
    truth = {round(t, 6): items for t, items in truth_lines}
    motion = truth_motion(truth_lines)
    flags = {"maneuvering": [0, 0], "straight": [0, 0]}  # [pairs, flagged]
    was_flagged: dict[Any, bool] = {}
    onsets = 0
    series: list[dict[str, float]] = []
    sequences: dict[Any, list[int | None]] = {}
    sq_err: list[float] = []
    alt_err: list[float] = []
    nees: list[tuple[float, int]] = []
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
            if "P" in shown[j] and xt.shape == xe.shape:
                P = np.asarray(shown[j]["P"], float)
                e = xt - xe
                nees.append((float(e @ np.linalg.solve(P, e)), xt.size))
    if not series:
        raise InputError(f"{tracks_path}: no picture has a truth line at its time in {truth_path}")
    switches = fragments = 0
    for seq in sequences.values():
        s, f = id_changes(seq)
        switches, fragments = switches + s, fragments + f
    inside = [lo <= v <= hi for v, dof in nees for lo, hi in [(chdtri(dof, 0.975), chdtri(dof, 0.025))]]
    mean = {key: float(np.mean([row[key] for row in series])) for key in ("gospa", "localisation", "missed",
                                                                          "false", "ospa")}
    return {
        "c": c, "p": p, "alpha": 2, "pictures": len(series), "pictures_without_truth": skipped,
        "mean": mean, "id_switches": switches, "fragmentations": fragments,
        "position_rmse": math.sqrt(float(np.mean(sq_err))) if sq_err else None, "horizontal": horizontal,
        "altitude_rmse": math.sqrt(float(np.mean(np.square(alt_err)))) if alt_err else None,
        "altitude_bias": float(np.mean(alt_err)) if alt_err else None,
        "nees_mean": float(np.mean([v for v, _ in nees])) if nees else None,
        "nees_dof": nees[0][1] if nees else None,
        "nees_inside_95": float(np.mean(inside)) if inside else None,
        "maneuvers": {"onsets": onsets, "maneuver_accel": MANEUVER_ACCEL, "straight_accel": STRAIGHT_ACCEL,
                      "straight_for_s": STRAIGHT_FOR_S,
                      **{f"{kind}_pairs": n for kind, (n, _) in flags.items()},
                      **{f"flagged_while_{kind}": hit / n if n else None for kind, (n, hit) in flags.items()}},
        "series": series,
    }


def plot(result: dict[str, Any], tracks_path: Path, truth_path: Path, out: Path,
         events: dict[str, float] | None = None) -> None:
    """Tracks over truth (x-y), where their maneuvers were flagged, and GOSPA with its parts over
    time, with ``events`` (label -> time, such as a sensor joining) marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 6))
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
    for (kind, _), pts in paths.items():
        a = np.array(pts)
        if kind == "truth":
            ax1.plot(a[:, 0], a[:, 1], color="0.6", lw=2.5, zorder=1)
        else:
            ax1.plot(a[:, 0], a[:, 1], lw=1.0, zorder=2)
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
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack evaluate", description="GOSPA, OSPA, id switches, "
                                     "fragmentations, RMSE and NEES of a track picture file against truth")
    parser.add_argument("--tracks", required=True, type=Path)
    parser.add_argument("--truth", required=True, type=Path)
    parser.add_argument("--c", type=float, default=100.0, help="cut-off distance [m] (default 100)")
    parser.add_argument("--p", type=float, default=2.0, help="order (default 2)")
    parser.add_argument("--alpha", type=float, default=2.0, help="GOSPA alpha (only 2 is supported)")
    parser.add_argument("--all-tracks", action="store_true", help="evaluate tentative tracks too")
    parser.add_argument("--horizontal", action="store_true", help="GOSPA, OSPA and RMSE on x, y only (the "
                        "altitude error is reported on its own either way)")
    parser.add_argument("--json", type=Path, help="write the full result (with the per-picture series)")
    parser.add_argument("--plot", type=Path, help="PNG: tracks over truth and GOSPA over time")
    parser.add_argument("--config", type=Path, help="with --plot: a config whose [frame] puts the tracks on the "
                        "Earth; the map (longitude / latitude, sensor sites marked) goes to PLOT's name + -map.png")
    args = parser.parse_args(argv)
    if args.alpha != 2:
        parser.error("--alpha: only alpha = 2 (the decomposable GOSPA) is supported")
    if not (args.c > 0 and args.p >= 1):
        parser.error("--c must be > 0 and --p >= 1")
    for path in (args.json, args.plot):
        if path is not None and not path.parent.is_dir():
            raise InputError(f"{path}: the folder {path.parent} does not exist")
    result = evaluate(args.tracks, args.truth, args.c, args.p, args.all_tracks, args.horizontal)
    m = result["mean"]
    print(f"pictures {result['pictures']} (without truth: {result['pictures_without_truth']})")
    print(f"mean GOSPA {m['gospa']:.2f} m (c = {args.c:g}, p = {args.p:g}, alpha = 2"
          f"{', x-y' if args.horizontal else ''}): localisation "
          f"{m['localisation']:.1f}, missed {m['missed']:.1f}, false {m['false']:.1f} (p-th power parts)")
    print(f"mean OSPA {m['ospa']:.2f} m; id switches {result['id_switches']}; fragmentations "
          f"{result['fragmentations']}")
    rmse, nees = result["position_rmse"], result["nees_mean"]
    print(f"position RMSE {rmse:.2f} m" if rmse is not None else "position RMSE -", end="; ")
    print(f"NEES mean {nees:.2f} ({result['nees_dof']} dof), {100 * result['nees_inside_95']:.1f}% inside the "
          f"95% band" if nees is not None else "NEES -")
    if result["altitude_rmse"] is not None:
        print(f"altitude error over the assigned pairs: RMSE {result['altitude_rmse']:.2f} m, mean "
              f"{result['altitude_bias']:+.2f} m (track - truth)")
    man = result["maneuvers"]
    rate = {k: "-" if man[f"flagged_while_{k}"] is None else f"{100 * man[f'flagged_while_{k}']:.1f}%"
            for k in ("maneuvering", "straight")}
    print(f"maneuver flags: {rate['maneuvering']} of {man['maneuvering_pairs']} assigned pairs while the target "
          f"accelerates (>= {MANEUVER_ACCEL:g} m/s^2), {rate['straight']} of {man['straight_pairs']} while it moves "
          f"straight (< {STRAIGHT_ACCEL:g} m/s^2 for {STRAIGHT_FOR_S:g} s); {man['onsets']} onsets")
    if args.json:
        args.json.write_text(json.dumps(result))
    if args.plot:
        plot(result, args.tracks, args.truth, args.plot)
        print(f"wrote {args.plot}")
        frame = load_frame(args.config)
        if frame is not None:
            where = args.plot.with_name(args.plot.stem + "-map.png")
            plot_map(args.tracks, args.truth, frame, where)
            print(f"wrote {where}")
    return 0
