"""The figure of ``evaluate --plot``: tracks over truth, maneuver flags, region borders and
hand-overs, and GOSPA over time."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.fusion_center.mtt.earthmap import TRUTH_GREY, track_colours
from fedtrack.fusion_center.mtt.evaluation.consistency import flagged
from fedtrack.fusion_center.mtt.evaluation.scoring import _load, _positions
from fedtrack.jsonl import InputError, output_file
from fedtrack.local_filters.regions import Regions, region_of

#: more truth paths than this are drawn as trails over the run's last ``duration * MAX_PATHS / n``
#: seconds: the ink of MAX_PATHS whole paths (200 targets over 120 s were measured readable)
MAX_PATHS = 250
#: a scene wider than this [m] is drawn in km
KM_ABOVE = 20_000.0


class Paths(NamedTuple):
    """Position paths to draw: truth and confirmed tracks, each (n, 3) rows of t, x, y."""

    truth: list[np.ndarray]
    tracks: list[np.ndarray]
    flagged: np.ndarray  # (m, 3) t, x, y where a confirmed track's maneuver was flagged


def check_figure_format(out: Path) -> None:
    """An InputError naming ``out`` unless matplotlib writes its suffix's format (none: PNG)."""
    from matplotlib.figure import Figure

    formats = Figure().canvas.get_supported_filetypes()
    if out.suffix and out.suffix[1:].lower() not in formats:
        raise InputError(f"{out}: --plot writes a figure; its suffix {out.suffix!r} is not a format matplotlib "
                         f"writes (use one of {', '.join('.' + f for f in sorted(formats))})")


def load_paths(tracks_path: Path, truth_path: Path) -> Paths:
    """The truth's and the confirmed tracks' paths, in the files' order, and the flagged positions."""
    truth: dict[Any, list[list[float]]] = {}
    tracks: dict[Any, list[list[float]]] = {}
    maneuvering: list[list[float]] = []
    for t, targets in _load(truth_path, "targets"):
        for g in targets:
            truth.setdefault(g["id"], []).append([t, *_positions(g["x"])[:2]])
    for t, items in _load(tracks_path, "tracks"):
        for tr in items:
            if tr.get("status", "confirmed") == "confirmed":
                tracks.setdefault(tr["id"], []).append([t, *_positions(tr["x"])[:2]])
                if flagged(tr):
                    maneuvering.append(tracks[tr["id"]][-1])
    return Paths([np.array(p) for p in truth.values()], [np.array(p) for p in tracks.values()],
                 np.array(maneuvering).reshape(-1, 3))


def thinned(paths: Paths) -> tuple[Paths, float | None, float]:
    """With more than MAX_PATHS truth paths, every path and flag cut to the run's last ``window``
    seconds; else ``paths`` whole (``window`` None); and the run's ``span`` [s]."""
    times = np.concatenate([p[:, 0] for p in paths.truth + paths.tracks] or [np.zeros(1)])
    span = float(times.max() - times.min())
    if len(paths.truth) <= MAX_PATHS:
        return paths, None, span
    window = span * MAX_PATHS / len(paths.truth)
    start = float(times.max()) - window

    def cut(ps: list[np.ndarray]) -> list[np.ndarray]:
        return [p[p[:, 0] >= start] for p in ps if p[-1, 0] >= start]
    return Paths(cut(paths.truth), cut(paths.tracks), paths.flagged[paths.flagged[:, 0] >= start]), window, span


def handovers(tracks: list[np.ndarray], regions: Regions) -> np.ndarray:
    """(k, 2) midpoints of the steps where a track's owning region (by position) changes."""
    out = []
    for p in tracks:
        owner = region_of(regions, p[:, 1:])
        step = np.flatnonzero(owner[1:] != owner[:-1])
        out.append((p[step, 1:] + p[step + 1, 1:]) / 2)
    return np.concatenate(out).reshape(-1, 2) if out else np.zeros((0, 2))


def title(result: dict[str, Any], tracks_path: Path, label: str | None) -> str:
    """The algorithm (``label``, else the file's), its maneuver detector if one ran, and the file."""
    detector = (result.get("maneuvers") or {}).get("detector")
    algorithm = label or result.get("algorithm") or "algorithm not recorded (--label)"
    return f"{algorithm}{f' (maneuver detector {detector})' if detector not in (None, 'none') else ''}: " \
           f"{tracks_path.name}"


def plot(result: dict[str, Any], tracks_path: Path, truth_path: Path, out: Path,
         events: dict[str, float] | None = None, label: str | None = None, regions: Regions | None = None) -> None:
    """Tracks over truth (x-y), where their maneuvers were flagged, the ``regions``' borders and the
    tracks' hand-overs, and GOSPA with its parts over time, with ``events`` (label -> time, such as
    a sensor joining) marked; the title names the algorithm (:func:`title`) and the tracks file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 7))
    fig.suptitle(title(result, tracks_path, label))
    every = load_paths(tracks_path, truth_path)
    paths, window, span = thinned(every)
    pts = np.concatenate([p[:, 1:] for p in every.truth + every.tracks] or [np.zeros((0, 2))])
    if regions is not None:
        pts = np.concatenate([pts, regions.vertices.reshape(-1, 2)])
    km = pts.size > 0 and float(np.ptp(pts, axis=0).max()) > KM_ABOVE
    scale = 1e-3 if km else 1.0
    colours = track_colours()
    for p in paths.truth:
        ax1.plot(p[:, 1] * scale, p[:, 2] * scale, color=TRUTH_GREY, lw=2.5, zorder=1)
    for k, p in enumerate(paths.tracks):
        ax1.plot(p[:, 1] * scale, p[:, 2] * scale, color=colours[k % len(colours)], lw=1.0, zorder=2)
    handles = [Line2D([], [], color=TRUTH_GREY, lw=2.5, label=f"truth ({len(every.truth)} targets)"),
               Line2D([], [], color=colours[0], lw=1.0, label=f"confirmed tracks ({len(every.tracks)}), a colour each")]
    if len(paths.flagged):
        m = paths.flagged[:, 1:] * scale
        handles.append(ax1.scatter(m[:, 0], m[:, 1], s=9, c="red", marker="x", lw=0.8, zorder=3,
                                   label="maneuver flagged"))
    if regions is not None:
        for rid, poly in zip(regions.ids, regions.vertices):
            closed = np.vstack([poly, poly[:1]]) * scale
            ax1.plot(closed[:, 0], closed[:, 1], color="black", lw=1.0, ls="--", zorder=4)
            ax1.annotate(rid, tuple(poly.mean(axis=0) * scale), ha="center", va="center", fontsize=9,
                         color="black", alpha=0.6, zorder=5)
        handles.append(Line2D([], [], color="black", lw=1.0, ls="--", label=f"region borders ({len(regions.ids)})"))
        h = handovers(paths.tracks, regions) * scale
        handles.append(ax1.scatter(h[:, 0], h[:, 1], s=30, facecolors="none", edgecolors="black", marker="o", lw=1.0,
                                   zorder=5, label=f"track crosses a border: hand-over ({len(h)})"))
    unit = "km" if km else "m"
    panel = "confirmed tracks over truth"
    if window is not None:
        panel += (f"\n{len(every.truth)} targets: only the last {window:.0f} s of {span:.0f} s drawn, so that the "
                  "plot stays readable")
    if not every.tracks:
        ax1.text(0.5, 0.5, f"no confirmed track in {tracks_path.name}", transform=ax1.transAxes, ha="center",
                 va="center", fontsize=12, color="0.3", bbox={"facecolor": "white", "edgecolor": "0.5"})
    ax1.set_title(panel)
    ax1.set_xlabel(f"x [{unit}]")
    ax1.set_ylabel(f"y [{unit}]")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8, frameon=False)
    _gospa(ax2, result, events or {})
    fig.tight_layout()
    with output_file(out, "wb") as fh:
        fig.savefig(fh, dpi=110, format=out.suffix[1:].lower() or "png")
    plt.close(fig)


def _gospa(ax: Any, result: dict[str, Any], events: dict[str, float]) -> None:
    """GOSPA and its parts over time on ``ax``, ``events`` marked, the legend below the axes."""
    t = [r["t"] for r in result["series"]]
    p = result["p"]
    ax.plot(t, [r["gospa"] for r in result["series"]], "k-", lw=1.5, label="GOSPA")
    for key, style in (("localisation", "b--"), ("missed", "r:"), ("false", "g-.")):
        ax.plot(t, [r[key] ** (1 / p) for r in result["series"]], style, lw=1.0, label=f"{key} (p-th root)")
    for name, when in events.items():
        ax.axvline(when, color="0.4", lw=1.0, ls="--")
        ax.annotate(name, (when, 0.97), xycoords=("data", "axes fraction"), rotation=90, ha="right", va="top",
                    fontsize=8, color="0.3")
    if not t:
        ax.text(0.5, 0.5, "no picture has a truth line at its time", transform=ax.transAxes, ha="center",
                va="center", fontsize=12, color="0.3", bbox={"facecolor": "white", "edgecolor": "0.5"})
    ax.set_xlabel("t [s]")
    ax.set_ylabel("GOSPA and its parts [m]")
    mean = result["mean"]["gospa"]
    ax.set_title(f"GOSPA (c = {result['c']:g} m, p = {p:g}, alpha = 2): mean "
                 f"{'-' if mean is None else f'{mean:.1f} m'}")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4, fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
