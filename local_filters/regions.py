"""Regions of a deployment's area: the shards of the fusion centre (issue 27).

A deployment may divide its area into regions, each owned by one centre. ``[regions]`` gives
them as a grid or as polygons (local frame, or WGS-84 through ``[frame]``)::

    [regions]
    margin = 2000.0                 # m: a track this near a region is also sent to it
    grid = {origin = [-5000.0, -5000.0], cell = [5000.0, 5000.0], nx = 2, ny = 2}
    # or, instead of grid:
    [[regions.polygon]]
    id = "north"
    points = [[-5000.0, 0.0], [5000.0, 0.0], [5000.0, 5000.0], [-5000.0, 5000.0]]  # x, y [m]
    # or lat_lon = [[lat, lon], ...] [deg] through [frame] origin

Grid cell ``(i, j)`` (column ``i`` along x, row ``j`` along y) is region ``x<i>y<j>``; a
polygon's id is its ``id``. Each id is one key-expression chunk (``.../region/<id>/...``).

Every region is a polygon (a grid cell is a rectangle). :func:`distances` gives each
position's distance to each region (0 inside: even-odd rule); :func:`region_of` the nearest
region (the first containing one, and for a position outside every region the nearest, so
that each track has exactly one owner); :func:`near_regions` every region within ``margin``
(its own included): the regions a local tracker publishes a track's report to.

``margin`` has no default: it must cover how far a track moves between two reports of the
slowest sensor plus the association gate's reach of its position error (docs/multitarget.md
#regions), which the deployment knows and this table does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fedtrack.config import ConfigError, load_tables
from fedtrack.geodetic import Frame, FrameConfig, enu_from_geodetic
from fedtrack.keys import AREA_CENTRE_ID, MAX_ID_LENGTH, InvalidName, check_id, is_identity_name, standby_id
from fedtrack.wire import MAX_MAGNITUDE

MAX_REGIONS = 10_000


class Regions(NamedTuple):
    """``R`` regions as polygons padded to ``E`` vertices (the last vertex repeated)."""

    ids: tuple[str, ...]
    vertices: np.ndarray  # (R, E, 2) x, y [m] in the local frame
    margin: float  # m


@dataclass(frozen=True)
class GridConfig:
    """``[regions] grid``: ``nx`` x ``ny`` cells of ``cell`` [m] from ``origin`` (lower-left corner)."""

    origin: tuple[float, float]
    cell: tuple[float, float]
    nx: int
    ny: int

    def validate(self) -> None:
        if not all(np.isfinite(self.origin)):
            raise ConfigError("origin: must be finite")
        if not all(np.isfinite(c) and c > 0 for c in self.cell):
            raise ConfigError("cell: both sizes must be > 0")
        if not (self.nx >= 1 and self.ny >= 1 and self.nx * self.ny <= MAX_REGIONS):
            raise ConfigError(f"nx, ny: must be >= 1 with nx * ny <= {MAX_REGIONS}")


@dataclass(frozen=True)
class PolygonConfig:
    """``[[regions.polygon]]``: a region's id and its vertices, ``points`` (x, y [m]) or ``lat_lon`` [deg]."""

    id: str
    points: tuple[tuple[float, float], ...] = ()
    lat_lon: tuple[tuple[float, float], ...] = ()

    def validate(self) -> None:
        try:
            check_id(self.id, "id")
        except InvalidName as exc:
            raise ConfigError(str(exc)) from exc
        if not is_identity_name(self.id):  # its centres' TLS identity is region-<id> (deploy/access_control.py)
            raise ConfigError(f"id {self.id!r}: letters, digits, . _ - only (the region's TLS identity, "
                              f"region-{self.id}, and its certificate's files are named by it)")
        if len(standby_id(self.id)) > MAX_ID_LENGTH:  # a key chunk too (deploy/access_control.py)
            raise ConfigError(f"id is longer than {MAX_ID_LENGTH - len(standby_id(''))} characters (its standby's id, "
                              f"{standby_id('<id>')}, is at most {MAX_ID_LENGTH})")
        if bool(self.points) == bool(self.lat_lon):
            raise ConfigError(f"{self.id}: give exactly one of points, lat_lon")
        corners = self.points or self.lat_lon
        if len(corners) < 3 or not np.all(np.isfinite(corners)):
            raise ConfigError(f"{self.id}: at least 3 finite vertices")
        bad = [k for k, (lat, lon) in enumerate(self.lat_lon) if not (-90 <= lat <= 90 and -180 <= lon <= 360)]
        if bad:
            raise ConfigError(f"{self.id}: lat_lon vertex {bad[0] + 1} {list(self.lat_lon[bad[0]])}: expected "
                              "[lat deg in [-90, 90], lon deg in [-180, 360]] (as [frame] origin)")


@dataclass(frozen=True)
class RegionsConfig:
    """``[regions]``: a grid or polygons, and the margin."""

    margin: float
    grid: GridConfig | None = None
    polygon: tuple[PolygonConfig, ...] = ()

    def validate(self) -> None:
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise ConfigError("margin: must be >= 0")
        if (self.grid is None) == (not self.polygon):
            raise ConfigError("give exactly one of grid, polygon")
        ids = [p.id for p in self.polygon]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ConfigError(f"polygon: id {dup[0]!r} given twice")
        standbys = sorted(set(ids) & {standby_id(i) for i in ids})
        if standbys:  # a region's centres would run as two identities' (deploy/access_control.py)
            raise ConfigError(f"polygon: id {standbys[0]!r} is the id of the standby of region "
                              f"{standbys[0].removesuffix(standby_id(''))!r}")
        taken = sorted(set(ids) & {AREA_CENTRE_ID, standby_id(AREA_CENTRE_ID)})
        if taken:  # its Health and token keys would be the identity fusion's too (deploy/access_control.py)
            raise ConfigError(f"polygon: id {taken[0]!r} is the id of the whole area's centre (or its standby)")
        if len(ids) > MAX_REGIONS:
            raise ConfigError(f"polygon: at most {MAX_REGIONS} regions")


@dataclass(frozen=True)
class RegionsSettings:
    """The tables the regions are read from: ``[regions]`` and ``[frame]`` (for ``lat_lon``)."""

    regions: RegionsConfig | None = None
    frame: FrameConfig | None = None


def grid_regions(origin: tuple[float, float], cell: tuple[float, float], nx: int, ny: int,
                 margin: float) -> Regions:
    """The ``nx`` x ``ny`` grid's cells as regions ``x<i>y<j>`` (``i`` fastest)."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    lo = np.asarray(origin) + np.stack([i.ravel(), j.ravel()], axis=-1) * np.asarray(cell)  # (R, 2)
    unit = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    ids = tuple(f"x{a}y{b}" for a, b in zip(i.ravel().tolist(), j.ravel().tolist()))
    return Regions(ids, lo[:, None, :] + unit * np.asarray(cell), float(margin))


def grid_over(positions: np.ndarray, nx: int, ny: int, margin: float) -> Regions:
    """An ``nx`` x ``ny`` grid spanning the bounding box of ``positions`` (N, 2)."""
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    return grid_regions(tuple(lo), tuple(np.maximum((hi - lo) / (nx, ny), 1e-9)), nx, ny, margin)


def regions_of_config(cfg: RegionsConfig, frame: FrameConfig | None) -> Regions:
    """The regions of a validated ``[regions]`` table (``frame`` converts ``lat_lon`` vertices); a
    ConfigError naming the key for polygons that are not simple, enclose no area or overlap, and for
    coordinates beyond the wire's +-MAX_MAGNITUDE (:func:`check_polygons`, :func:`check_overlaps`); ``lat_lon``
    edges are split at the vertices on them (:func:`split_at_junctions`)."""
    if cfg.margin > MAX_MAGNITUDE:
        raise ConfigError(f"regions.margin: beyond {MAX_MAGNITUDE:g} m")
    if cfg.grid is not None:
        g = cfg.grid
        far = [o + c * n for o, c, n in zip(g.origin, g.cell, (g.nx, g.ny))]  # Python floats: inf, no warning
        if not all(abs(v) <= MAX_MAGNITUDE for v in (*g.origin, *far)):
            raise ConfigError(f"regions.grid: the grid reaches beyond +-{MAX_MAGNITUDE:g} m (the wire's bound on "
                              "any position; distances there overflow)")
        return grid_regions(g.origin, g.cell, g.nx, g.ny, cfg.margin)
    keys = [f"regions.polygon.{p.id}.{'lat_lon' if p.lat_lon else 'points'}" for p in cfg.polygon]
    for key, p in zip(keys, cfg.polygon):
        if not p.lat_lon:
            continue
        if frame is None:
            raise ConfigError(f"{key}: needs [frame] origin")
        far = np.flatnonzero(~facing(frame.frame, *np.asarray(p.lat_lon, dtype=float).T))
        if far.size:
            raise ConfigError(f"{key}: vertex {far[0] + 1} {list(p.lat_lon[far[0]])} is 90 deg or more from [frame] "
                              "origin, on the far side of the Earth, where the local frame's x, y fold back onto the "
                              "near side (lat and lon swapped?)")
    wgs84 = [k for k, p in enumerate(cfg.polygon) if p.lat_lon]
    lat_lon = [np.asarray(cfg.polygon[k].lat_lon, dtype=float) for k in wgs84]
    polygons = [np.asarray(p.points, dtype=float) for p in cfg.polygon]
    for k, corners in zip(wgs84, lat_lon):
        polygons[k] = to_local(frame.frame, corners)
    check_polygons(keys, polygons, [p.lat_lon for p in cfg.polygon])  # each as given (its edges numbered as written)
    for k, corners in zip(wgs84, split_at_junctions(lat_lon) if lat_lon else []):
        polygons[k] = to_local(frame.frame, corners)
    check_overlaps(keys, [p.id for p in cfg.polygon], polygons)
    size = max(len(v) for v in polygons)
    padded = np.stack([np.concatenate([v, np.repeat(v[-1:], size - len(v), axis=0)]) for v in polygons])
    return Regions(tuple(p.id for p in cfg.polygon), padded, cfg.margin)


def facing(frame: Frame, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """(N,) bool: WGS-84 points [deg] on the near side of the Earth from ``frame``'s origin, where the
    ellipsoid's normal and the origin's make an angle under 90 deg: there the local frame's x, y
    (the point's projection along the origin's up) are one-to-one; beyond, they fold back."""
    phi, dlam = np.radians(lat), np.radians(np.asarray(lon) - frame.lon)
    phi0 = np.radians(frame.lat)
    return np.sin(phi) * np.sin(phi0) + np.cos(phi) * np.cos(phi0) * np.cos(dlam) > 0


def to_local(frame: Frame, lat_lon: np.ndarray) -> np.ndarray:
    """x, y (n, 2) [m] in the local frame of WGS-84 vertices (n, 2) [lat, lon deg] at height 0."""
    return enu_from_geodetic(frame, lat_lon[:, 0], lat_lon[:, 1], np.zeros(len(lat_lon)))[:, :2]


CHUNK = 1 << 20  # elements of a temporary array of pairs (edges and edges, positions and edges): 8 MB of floats
JUNCTION_DEG = 1e-9  # a vertex this near another polygon's edge, in degrees (0.1 mm), lies on it


def split_at_junctions(polygons: list[np.ndarray]) -> list[np.ndarray]:
    """WGS-84 polygons (n, 2) [lat, lon deg], each edge split at every vertex of theirs that lies on it
    in latitude and longitude (longitude the short way round): a T-junction, such as the corner of two
    regions on a third's side along a parallel. Converted, an edge is the straight line between its
    ends in the local frame, so without the split the third's side and the two's sides were different
    lines (121 m apart in the middle of a 1 deg edge at 48.8 deg N) that overlapped or left a gap."""
    every = np.unique(np.concatenate(polygons), axis=0)
    by_lat = np.argsort(every[:, 0])
    lats = every[by_lat, 0]
    out = []
    for poly in polygons:
        pieces = []
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):
            pieces.append(a[None])
            lo, hi = np.searchsorted(lats, [min(a[0], b[0]) - JUNCTION_DEG, max(a[0], b[0]) + JUNCTION_DEG],
                                     side="right")
            cand = every[by_lat[lo:hi]]
            d = np.array([b[0] - a[0], (b[1] - a[1] + 180.0) % 360.0 - 180.0])
            v = np.stack([cand[:, 0] - a[0], (cand[:, 1] - a[1] + 180.0) % 360.0 - 180.0], axis=-1)
            length = float(np.hypot(*d))
            if length == 0.0:
                continue
            t = v @ d / length  # along the edge [deg]
            off = np.abs(v[:, 0] * d[1] - v[:, 1] * d[0]) / length
            on = (off <= JUNCTION_DEG) & (t > JUNCTION_DEG) & (t < length - JUNCTION_DEG)
            pieces.append(cand[on][np.argsort(t[on])])
        out.append(np.concatenate(pieces))
    return out


def _crossings(a: np.ndarray, b: np.ndarray, tol: float) -> np.ndarray:
    """(K, 2) index pairs ``(i, j)``, in increasing order: edge i of closed polygon ``a`` (Ea, 2) and
    edge j of ``b`` cross at one point inside both (touching or collinear overlap is not a crossing; a
    vertex within ``tol`` [m] of the other edge's line touches it: one place given in two ways, such as
    a pole at two longitudes, converts to points some 1e-10 m apart). Only pairs whose bounding boxes
    meet are tested (a crossing point lies in both), ``CHUNK`` pairs of boxes at a time: a border of
    thousands of vertices took its square in memory (3,000: 1 GB)."""
    a0, a1, b0, b1 = a, np.roll(a, -1, axis=0), b, np.roll(b, -1, axis=0)
    alo, ahi, blo, bhi = np.minimum(a0, a1), np.maximum(a0, a1), np.minimum(b0, b1), np.maximum(b0, b1)

    def side(o: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:  # sign of (p - o) x (q - o), 0 within tol
        cross = (p[:, 0] - o[:, 0]) * (q[:, 1] - o[:, 1]) - (p[:, 1] - o[:, 1]) * (q[:, 0] - o[:, 0])
        reach = tol * np.hypot(p[:, 0] - o[:, 0], p[:, 1] - o[:, 1])
        return np.where(np.abs(cross) > reach, np.sign(cross), 0.0)

    pairs = [np.zeros((0, 2), dtype=np.int64)]
    step = max(1, CHUNK // max(len(b), 1))
    for start in range(0, len(a), step):
        lo, hi = alo[start:start + step, None], ahi[start:start + step, None]
        i, j = np.nonzero(np.all((lo <= bhi[None]) & (blo[None] <= hi), axis=-1))
        i += start
        hit = ((side(b0[j], b1[j], a0[i]) * side(b0[j], b1[j], a1[i]) < 0)
               & (side(a0[i], a1[i], b0[j]) * side(a0[i], a1[i], b1[j]) < 0))
        pairs.append(np.stack([i[hit], j[hit]], axis=1))
    return np.concatenate(pairs)


def _strictly_inside(poly: np.ndarray, pos: np.ndarray, tol: float) -> np.ndarray:
    """(N,) bool: positions inside polygon ``poly`` farther than ``tol`` from its edges."""
    inside, edge = _inside_and_edge(Regions(("p",), poly[None], 0.0), pos)
    return inside[:, 0] & (edge[:, 0] > tol)


def _tolerance(points: np.ndarray) -> float:
    """The distance [m] below which two of ``points``' places are one: 1e-9 of their largest
    coordinate (at least 1e-9 m), far above the round-off of a conversion to the local frame."""
    return 1e-9 * max(1.0, float(np.abs(points).max()))


def check_polygons(keys: list[str], polygons: list[np.ndarray], written: list[Sequence] | None = None) -> None:
    """Each region a simple polygon (no two edges cross) enclosing an area, every coordinate within
    +-MAX_MAGNITUDE (squared distances stay finite). A ConfigError naming ``keys[i]`` otherwise; for a
    polygon ``written`` in WGS-84 (its ``lat_lon``, else empty) that encloses no area, the two of its
    vertices written as different places that are one (:func:`one_place`)."""
    for i, (key, poly) in enumerate(zip(keys, polygons)):
        if not np.all(np.abs(poly) <= MAX_MAGNITUDE):
            raise ConfigError(f"{key}: coordinates beyond +-{MAX_MAGNITUDE:g} m (the wire's bound on any position)")
        E = len(poly)
        pairs = _crossings(poly, poly, _tolerance(poly))
        apart = pairs[:, 1] - pairs[:, 0]
        crossed = pairs[(apart > 1) & (apart < E - 1)]  # each pair once, not neighbours
        if crossed.size:
            i, j = crossed[0] + 1
            raise ConfigError(f"{key}: edges {i} and {j} cross (a region must be a simple polygon; edge k runs from "
                              "vertex k to the next)")
        x, y = poly[:, 0], poly[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        extent = float(np.ptp(poly, axis=0).max())
        if not area > 1e-12 * extent * extent:
            same = one_place(np.asarray(written[i], dtype=float), poly) if written and len(written[i]) else None
            if same is None:
                raise ConfigError(f"{key}: encloses no area (its vertices are on one line or one point)")
            a, b = same
            raise ConfigError(f"{key}: encloses no area: vertices {a + 1} {list(written[i][a])} and {b + 1} "
                              f"{list(written[i][b])} are one place (an edge is the straight line between its two "
                              "vertices in the local frame, not a parallel: a cap about a pole is a ring of vertices "
                              "along its parallel, a few degrees of longitude apart, not a box of latitudes and "
                              "longitudes)")


def one_place(lat_lon: np.ndarray, local: np.ndarray) -> tuple[int, int] | None:
    """The first two of a polygon's WGS-84 vertices (n, 2) [lat, lon deg] written as different places
    that convert to one place of the local frame, ``local`` (n, 2) (within :func:`_tolerance`): the
    same parallel at longitudes 360 deg apart, or the pole at two longitudes; None if there are none."""
    tol = _tolerance(local)
    for a in range(len(local)):
        for b in range(a + 1, len(local)):
            if np.hypot(*(local[a] - local[b])) <= tol and not np.array_equal(lat_lon[a], lat_lon[b]):
                return a, b
    return None


def check_overlaps(keys: list[str], ids: list[str], polygons: list[np.ndarray]) -> None:
    """No region overlapping another (the first containing region owns a position: a region inside
    another would own nothing); shared borders are fine. A ConfigError naming ``keys[j]`` otherwise."""
    boxes = np.array([[*p.min(axis=0), *p.max(axis=0)] for p in polygons])
    for j in range(1, len(polygons)):
        b = polygons[j]
        near = np.flatnonzero((boxes[:j, 0] < boxes[j, 2]) & (boxes[j, 0] < boxes[:j, 2])
                              & (boxes[:j, 1] < boxes[j, 3]) & (boxes[j, 1] < boxes[:j, 3]))
        for i in near.tolist():
            a = polygons[i]
            tol = _tolerance(np.concatenate([a, b]))
            probes_b = np.concatenate([b, 0.5 * (b + np.roll(b, -1, axis=0))])
            probes_a = np.concatenate([a, 0.5 * (a + np.roll(a, -1, axis=0))])
            same = {tuple(v) for v in a.tolist()} == {tuple(v) for v in b.tolist()}
            if (same or _crossings(a, b, tol).size or _strictly_inside(a, probes_b, tol).any()
                    or _strictly_inside(b, probes_a, tol).any()):
                raise ConfigError(f"{keys[j]}: overlaps region {ids[i]} (regions may share borders, not area: "
                                  "a position belongs to one region)")


def load_regions(path: str | Path | None) -> Regions | None:
    """The config file's regions (None without a file or without ``[regions]``)."""
    if path is None:
        return None
    settings = load_tables(path, RegionsSettings)
    if settings.regions is None:
        return None
    try:
        return regions_of_config(settings.regions, settings.frame)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc


def parse_grid_spec(spec: str) -> tuple[int, int]:
    """``"NXxNY"`` (e.g. ``"2x2"``) as ``(nx, ny)``."""
    parts = spec.lower().split("x")
    if (len(parts) != 2 or not all(p.isascii() and p.isdigit() and int(p) >= 1 for p in parts)
            or int(parts[0]) * int(parts[1]) > MAX_REGIONS):
        raise ConfigError(f"--regions: expected NXxNY (e.g. 2x2, at most {MAX_REGIONS} cells) or 'config', got {spec!r}")
    return int(parts[0]), int(parts[1])


def distances(regions: Regions, pos: np.ndarray) -> np.ndarray:
    """The distance (N, R) [m] of each position (N, 2) to each region: 0 inside (even-odd rule),
    else to the nearest edge."""
    inside, edge = _inside_and_edge(regions, pos)
    return np.where(inside, 0.0, edge)


def _inside_and_edge(regions: Regions, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, R) each: whether each position is inside each region (even-odd rule), and its distance
    to the region's nearest edge; positions ``CHUNK`` position-edge pairs at a time."""
    pos = np.asarray(pos, dtype=float)
    step = max(1, CHUNK // max(regions.vertices.shape[0] * regions.vertices.shape[1], 1))
    if pos.shape[0] <= step:
        return _inside_and_edge_of(regions, pos)
    parts = [_inside_and_edge_of(regions, pos[k:k + step]) for k in range(0, pos.shape[0], step)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _inside_and_edge_of(regions: Regions, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_inside_and_edge` in one pass ((N, R, E) temporaries)."""
    ax, ay = regions.vertices[..., 0], regions.vertices[..., 1]  # (R, E) edge starts
    b = np.roll(regions.vertices, -1, axis=1)  # edge ends (closing edge included)
    abx, aby = b[..., 0] - ax, b[..., 1] - ay
    length2 = abx * abx + aby * aby
    p = np.asarray(pos, dtype=float)
    px, py = p[:, 0, None, None], p[:, 1, None, None]  # (N, 1, 1); x and y apart: no size-2 axis to reduce
    apx, apy = px - ax, py - ay  # (N, R, E)
    s = np.clip((apx * abx + apy * aby) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    ex, ey = apx - s * abx, apy - s * aby
    edge = np.sqrt(ex * ex + ey * ey).min(axis=-1)  # (N, R)
    straddles = (ay > py) != (b[..., 1] > py)  # a padded (zero-length) edge never straddles
    x_cross = ax + (py - ay) * abx / np.where(straddles, b[..., 1] - ay, 1.0)
    inside = np.count_nonzero(straddles & (px < x_cross), axis=-1) % 2 == 1
    return inside, edge


def region_of(regions: Regions, pos: np.ndarray) -> np.ndarray:
    """The owning region's index (N,) of each position (N, 2): the first containing it, else the nearest."""
    return np.argmin(distances(regions, pos), axis=1)


def near_regions(regions: Regions, pos: np.ndarray) -> np.ndarray:
    """(N, R) bool: the regions within ``margin`` of each position, its owner always included."""
    d = distances(regions, pos)
    near = d <= regions.margin
    near[np.arange(d.shape[0]), np.argmin(d, axis=1)] = True
    return near
