"""Positions on the Earth: WGS-84 <-> the local east-north-up frame <-> each radar's own frame.

A deployment's common frame is the east-north-up (ENU) tangent frame at its origin (``[frame]
origin = [lat deg, lon deg, h m]``, height above the WGS-84 ellipsoid); the trackers' ``[x, y,
z]`` are its east, north, up [m]. WGS-84 <-> ENU is pymap3d's (``geodetic2enu`` /
``enu2geodetic``). A radar's own frame is the ENU frame at its site, in which it measures
azimuth (from north, clockwise, in [0, 2 pi)), elevation (from the site's horizontal plane) and
range: ``own = M (p - s)`` with ``s`` the site in the common frame and ``M = R_site R_origin'``
(``R`` the ECEF -> ENU rotation at a latitude and longitude), a rigid motion, so the round trip
is exact to round-off. Everything is batched over a leading axis (``(N, 3)`` arrays).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import orjson

from fedtrack.config import ConfigError, load_tables
from fedtrack.wire import with_geodetic


class Frame(NamedTuple):
    """A common ENU frame: its origin in WGS-84 (degrees, degrees, metres above the ellipsoid)."""

    lat: float
    lon: float
    h: float = 0.0


class RadarSite(NamedTuple):
    """A radar's site: ``position`` (3,) in the common frame, ``rotation`` (3, 3) from the common
    frame's axes to the site's own ENU axes, ``geodetic`` (3,) lat, lon [deg], h [m]."""

    position: np.ndarray
    rotation: np.ndarray
    geodetic: np.ndarray


def ecef_to_enu_rotation(lat: float, lon: float) -> np.ndarray:
    """The rotation (3, 3) from ECEF axes to the ENU axes at geodetic ``lat``, ``lon`` [deg]."""
    phi, lam = np.radians(lat), np.radians(lon)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    return np.array([[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])


def enu_from_geodetic(frame: Frame, lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
    """ENU positions (N, 3) [m] of WGS-84 points (N,) [deg, deg, m] in ``frame``."""
    import pymap3d  # here: only a deployment with a [frame] converts

    e, n, u = pymap3d.geodetic2enu(np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float), *frame)
    return np.stack(np.broadcast_arrays(e, n, u), axis=-1)


def wrap_lon(lon: np.ndarray | float) -> np.ndarray:
    """Longitudes [deg] in [-180, 180) (RFC 7946's range; pymap3d gives (-180, 180], a config may say
    up to 360); a longitude already in range is returned unchanged, to the bit."""
    lon = np.asarray(lon, float)
    return np.where((lon >= -180.0) & (lon < 180.0), lon, np.mod(lon + 180.0, 360.0) - 180.0)


def median_lon(lon: np.ndarray) -> float:
    """The median of longitudes [deg] measured about their circular mean, in [-180, 180): the middle
    of a scene across the antimeridian (179.9 E and 179.9 W: 180, not 0)."""
    lon = np.radians(np.asarray(lon, float))
    ref = np.degrees(np.arctan2(np.sin(lon).mean(), np.cos(lon).mean()))
    return float(wrap_lon(ref + np.median(wrap_lon(np.degrees(lon) - ref))))


def geodetic_from_enu(frame: Frame, enu: np.ndarray) -> np.ndarray:
    """``[lat deg, lon deg in [-180, 180), h m]`` (N, 3) of ENU positions (N, 3) of ``frame``."""
    import pymap3d

    enu = np.asarray(enu, float)
    lat, lon, h = pymap3d.enu2geodetic(enu[..., 0], enu[..., 1], enu[..., 2], *frame)
    return np.stack(np.broadcast_arrays(lat, wrap_lon(lon), h), axis=-1)


def surface_enu(frame: Frame, xy: np.ndarray) -> np.ndarray:
    """The points (N, 3) of the WGS-84 ellipsoid (h = 0) whose east, north in ``frame`` are ``xy`` (N, 2): where
    the line through ``(x, y, 0)`` along the origin's up meets the ellipsoid, its upper crossing. The inverse of
    :func:`surface_xy`: a 2-D track's place on the Earth. A line past the ellipsoid's limb (6,000 km and more
    from the origin: no 2-D sensor on the Earth measures there) meets it nowhere; its point is then the
    ellipsoid's nearest to the line (the limb in that direction; the unit sphere's metric), whose east and north
    are not ``xy``: it was NaN, and a picture holding such a track (one forged detection 8,000 km out) was
    refused by every receiver (``TrackPicture.lla``)."""
    import pymap3d

    xy = np.asarray(xy, float)
    axes = ecef_to_enu_rotation(frame.lat, frame.lon)  # rows: east, north, up in ECEF
    scale = 1.0 / np.array([WGS84_A, WGS84_A, WGS84_A * math.sqrt(1.0 - WGS84_E2)])  # the ellipsoid -> the unit sphere
    origin = np.array(pymap3d.geodetic2ecef(*frame))
    p0 = (origin + xy[..., :1] * axes[0] + xy[..., 1:2] * axes[1]) * scale
    up = axes[2] * scale
    b, c = p0 @ up, np.einsum("...i,...i", p0, p0) - 1.0
    disc = b * b - (up @ up) * c
    with np.errstate(invalid="ignore"):
        z = -c / (b + np.sqrt(disc))  # the upper root of |p0 + z up|^2 = 1, without cancellation
    enu = np.concatenate([xy[..., :2], z[..., None]], axis=-1)
    past = ~(disc >= 0)
    if past.any():  # the line's point nearest the centre, onto the unit sphere, back to the frame
        near = p0[past] - (b[past] / (up @ up))[:, None] * up
        enu[past] = (near / np.linalg.norm(near, axis=-1, keepdims=True) / scale - origin) @ axes.T
    return enu


def level_z(frame: Frame | None, xy: np.ndarray) -> np.ndarray:
    """The common frame's ``z`` (N,) of the origin's height carried over the Earth at east, north ``xy`` (N, 2):
    the ellipsoid's point along the origin's up (:func:`surface_enu`) raised by the origin's height ``frame.h``.
    0 at the origin, about ``-d^2 / 2R`` at ``d`` from it (7 km at 300 km): where a 3-D track started from a 2-D
    plot is centred, its altitude unknown (docs/geodetic.md, "A 2-D start on the Earth"). Without a frame (a flat
    world) 0."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if frame is None:
        return np.zeros(len(xy))
    return surface_enu(frame, xy)[:, 2] + frame.h


def surface_xy(frame: Frame, enu: np.ndarray) -> np.ndarray:
    """East, north (N, 2) in ``frame`` of the points of the WGS-84 ellipsoid below ENU positions (N, 3): each
    position's latitude and longitude at h = 0, what a 2-D position sensor on the Earth measures."""
    lla = geodetic_from_enu(frame, enu)
    return enu_from_geodetic(frame, lla[..., 0], lla[..., 1], np.zeros(lla.shape[:-1]))[..., :2]


def common_from_local_vectors(frame: Frame, lat: np.ndarray, lon: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors (N, 3) given in the ENU axes at each point ``lat``, ``lon`` (N,) [deg] (a ground speed's
    east, north, up), in the common frame's axes: ``R_origin R_point' v``."""
    phi, lam = np.radians(np.asarray(lat, float)), np.radians(np.asarray(lon, float))
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    e, n, u = v[..., 0], v[..., 1], v[..., 2]
    ecef = np.stack([-sl * e - sp * cl * n + cp * cl * u, cl * e - sp * sl * n + cp * sl * u, cp * n + sp * u], axis=-1)
    return ecef @ ecef_to_enu_rotation(frame.lat, frame.lon).T


def local_from_common_vectors(frame: Frame, lat: np.ndarray, lon: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The inverse of :func:`common_from_local_vectors`: vectors (N, 3) in the common frame's axes, in the
    ENU axes at each point ``lat``, ``lon`` (N,) [deg]: ``R_point R_origin' v``."""
    phi, lam = np.radians(np.asarray(lat, float)), np.radians(np.asarray(lon, float))
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    x, y, z = np.moveaxis(np.asarray(v, float) @ ecef_to_enu_rotation(frame.lat, frame.lon), -1, 0)
    return np.stack([-sl * x + cl * y, -sp * cl * x - sp * sl * y + cp * z, cp * cl * x + cp * sl * y + sp * z], axis=-1)


def site_from_geodetic(frame: Frame, lat: float, lon: float, h: float) -> RadarSite:
    """A radar standing at a WGS-84 point."""
    position = enu_from_geodetic(frame, np.array([lat]), np.array([lon]), np.array([h]))[0]
    rotation = ecef_to_enu_rotation(lat, lon) @ ecef_to_enu_rotation(frame.lat, frame.lon).T
    return RadarSite(position, rotation, np.array([lat, lon, h], float))


def site_from_enu(frame: Frame, position: np.ndarray) -> RadarSite:
    """A radar standing at a point of the common frame."""
    lat, lon, h = geodetic_from_enu(frame, np.asarray(position, float)).tolist()
    site = site_from_geodetic(frame, lat, lon, h)
    return site._replace(position=np.array(position, float))


@lru_cache(maxsize=64)
def own_axes(frame: Frame, position: tuple[float, float, float]) -> np.ndarray:
    """The rotation (3, 3) from the common frame's axes to the own east-north-up axes of a site at ``position``
    (common frame): :func:`site_from_enu`'s ``rotation``, kept for the sites a tracker sees scan after scan
    (read-only: every caller shares the cached array)."""
    rotation = site_from_enu(frame, np.array(position, float)).rotation.copy()
    rotation.flags.writeable = False
    return rotation


def own_from_enu(site: RadarSite, enu: np.ndarray) -> np.ndarray:
    """Positions (N, 3) in the site's own ENU frame of common-frame positions (N, 3)."""
    return (np.asarray(enu, float) - site.position) @ site.rotation.T


def enu_from_own(site: RadarSite, own: np.ndarray) -> np.ndarray:
    """Common-frame positions (N, 3) of positions (N, 3) in the site's own ENU frame."""
    return np.asarray(own, float) @ site.rotation + site.position


def aer_from_own(own: np.ndarray) -> np.ndarray:
    """``[azimuth from north rad in [0, 2 pi), elevation rad, range m]`` (N, 3) of own-frame positions.

    pymap3d's ``enu2aer`` without its rounding of components under 1 mm to zero (which would
    cost the round trip its 1e-9 m)."""
    e, n, u = own[..., 0], own[..., 1], own[..., 2]
    rho = np.hypot(e, n)
    return np.stack([np.mod(np.arctan2(e, n), 2 * np.pi), np.arctan2(u, rho), np.hypot(rho, u)], axis=-1)


def own_from_aer(aer: np.ndarray) -> np.ndarray:
    """Own-frame positions (N, 3) of ``[azimuth from north, elevation, range]`` (N, 3) (pymap3d's ``aer2enu``)."""
    az, el, r = aer[..., 0], aer[..., 1], aer[..., 2]
    rho = r * np.cos(el)
    return np.stack([rho * np.sin(az), rho * np.cos(az), r * np.sin(el)], axis=-1)


def aer_from_enu(site: RadarSite, enu: np.ndarray) -> np.ndarray:
    """What the radar at ``site`` measures of common-frame positions: ``[az, el, range]`` (N, 3)."""
    return aer_from_own(own_from_enu(site, enu))


def enu_from_aer(site: RadarSite, aer: np.ndarray) -> np.ndarray:
    """Common-frame positions (N, 3) of the radar's ``[az, el, range]`` (N, 3)."""
    return enu_from_own(site, own_from_aer(np.asarray(aer, float)))


#: WGS-84's semi-major axis [m] and first eccentricity squared
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: the effective Earth radius factor of standard atmospheric refraction (the "4/3 Earth" of radar
#: texts, e.g. Skolnik's: radar waves bend down, so a radar sees as if the Earth's radius were 4/3 of its own)
REFRACTION_K = 4.0 / 3.0


def gaussian_radius(lat: float) -> float:
    """The Earth's Gaussian radius of curvature [m] at geodetic latitude ``lat`` [deg],
    ``a sqrt(1 - e^2) / (1 - e^2 sin^2 lat)``: 6,335 km at the equator to 6,400 km at the poles."""
    return WGS84_A * math.sqrt(1.0 - WGS84_E2) / (1.0 - WGS84_E2 * math.sin(math.radians(lat)) ** 2)


def above_radio_horizon(site: RadarSite, enu: np.ndarray, k: float = REFRACTION_K) -> np.ndarray:
    """Whether the radar at ``site`` sees each common-frame position (N, 3) (N,): on a sphere of the
    Earth's Gaussian radius of curvature at the site (:func:`gaussian_radius`) ``R``, a
    target at height ``h_t`` and ground distance ``d`` from a radar at height ``h_r`` is in sight when
    ``d <= sqrt(2 k R h_r) + sqrt(2 k R h_t)``: the distances to the radio horizon of the radar and of
    the target, on the Earth of radius ``k R``. Heights are above the surface, taken at the ellipsoid or,
    for a radar below it (the Dead Sea's shore, -430 m), at the radar's own height (a target below the
    surface: 0); terrain is not modelled."""
    lat, _, h_site = site.geodetic
    radius = gaussian_radius(lat)
    own = own_from_enu(site, enu)
    up = own[..., 2] + radius + h_site  # from the ellipsoid sphere's centre, along the site's up
    h_t = np.hypot(np.hypot(own[..., 0], own[..., 1]), up) - radius
    d = radius * np.arctan2(np.hypot(own[..., 0], own[..., 1]), up)
    return d <= radio_reach(site, h_t, k)


def radio_reach(site: RadarSite, h_target: float | np.ndarray, k: float = REFRACTION_K) -> np.ndarray:
    """The ground distance [m] out to which the radar at ``site`` sees a target ``h_target`` [m] (each of
    an array) above the ellipsoid: :func:`above_radio_horizon`'s bound."""
    lat, _, h_site = site.geodetic
    surface, radius = min(h_site, 0.0), gaussian_radius(lat)
    return np.sqrt(2 * k * radius * (h_site - surface)) + np.sqrt(2 * k * radius * np.maximum(h_target - surface, 0.0))


def ground_angle(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """The angle [rad] between the ellipsoid normals at two geodetic points [deg] (times the Earth's
    radius, the ground distance between them)."""
    a, b = ecef_to_enu_rotation(lat1, lon1)[2], ecef_to_enu_rotation(lat2, lon2)[2]
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b))


#: the heights [m] a site or origin may have (``[frame]``, ``simulate traffic``): the Dead Sea's shore is at
#: -430 m and the ellipsoid's height of the geoid between -107 and +85 m; the highest radars and aircraft are
#: below 100 km
HEIGHTS = (-1.0e4, 1.0e5)


def geodetic_error(lat: float, lon: float, h: float) -> str | None:
    """Why ``lat``, ``lon`` [deg], ``h`` [m] is no place for an origin or a site (None: it is one)."""
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0 and HEIGHTS[0] <= h <= HEIGHTS[1]):
        return f"expected lat deg in [-90, 90], lon deg in [-180, 360], h m in [{HEIGHTS[0]:g}, {HEIGHTS[1]:g}]"
    return None


#: how far [m] a radar scan's ``sensor_position`` may lie from the common-frame place of its ``[frame.sites]``
#: site: the two are one point written twice, equal to round-off when both come from the same numbers; a
#: metre is below any radar's range noise, and far below the mistakes it catches (a height above mean sea
#: level for one above the ellipsoid: the geoid is -107 to +85 m from it; a site's latitude and longitude
#: swapped; a radar's plots given about another radar's site)
SITE_TOLERANCE_M = 1.0


def sensor_position_error(frame_cfg: FrameConfig, sensor: str, position: np.ndarray) -> str | None:
    """Why ``position`` (3,), a radar scan's ``sensor_position`` in the common frame of ``frame_cfg``, cannot be
    radar ``sensor``'s (None: it can): on the Earth no higher or lower than a site may be (:data:`HEIGHTS`);
    for a radar with a site in ``[frame.sites]``, ``position`` within :data:`SITE_TOLERANCE_M` of it (a radar
    without one, on a ship or one the table leaves out, is checked for its height only). Remembered for the
    last places asked about (a radar sends its one place with every scan)."""
    return _position_error(frame_cfg.origin, frame_cfg.sites.get(sensor), sensor,
                           tuple(np.asarray(position, float).tolist()))


@lru_cache(maxsize=256)
def _position_error(origin: tuple[float, float, float], site: tuple[float, float, float] | None,
                    sensor: str, position: tuple[float, float, float]) -> str | None:
    frame = Frame(*origin)
    lat, lon, h = geodetic_from_enu(frame, np.array(position)).tolist()
    if not HEIGHTS[0] <= h <= HEIGHTS[1]:
        return (f"sensor_position is {h:.6g} m above the WGS-84 ellipsoid (lat {lat:.6f}, lon {lon:.6f}), expected "
                f"h in [{HEIGHTS[0]:g}, {HEIGHTS[1]:g}] m: it is the radar's east, north, up [m] in the common "
                "frame of [frame] origin")
    if site is None:
        return None
    place = enu_from_geodetic(frame, *(np.array([v]) for v in site))[0]
    off = float(np.linalg.norm(np.array(position) - place))
    if off > SITE_TOLERANCE_M:
        return (f"sensor_position {np.round(position, 3).tolist()} is {off:.6g} m from the site of radar {sensor!r} "
                f"in [frame.sites], {list(site)}, at {np.round(place, 3).tolist()} in the common "
                f"frame (at most {SITE_TOLERANCE_M:g} m: heights are above the WGS-84 ellipsoid, not sea level)")
    return None


def _check_geodetic(value: tuple[float, float, float], key: str) -> None:
    problem = geodetic_error(*value)
    if problem:
        raise ConfigError(f"{key}: {problem}, got {list(value)}")


@dataclass(frozen=True)
class FrameConfig:
    """``[frame]``: the common frame's WGS-84 origin and (``[frame.sites]``) sensor sites in WGS-84."""

    origin: tuple[float, float, float]  # required: a frame placed nowhere in particular is an error
    sites: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # sensor id -> lat, lon, h

    def validate(self) -> None:
        _check_geodetic(self.origin, "origin")
        for sid, where in self.sites.items():
            _check_geodetic(where, f"sites.{sid}")

    @property
    def frame(self) -> Frame:
        return Frame(*self.origin)

    def radar_sites(self) -> dict[str, RadarSite]:
        """Each sensor of ``[frame.sites]`` as a :class:`RadarSite` of the common frame."""
        return {sid: site_from_geodetic(self.frame, *where) for sid, where in self.sites.items()}


@dataclass(frozen=True)
class FrameSettings:
    """The ``[frame]`` table alone, for the commands that read only it from a config file."""

    frame: FrameConfig | None = None


def load_frame(path: str | Path | None) -> FrameConfig | None:
    """The config file's ``[frame]`` (None without a file or without the table)."""
    return None if path is None else load_tables(path, FrameSettings).frame


def add_geodetic(frame: Frame, rows: list[dict[str, Any]], init_z_std: float | None = None) -> list[dict[str, Any]]:
    """Picture or truth rows (each with ``x`` = ``[x, vx, y, vy(, z, vz)]``) with ``lat``, ``lon`` [deg]
    and, for a 3-D state, ``alt`` [m above the ellipsoid] beside ``x`` (:func:`fedtrack.wire.with_geodetic`;
    a 2-D state on the ellipsoid: :func:`geodetic_of_states`). With ``init_z_std`` (``[mtt]``'s), a 3-D
    track row (with ``P``) whose altitude is not measured (:func:`altitude_unmeasured`) is placed at the
    origin's height and marked ``"alt_measured": false``."""
    lla = np.zeros((len(rows), 3))
    flat = np.zeros(len(rows), bool)
    sizes = np.array([len(row["x"]) for row in rows])
    for size in set(sizes.tolist()):  # one batch per state size
        which = np.flatnonzero(sizes == size)
        P = None
        if size == 6 and init_z_std is not None and all("P" in rows[i] for i in which):
            P = np.array([rows[i]["P"] for i in which], float)
            flat[which] = altitude_unmeasured(P, init_z_std)
        lla[which] = geodetic_of_states(frame, np.array([rows[i]["x"] for i in which], float), P, init_z_std)
    return with_geodetic(rows, lla, tuple((~flat).tolist()) if flat.any() else ())


def picture_geodetic(frame: Frame | None, X: np.ndarray, P: np.ndarray,
                     init_z_std: float | None) -> tuple[np.ndarray | None, tuple[bool, ...]]:
    """A live picture's ``TrackPicture.lla`` and ``alt_measured`` for states ``X`` (n, d), ``P`` (n, d, d):
    :func:`geodetic_of_states`, and per track whether its altitude was measured (:func:`altitude_unmeasured`),
    empty when every one was, so that ``serve mtt-centre`` and ``serve picture`` mark a track as ``replay`` does
    (:func:`add_geodetic`). Without a frame ``(None, ())``."""
    if frame is None:
        return None, ()
    flat = np.zeros(len(X), bool)
    if X.shape[1] == 6 and init_z_std is not None:
        flat = altitude_unmeasured(P, init_z_std)
    return geodetic_of_states(frame, X, P, init_z_std), tuple((~flat).tolist()) if flat.any() else ()


def altitude_unmeasured(P: np.ndarray, init_z_std: float) -> np.ndarray:
    """Which 3-D states (covariances ``P`` (n, 6, 6)) carry an altitude that is more the prior's than measured:
    a variance above half the one-point start's ``init_z_std^2``, the rule ``initiation.unmeasured`` applies to
    the velocity (their altitude plots gave less information than the prior had): never measured (a 2-D
    sensor's track), or measured so long ago that the motion's noise has spread it that wide (a radar's altitude
    gone stale below its horizon; docs/geodetic.md, "Altitudes nobody measured")."""
    return np.asarray(P, float)[:, 4, 4] > 0.5 * init_z_std**2


def geodetic_of_states(frame: Frame, X: np.ndarray, P: np.ndarray | None = None,
                       init_z_std: float | None = None) -> np.ndarray:
    """``[lat, lon, h]`` (n, 3) of the positions of states ``X`` (n, 4 or 6): a 3-D state's position, a 2-D
    state's point of the ellipsoid at its x, y (:func:`surface_enu`, the inverse of what a 2-D position sensor
    measures: :func:`surface_xy`). Given ``P`` and ``init_z_std``, a 3-D state whose altitude is not measured
    (:func:`altitude_unmeasured`) is placed at its x, y at the origin's height (:func:`level_z`, the prior's
    centre) instead of its extrapolated z (before 2026-11-28 a descent extrapolated for minutes put aircraft
    2.3 km underground)."""
    X = np.asarray(X, float)
    if X.shape[1] == 4:
        return geodetic_from_enu(frame, surface_enu(frame, X[:, [0, 2]]))
    enu = X[:, [0, 2, 4]]
    if P is not None and init_z_std is not None:
        flat = altitude_unmeasured(P, init_z_std)
        if flat.any():
            enu = enu.copy()
            enu[flat, 2] = level_z(frame, X[flat][:, [0, 2]])
    return geodetic_from_enu(frame, enu)


#: the lowest the Earth's surface lies anywhere [m above the WGS-84 ellipsoid]: the lowest land, the Dead Sea's
#: shore at -430 m, over the geoid's lowest height above the ellipsoid, -107 m (:data:`HEIGHTS`); nothing that
#: flies is below it, wherever it is (docs/geodetic.md, "Altitudes below the Earth")
LOWEST_SURFACE_H = -537.0


def above_the_surface(frame: Frame, X: np.ndarray, P: np.ndarray,
                      init_z_std: float) -> tuple[np.ndarray, np.ndarray]:
    """3-D states ``X`` (n, 6), ``P`` (n, 6, 6) whose altitude was measured (not :func:`altitude_unmeasured`)
    conditioned on being above the Earth's lowest surface, ``z >= z_s`` with ``z_s`` the ellipsoid below the
    state's x, y (:func:`surface_enu`) raised by :data:`LOWEST_SURFACE_H`: the Gaussian's altitude truncated
    there, its mean and variance the truncated normal's, ``mu + sigma lam`` and ``sigma^2 (1 - lam (lam - a))``
    with ``a = (z_s - mu) / sigma`` and ``lam = phi(a) / (1 - Phi(a))`` (Johnson, Kotz and Balakrishnan,
    *Continuous Univariate Distributions* 1, eq. 13.134-13.135), carried to the other components by their
    regression on z (Simon, *Kalman filtering with state constraints*, IET CTA 2010, section 4.3, "PDF
    truncation"). A state far above (``a`` below -38) is returned unchanged to the bit; a 2-D state, or one whose
    altitude nobody measured (shown at the origin's height, scored on x, y), as given."""
    from scipy.special import erfcx

    X, P = np.asarray(X, float), np.asarray(P, float)
    if X.shape[1] != 6 or not len(X):
        return X, P
    live = np.flatnonzero(~altitude_unmeasured(P, init_z_std))
    var = P[live, 4, 4]
    sigma = np.sqrt(var)
    a = (surface_enu(frame, X[live][:, [0, 2]])[:, 2] + LOWEST_SURFACE_H - X[live, 4]) / sigma
    with np.errstate(over="ignore"):
        lam = math.sqrt(2.0 / math.pi) / erfcx(a / math.sqrt(2.0))  # phi(a) / (1 - Phi(a)), without underflow
    # the variance's fall, lam (lam - a); past a = 1e3 its asymptote 1 - 1/a^2, where the difference cancels
    fall = np.where(a > 1e3, 1.0 - 1.0 / np.maximum(a, 1e3) ** 2, lam * (lam - a))
    gain = P[live, :, 4] / var[:, None]  # each component's regression on z
    X, P = X.copy(), P.copy()
    X[live] += gain * (sigma * lam)[:, None]
    P[live] -= fall[:, None, None] * gain[:, :, None] * P[live, None, 4, :]
    P[live] = 0.5 * (P[live] + np.swapaxes(P[live], 1, 2))
    return X, P


def geodetic_line(line: str, frame: Frame, init_z_std: float | None = None) -> str:
    """A tracks-file line (``{"t", "tracks"}``) with :func:`add_geodetic`'s fields in each track."""
    obj = orjson.loads(line)
    obj["tracks"] = add_geodetic(frame, obj["tracks"], init_z_std)
    return orjson.dumps(obj).decode()
