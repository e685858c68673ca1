"""The figure of ``evaluate --plot``: tracks over truth, maneuver flags and GOSPA over time."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.fusion_center.mtt.earthmap import TRUTH_GREY, track_colours
from fedtrack.fusion_center.mtt.evaluation.consistency import flagged
from fedtrack.fusion_center.mtt.evaluation.scoring import _load, _positions
from fedtrack.jsonl import InputError, output_file


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
