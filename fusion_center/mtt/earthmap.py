"""A map of track pictures over truth in longitude / latitude, with the sensor sites marked.

Drawn from :func:`fedtrack.geojson.feature_collection` (the same lines ``export --geojson``
writes): truth grey and wide, each confirmed track a thin coloured line, radar and sensor sites
as triangles, the frame's origin as a cross. Longitude is stretched by 1 / cos(latitude of the
origin), so that a degree is about as long on both axes near it, and drawn continuous about the
origin's (its ticks labelled in [-180, 180)), so that a scene across the antimeridian is one
picture, not two strips 360 degrees apart.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fedtrack.geodetic import FrameConfig, wrap_lon
from fedtrack.geojson import feature_collection

TRUTH_GREY = "0.6"


def track_colours() -> list[tuple[float, float, float, float]]:
    """The colours tracks cycle through: matplotlib's ``tab20`` without its greys (the truth is
    drawn grey, so no track may look like an untracked target)."""
    from matplotlib import colormaps

    cmap = colormaps["tab20"]
    return [rgba for rgba in (cmap(i) for i in range(cmap.N)) if max(rgba[:3]) - min(rgba[:3]) > 0.1]



def plot_map(tracks: Path, truth: Path | None, frame: FrameConfig, out: Path, label: str | None = None) -> None:
    """Write the map to ``out`` (PNG), titled with ``label`` (the algorithm) and the tracks file's name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    fig, ax = plt.subplots(figsize=(9, 8))
    colours = track_colours()
    n_tracks = 0
    lon0 = frame.origin[1]
    for feature in feature_collection(frame, tracks, truth)["features"]:
        kind, geometry = feature["properties"]["kind"], feature["geometry"]
        parts = {"Point": [[geometry["coordinates"]]], "LineString": [geometry["coordinates"]]}.get(
            geometry["type"], geometry["coordinates"])
        coords = [c for part in parts for c in part]
        lon = (lon0 + wrap_lon(np.array([c[0] for c in coords]) - lon0)).tolist()
        lat = [c[1] for c in coords]
        if kind == "truth":
            ax.plot(lon, lat, color=TRUTH_GREY, lw=3.0, zorder=1)
        elif kind == "track":
            ax.plot(lon, lat, color=colours[n_tracks % len(colours)], lw=1.0, zorder=2)
            n_tracks += 1
        elif kind == "sensor":
            ax.scatter(lon, lat, marker="^", s=90, c="black", zorder=4)
            ax.annotate(feature["properties"]["id"], (lon[0], lat[0]), xytext=(6, 6), textcoords="offset points",
                        fontsize=9, weight="bold")
        else:
            ax.scatter(lon, lat, marker="+", s=120, c="red", zorder=4, label="frame origin")
    ax.set_aspect(1.0 / math.cos(math.radians(frame.origin[0])))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{float(wrap_lon(v)):g}"))
    ax.set_xlabel("longitude [deg]")
    ax.set_ylabel("latitude [deg]")
    fig.suptitle(f"{label or 'algorithm not recorded (--label)'}: {tracks.name}")
    ax.set_title("confirmed tracks (colours) over truth (grey); sensor sites as triangles")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
