"""A map of track pictures over truth in longitude / latitude, with the sensor sites marked.

Drawn from :func:`fedtrack.geojson.feature_collection` (the same lines ``export --geojson``
writes): truth grey and wide, each confirmed track a thin coloured line, radar and sensor sites
as triangles, the frame's origin as a cross. Longitude is stretched by 1 / cos(latitude of the
origin), so that a degree is about as long on both axes near it.
"""

from __future__ import annotations

import math
from pathlib import Path

from fedtrack.geodetic import FrameConfig
from fedtrack.geojson import feature_collection


def plot_map(tracks: Path, truth: Path | None, frame: FrameConfig, out: Path, title: str = "") -> None:
    """Write the map to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 8))
    for feature in feature_collection(frame, tracks, truth)["features"]:
        kind, geometry = feature["properties"]["kind"], feature["geometry"]
        coords = geometry["coordinates"] if geometry["type"] == "LineString" else [geometry["coordinates"]]
        lon, lat = [c[0] for c in coords], [c[1] for c in coords]
        if kind == "truth":
            ax.plot(lon, lat, color="0.65", lw=3.0, zorder=1)
        elif kind == "track":
            ax.plot(lon, lat, lw=1.0, zorder=2)
        elif kind == "sensor":
            ax.scatter(lon, lat, marker="^", s=90, c="black", zorder=4)
            ax.annotate(feature["properties"]["id"], (lon[0], lat[0]), xytext=(6, 6), textcoords="offset points",
                        fontsize=9, weight="bold")
        else:
            ax.scatter(lon, lat, marker="+", s=120, c="red", zorder=4, label="frame origin")
    ax.set_aspect(1.0 / math.cos(math.radians(frame.origin[0])))
    ax.set_xlabel("longitude [deg]")
    ax.set_ylabel("latitude [deg]")
    ax.set_title(title or "confirmed tracks (colours) over truth (grey); sensor sites ^")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
