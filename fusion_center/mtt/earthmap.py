"""A map of track pictures over truth in longitude / latitude, with the sensor sites marked.

Drawn from :func:`fedtrack.geojson.feature_collection` (the same lines ``export --geojson``
writes): truth grey and wide, each confirmed track a thin coloured line, radar and sensor sites
as triangles, the frame's origin as a cross. Longitude is stretched by 1 / cos(latitude of the
origin), so that a degree is about as long on both axes near it, and drawn continuous about the
origin's (its ticks labelled in [-180, 180)), so that a scene across the antimeridian is one
picture, not two strips 360 degrees apart. That stretch is right at the origin's latitude only: a
degree of longitude is ``cos(lat) / cos(lat0)`` of it elsewhere, off by ``tan(lat0)`` times the
latitude difference [rad]. Where that exceeds ``MAX_SCALE_ERROR`` over the scene (near a pole: 10 %
at 85 deg N across 100 km; at the pole a degree of longitude is no length at all), the map is drawn
in the common frame's plane instead (east, north [km] of the origin, the trackers' own frame).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fedtrack.geodetic import FrameConfig, enu_from_geodetic, wrap_lon
from fedtrack.geojson import feature_collection

TRUTH_GREY = "0.6"
#: the largest error of the east-west scale over the scene that a longitude / latitude map may have
MAX_SCALE_ERROR = 0.1


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
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter

    fig, ax = plt.subplots(figsize=(9, 8))
    colours = track_colours()
    n_tracks = 0
    lat0, lon0 = frame.origin[:2]
    features = []
    for feature in feature_collection(frame, tracks, truth)["features"]:
        geometry = feature["geometry"]
        parts = {"Point": [[geometry["coordinates"]]], "LineString": [geometry["coordinates"]]}.get(
            geometry["type"], geometry["coordinates"])
        features.append((feature["properties"], np.array([c[:2] for part in parts for c in part], float)))
    span = max(float(np.abs(np.radians(xy[:, 1] - lat0)).max()) for _, xy in features)
    plane = abs(math.tan(math.radians(lat0))) * span > MAX_SCALE_ERROR
    for props, xy in features:
        kind = props["kind"]
        if plane:
            lon, lat = (enu_from_geodetic(frame.frame, xy[:, 1], xy[:, 0], np.zeros(len(xy)))[:, :2].T / 1e3).tolist()
        else:
            lon, lat = (lon0 + wrap_lon(xy[:, 0] - lon0)).tolist(), xy[:, 1].tolist()
        if kind == "truth":
            ax.plot(lon, lat, color=TRUTH_GREY, lw=3.0, zorder=1)
        elif kind == "track":
            ax.plot(lon, lat, color=colours[n_tracks % len(colours)], lw=1.0, zorder=2)
            n_tracks += 1
        elif kind == "sensor":
            ax.scatter(lon, lat, marker="^", s=90, c="black", zorder=4)
            ax.annotate(props["id"], (lon[0], lat[0]), xytext=(6, 6), textcoords="offset points",
                        fontsize=9, weight="bold")
        else:
            ax.scatter(lon, lat, marker="+", s=120, c="red", zorder=4)
    if plane:
        ax.set_aspect(1.0)
        ax.set_xlabel(f"east of the origin ({lat0:g}, {lon0:g}) [km] (near the pole: the common frame's plane)")
        ax.set_ylabel("north of the origin [km]")
    else:
        ax.set_aspect(1.0 / math.cos(math.radians(lat0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{float(wrap_lon(v)):g}"))
        ax.set_xlabel("longitude [deg]")
        ax.set_ylabel("latitude [deg]")
    fig.suptitle(f"{label or 'algorithm not recorded (--label)'}: {tracks.name}")
    ax.set_title("confirmed tracks over truth")
    ax.grid(alpha=0.3)
    kinds = [props["kind"] for props, _ in features]
    handles = [Line2D([], [], color=TRUTH_GREY, lw=3.0, label=f"truth ({kinds.count('truth')} aircraft)"),
               Line2D([], [], color=colours[0], lw=1.0, label=f"confirmed tracks ({n_tracks}), a colour each"),
               Line2D([], [], color="black", marker="^", ls="none", label="sensor sites"),
               Line2D([], [], color="red", marker="+", ms=10, ls="none", label="frame origin")]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
