"""``fedtrack export --geojson``: track pictures and truth on the Earth, as GeoJSON (RFC 7946).

One ``FeatureCollection``: a ``LineString`` per confirmed track and per truth target through its
positions in time order (``[lon, lat]`` or ``[lon, lat, alt]``, WGS-84 degrees and metres above
the ellipsoid, as RFC 7946 orders them), with the times in ``properties.times``; a ``Point`` per
sensor site of ``[frame.sites]`` and one for the frame's origin. A track that appears in one
picture only is a ``Point``. Positions come from the rows' ``lat``, ``lon``, ``alt`` when they carry
them (replay with a ``[frame]``, ``simulate traffic``'s truth), else from ``x`` in the config's frame.
Longitudes are in [-180, 180); a line that crosses the antimeridian is cut there into a
``MultiLineString`` (RFC 7946 section 3.1.9), its parts ending and starting at 180 and -180. A track line
some of whose rows are marked ``"alt_measured": false`` has ``properties.alt_measured``, a boolean per position.
"""

from __future__ import annotations

import argparse
import json
from itertools import pairwise
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError
from fedtrack.geodetic import Frame, FrameConfig, add_geodetic, load_frame, wrap_lon
from fedtrack.jsonl import InputError, as_float, check_outputs, output_file, picture_rows, read_jsonl, require


def _placed(r: Any, frame: Frame, where: str) -> dict[str, Any]:
    """A picture or truth row with its ``lat``, ``lon`` (and ``alt`` when it has one) checked, or placed from ``x`` in
    ``frame`` when it has no ``lat``; an InputError naming ``where`` and the field otherwise (before 2026-11-28 a
    ``lat`` of 95, null, a string or 1e400 was written into the GeoJSON, exit 0, and a ``lat`` without ``lon`` or a
    list for ``id`` ended in a traceback)."""
    needs = f"{where}: each needs \"id\" (a number or a string) and \"x\" ([x, vx, y, vy(, z, vz)])"
    if not isinstance(r, dict) or "id" not in r or isinstance(r["id"], (bool, list, dict)):
        raise InputError(needs)
    if "lat" not in r:
        try:
            return add_geodetic(frame, [r])[0]
        except (KeyError, TypeError, IndexError, ValueError) as exc:
            raise InputError(needs) from exc
    if not -90.0 <= as_float(r["lat"], "lat", where) <= 90.0:
        raise InputError(f"{where}: lat must be in [-90, 90] (degrees), got {r['lat']}")
    as_float(require(r, "lon", where), "lon", where)
    if "alt" in r:
        as_float(r["alt"], "alt", where)
    return r


def _paths(path: Path, key: str, frame: Frame, confirmed_only: bool) -> dict[Any, dict[str, Any]]:
    """id -> ``{"coords": [...], "times": [...], "props": {...}}`` of a tracks or truth file."""
    out: dict[Any, dict[str, Any]] = {}
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        for i, row in enumerate(picture_rows(obj, key, where)):
            if confirmed_only and isinstance(row, dict) and row.get("status", "confirmed") != "confirmed":
                continue
            r = _placed(row, frame, f"{where}: {key}[{i}]")
            item = out.setdefault(r["id"], {"coords": [], "times": [], "props": {}, "measured": []})
            point = [float(wrap_lon(r["lon"])), r["lat"]] + ([r["alt"]] if "alt" in r else [])
            item["coords"].append(point)
            item["times"].append(float(obj["t"]))
            item["measured"].append(r.get("alt_measured", True) is not False)
            for extra in ("icao24", "sensors"):
                if extra in r:
                    item["props"][extra] = r[extra]
    return out


def antimeridian_parts(coords: list[list[float]]) -> list[list[list[float]]]:
    """A line's positions (``[lon, lat(, alt)]``, lon in [-180, 180)) cut where a step between two of
    them crosses the antimeridian (a longitude step over 180 deg: the short way round), each cut at
    the crossing, interpolated linearly in longitude (RFC 7946 section 3.1.9)."""
    parts = [[coords[0]]]
    for a, b in pairwise(coords):
        step = b[0] - a[0]
        if abs(step) > 180.0:
            edge = 180.0 if step < 0 else -180.0  # the side a leaves by
            f = (edge - a[0]) / (step + 2 * edge)
            cut = [a[i] + f * (b[i] - a[i]) for i in range(1, len(a))]
            parts[-1].append([edge, *cut])
            parts.append([[-edge, *cut]])
        parts[-1].append(b)
    return parts


def _geometry(coords: list[list[float]]) -> dict[str, Any]:
    """A ``Point`` for one position, a ``LineString``, or a ``MultiLineString`` cut at the antimeridian."""
    if len(coords) == 1:
        return {"type": "Point", "coordinates": coords[0]}
    parts = antimeridian_parts(coords)
    return ({"type": "LineString", "coordinates": parts[0]} if len(parts) == 1
            else {"type": "MultiLineString", "coordinates": parts})


def feature_collection(frame_cfg: FrameConfig, tracks: Path | None, truth: Path | None) -> dict[str, Any]:
    """The GeoJSON ``FeatureCollection`` of the module docstring."""
    frame = frame_cfg.frame
    features: list[dict[str, Any]] = []
    for kind, path, key in (("truth", truth, "targets"), ("track", tracks, "tracks")):
        if path is None:
            continue
        for tid, item in _paths(path, key, frame, kind == "track").items():
            # a line with altitudes nobody measured says which, position by position (docs/geodetic.md)
            measured = {} if all(item["measured"]) else {"alt_measured": item["measured"]}
            features.append({"type": "Feature", "geometry": _geometry(item["coords"]),
                             "properties": {"kind": kind, "id": tid, "times": item["times"], **item["props"],
                                            **measured}})
    points = [({"kind": "sensor", "id": sid}, where) for sid, where in frame_cfg.sites.items()]
    for props, (lat, lon, h) in points + [({"kind": "origin"}, frame)]:
        features.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": [float(wrap_lon(lon)), lat, h]},
                         "properties": props})
    return {"type": "FeatureCollection", "features": features}


def export_main(argv: list[str]) -> int:
    """``fedtrack export``: ``--geojson`` here, a recording database's export otherwise."""
    if not any(a == "--geojson" or a.startswith("--geojson=") for a in argv):
        from fedtrack.recording import main

        return main(argv)
    parser = argparse.ArgumentParser(prog="fedtrack export --geojson",
                                     description="track pictures and truth on the Earth as GeoJSON")
    parser.add_argument("--geojson", required=True, type=Path, metavar="OUT.geojson",
                        help="output file (its folder must exist)")
    parser.add_argument("--config", required=True, type=Path, metavar="C.toml",
                        help="the TOML config with [frame] origin (and sites)")
    parser.add_argument("--tracks", type=Path, metavar="T.jsonl",
                        help="a tracks file (replay's or the recorder's picture lines; default: none)")
    parser.add_argument("--truth", type=Path, metavar="U.jsonl", help="a truth file (simulate's truth.jsonl; "
                        "default: none)")
    args = parser.parse_args(argv)
    check_outputs({"--geojson": args.geojson},
                  {"--config": args.config, "--tracks": args.tracks, "--truth": args.truth})
    if args.tracks is None and args.truth is None:
        parser.error("give --tracks, --truth or both")
    frame = load_frame(args.config)
    if frame is None:
        raise ConfigError(f"{args.config}: no [frame] table (its origin places the tracks on the Earth)")
    collection = feature_collection(frame, args.tracks, args.truth)
    with output_file(args.geojson) as fh:
        fh.write(json.dumps(collection))
    kinds = [f["properties"]["kind"] for f in collection["features"]]
    print(f"wrote {args.geojson}: {kinds.count('track')} tracks, {kinds.count('truth')} truth targets, "
          f"{kinds.count('sensor')} sensor sites")
    return 0
