"""``evaluate``: a track picture file scored against truth, picture by picture (GOSPA, OSPA, RMSE,
id switches, fragmentations, NEES, maneuver flags, registration), and the files' readers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.fusion_center.mtt.evaluation.consistency import (
    MANEUVER_ACCEL,
    STRAIGHT_ACCEL,
    STRAIGHT_FOR_S,
    flagged,
    nees_parts,
    truth_motion,
)
from fedtrack.fusion_center.mtt.evaluation.metrics import id_changes, set_distance
from fedtrack.fusion_center.mtt.evaluation.registration import registration
from fedtrack.jsonl import InputError, is_number, picture_rows, read_jsonl
from fedtrack.progress import progress_bar


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
            if not isinstance(item.get("alt_measured", True), bool):
                raise InputError(f"{where}: {key}[{j}].alt_measured must be true or false, got "
                                 f"{item['alt_measured']!r}")
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
    unmeasured_pairs = 0  # assigned pairs whose track's altitude is not measured (scored on x, y)
    by_sensors: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}  # a track's sensors -> (truth, track) states
    unassigned: dict[str, int] = {}  # a track's sensors -> its pictures assigned to no truth (false)
    skipped = 0
    pictures = _load(tracks_path, "tracks")
    with progress_bar(len(pictures), "evaluate: pictures") as bar:  # GOSPA: 10 s a picture at 10,000 targets
        for t, items in pictures:
            bar.update()
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
            flat = np.array([tr.get("alt_measured", True) is False for tr in shown], bool)
            dist = set_distance(X[:, :k], Y[:, :k], c, p, flat if k == 3 else None)
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
                kj = 2 if flat[j] else k
                sq_err.append(float(np.sum((X[i, :kj] - Y[j, :kj]) ** 2)))
                unmeasured_pairs += bool(flat[j])
                if X.shape[1] > 2 and Y.shape[1] > 2 and not flat[j]:
                    alt_err.append(float(Y[j, 2] - X[i, 2]))
                kind = motion.get((round(t, 6), g["id"]))
                if kind in flags:
                    flags[kind][0] += 1
                    flags[kind][1] += flagged(shown[j])
                xt, xe = np.asarray(g["x"], float), np.asarray(shown[j]["x"], float)
                by_sensors.setdefault(",".join(shown[j].get("sensors", [])) or "-", []).append((xt[:4], xe[:4]))
                if xe.size == 4 and xt.size == 6:  # a 2-D tracker against a 3-D truth: its horizontal state
                    xt = xt[:4]
                elif flat[j] and xe.size == 6 and xt.size >= 4:  # an altitude nobody measured: x, vx, y, vy
                    xt, xe = xt[:4], xe[:4]
                if "P" in shown[j] and xt.shape == xe.shape:
                    P = np.asarray(shown[j]["P"], float)
                    try:
                        np.linalg.cholesky(P)
                    except np.linalg.LinAlgError:
                        raise InputError(f"{tracks_path}: the picture at t = {t:g}: track {shown[j]['id']}'s P is "
                                         "not positive definite (a covariance must be)") from None
                    errors.append(xt - xe)
                    covariances.append(P[:xe.size, :xe.size])
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
        "altitude_unmeasured_pairs": unmeasured_pairs,
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
