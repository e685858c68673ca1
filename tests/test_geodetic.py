"""fedtrack.geodetic: WGS-84 <-> common ENU <-> each radar's own azimuth-elevation-range frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import pytest

from fedtrack.config import ConfigError, parse_dataclass
from fedtrack.geodetic import (
    Frame,
    FrameConfig,
    add_geodetic,
    aer_from_enu,
    enu_from_aer,
    enu_from_geodetic,
    geodetic_from_enu,
    load_frame,
    own_axes,
    own_from_aer,
    own_from_enu,
    site_from_enu,
    site_from_geodetic,
    surface_enu,
    surface_xy,
)

# origins: equator, Paris, Alaska (west, high latitude), Sydney, near the pole, the antimeridian
ORIGINS = [(0.0, 0.0, 0.0), (48.86, 2.35, 35.0), (61.2, -149.9, 40.0), (-33.9, 151.2, 10.0),
           (84.0, 20.0, 0.0), (10.0, 179.9, 0.0)]


def _grid(frame: Frame, spread_m: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` WGS-84 points (n, 3) up to ``spread_m`` from the origin in each horizontal direction, 0-13 km up."""
    enu = np.column_stack([rng.uniform(-spread_m, spread_m, (n, 2)), rng.uniform(0.0, 13000.0, n)])
    return geodetic_from_enu(frame, enu)


def _ecef(lla: np.ndarray) -> np.ndarray:
    return np.column_stack(pymap3d.geodetic2ecef(lla[:, 0], lla[:, 1], lla[:, 2]))


@pytest.mark.parametrize("origin", ORIGINS)
def test_wgs84_enu_round_trip_within_a_micrometre(origin: tuple[float, float, float]) -> None:
    frame = Frame(*origin)
    lla = _grid(frame, 400e3, 2000, np.random.default_rng(1))
    back = geodetic_from_enu(frame, enu_from_geodetic(frame, lla[:, 0], lla[:, 1], lla[:, 2]))
    err = np.linalg.norm(_ecef(back) - _ecef(lla), axis=1)  # metres on the Earth
    assert err.max() < 1e-6, err.max()


@pytest.mark.parametrize("origin", ORIGINS)
def test_a_2d_state_is_placed_where_a_2d_sensor_measured_it(origin: tuple[float, float, float]) -> None:
    """A 2-D position sensor measures the point of the ellipsoid below an aircraft (``surface_xy``); a 2-D state
    at those x, y goes back to that point's latitude and longitude (``surface_enu``, ``add_geodetic``) within a
    micrometre, aircraft up to 400 km from the origin and 0-13 km up (placed on the common frame's plane before:
    off by about z d / R, 800 m at 400 km)."""
    frame = Frame(*origin)
    lla = _grid(frame, 400e3, 2000, np.random.default_rng(3))
    xy = surface_xy(frame, enu_from_geodetic(frame, lla[:, 0], lla[:, 1], lla[:, 2]))
    back = geodetic_from_enu(frame, surface_enu(frame, xy))
    assert np.abs(back[:, 2]).max() < 1e-6
    err = np.linalg.norm(_ecef(back) - _ecef(np.column_stack([lla[:, :2], np.zeros(len(lla))])), axis=1)
    assert err.max() < 1e-6, err.max()
    rows = add_geodetic(frame, [{"x": [x, 0.0, y, 0.0]} for x, y in xy[:50].tolist()])
    assert np.allclose([[r["lat"], r["lon"]] for r in rows], back[:50, :2], rtol=0, atol=1e-9)
    assert not any("alt" in r for r in rows)


@pytest.mark.parametrize("origin", ORIGINS)
def test_a_2d_state_past_the_limb_is_placed_at_the_limb(origin: tuple[float, float, float]) -> None:
    """A 2-D state 6,000 km and more from the origin (its line along the origin's up misses the ellipsoid: no
    2-D sensor on the Earth measures there) had NaN latitude and longitude, and a picture holding one was
    refused by every receiver. It is now placed at the ellipsoid's point nearest its line (on the ellipsoid,
    continuous at the limb), however far out (up to the wire's 1e100 m)."""
    frame = Frame(*origin)
    for angle in np.linspace(0.0, 2 * np.pi, 13)[:-1]:
        direction = np.array([np.cos(angle), np.sin(angle)])
        inside, past = 1e6, 1e8  # the limb between them: bisect it
        for _ in range(100):
            mid = (inside + past) / 2
            inside, past = (mid, past) if np.allclose(surface_enu(frame, mid * direction[None])[0, :2], mid * direction,
                                                      rtol=0, atol=1e-6) else (inside, mid)
        near = surface_enu(frame, np.array([inside, past])[:, None] * direction)
        assert np.linalg.norm(near[0] - near[1]) < 1e-3  # continuous at the limb
        far = np.array([2 * past, 1e9, 1e30, 1e99])[:, None] * direction
        lla = add_geodetic(frame, [{"x": [x, 0.0, y, 0.0]} for x, y in far.tolist()])
        lat_lon = np.array([[r["lat"], r["lon"]] for r in lla])
        assert np.isfinite(lat_lon).all()
        assert (np.abs(lat_lon[:, 0]) <= 90).all() and (np.abs(lat_lon[:, 1]) <= 180).all()
        assert np.abs(geodetic_from_enu(frame, surface_enu(frame, far))[:, 2]).max() < 1e-3  # on the ellipsoid


@pytest.mark.parametrize("origin", ORIGINS)
def test_radar_frame_round_trip_exact(origin: tuple[float, float, float]) -> None:
    """Sites up to 200 km from the origin (given in WGS-84 and in ENU), targets up to 400 km from each."""
    frame = Frame(*origin)
    rng = np.random.default_rng(2)
    sites = [site_from_geodetic(frame, *where) for where in _grid(frame, 200e3, 4, rng).tolist()]
    sites += [site_from_enu(frame, np.array([*rng.uniform(-200e3, 200e3, 2), 50.0])) for _ in range(4)]
    for site in sites:
        enu = site.position + np.column_stack([rng.uniform(-280e3, 280e3, (3000, 2)), rng.uniform(-5e3, 13e3, 3000)])
        back = enu_from_aer(site, aer_from_enu(site, enu))
        assert np.abs(back - enu).max() < 1e-9


def test_radar_frame_agrees_with_pymap3d_geodetic2aer() -> None:
    """Our rigid-motion radar frame is pymap3d's azimuth-elevation-range through ECEF (another path)."""
    frame = Frame(48.86, 2.35, 35.0)
    rng = np.random.default_rng(3)
    for lat, lon, h in _grid(frame, 200e3, 3, rng).tolist():
        site = site_from_geodetic(frame, lat, lon, h)
        lla = _grid(frame, 400e3, 500, rng)
        ours = aer_from_enu(site, enu_from_geodetic(frame, lla[:, 0], lla[:, 1], lla[:, 2]))
        az, el, r = pymap3d.geodetic2aer(lla[:, 0], lla[:, 1], lla[:, 2], lat, lon, h)
        az, el = np.radians(az), np.radians(el)
        assert np.abs(ours[:, 2] - r).max() < 1e-6
        # angles as metres across the line of sight
        assert np.abs(np.angle(np.exp(1j * (ours[:, 0] - az))) * r * np.cos(el)).max() < 1e-6
        assert np.abs((ours[:, 1] - el) * r).max() < 1e-6


def test_pymap3d_published_examples() -> None:
    """pymap3d's own test values (tests/test_aer.py): aer2enu(33 deg, 70 deg, 1000 m) and the ECEF point
    that lies at that azimuth, elevation and range from (42 deg, -82 deg, 200 m)."""
    own = own_from_aer(np.array([[np.radians(33.0), np.radians(70.0), 1000.0]]))[0]
    np.testing.assert_allclose(own, [186.2775, 286.8422, 939.6926], atol=1e-4)
    frame = Frame(42.5, -81.0, 0.0)  # a common frame about 100 km from the site
    site = site_from_geodetic(frame, 42.0, -82.0, 200.0)
    lat, lon, h = pymap3d.ecef2geodetic(660930.19276, -4701424.22296, 4246579.60463)
    aer = aer_from_enu(site, enu_from_geodetic(frame, np.array([lat]), np.array([lon]), np.array([h])))[0]
    np.testing.assert_allclose([np.degrees(aer[0]), np.degrees(aer[1]), aer[2]], [33.0, 70.0, 1000.0], rtol=1e-7)
    # straight up from the site: the site's own up, not the origin's (about 0.9 deg apart here)
    up = enu_from_aer(site, np.array([[0.0, np.pi / 2, 5.0]]))
    np.testing.assert_allclose(own_from_enu(site, up), [[0.0, 0.0, 5.0]], atol=1e-9)
    above = pymap3d.aer2geodetic(0.0, 90.0, 5.0, 42.0, -82.0, 200.0)
    np.testing.assert_allclose(up[0], enu_from_geodetic(frame, *above), atol=1e-6)
    assert np.hypot(*(up - site.position)[0, :2]) > 0.05  # tilted against the origin's up by about 0.9 deg
    np.testing.assert_allclose(enu_from_geodetic(frame, *map(np.array, ([42.5], [-81.0], [0.0]))), [[0, 0, 0]],
                               atol=1e-9)


def test_frame_config_validates_and_names_the_key() -> None:
    cfg = parse_dataclass(FrameConfig, {"origin": [48.86, 2.35, 35.0], "sites": {"r1": [49.0, 2.0, 100.0]}}, "frame")
    assert cfg.frame == Frame(48.86, 2.35, 35.0)
    with pytest.raises(ConfigError, match=r"frame\.origin"):
        parse_dataclass(FrameConfig, {"origin": [95.0, 2.0, 0.0]}, "frame")
    with pytest.raises(ConfigError, match=r"frame\.sites\.r2"):
        parse_dataclass(FrameConfig, {"sites": {"r2": [10.0, 2.0]}}, "frame")


def test_frame_table_in_the_config_file(tmp_path) -> None:
    from fedtrack.deploy.settings import load_settings

    path = tmp_path / "c.toml"
    path.write_text("[frame]\norigin = [48.86, 2.35, 35.0]\n[frame.sites]\nr1 = [49.0, 2.0, 100.0]\n")
    assert load_settings(path).frame.sites["r1"] == (49.0, 2.0, 100.0)
    path.write_text("[frame]\norigen = [48.86, 2.35, 35.0]\n")
    with pytest.raises(ConfigError, match=r"c\.toml: unknown config key frame\.origen"):
        load_settings(path)


def test_local_vectors_turned_into_the_common_frame() -> None:
    """A velocity in the ENU axes at a point 300 km away is the common-frame displacement per second."""
    from fedtrack.geodetic import common_from_local_vectors

    frame = Frame(48.86, 2.35, 35.0)
    lla = _grid(frame, 300e3, 200, np.random.default_rng(4))
    v = np.random.default_rng(5).uniform(-250.0, 250.0, (200, 3))
    ecef = _ecef(lla) + np.column_stack(pymap3d.enu2uvw(v[:, 0], v[:, 1], v[:, 2], lla[:, 0], lla[:, 1])) * 1e-3
    moved = np.column_stack(pymap3d.ecef2geodetic(ecef[:, 0], ecef[:, 1], ecef[:, 2]))
    expected = (enu_from_geodetic(frame, *moved.T) - enu_from_geodetic(frame, *lla.T)) * 1e3
    np.testing.assert_allclose(common_from_local_vectors(frame, lla[:, 0], lla[:, 1], v), expected, atol=1e-5)


def test_a_frame_without_its_origin_is_refused(tmp_path: Path) -> None:
    """``[frame]`` without ``origin`` placed the common frame at (0, 0, 0), off West Africa, without a word
    (sites given in WGS-84 then landed thousands of km away); its origin is now required."""
    path = tmp_path / "c.toml"
    path.write_text("[frame]\n[frame.sites]\nr1 = [48.0, 2.0, 100.0]\n")
    with pytest.raises(ConfigError, match=r"missing config key frame.origin"):
        load_frame(path)


def test_own_axes_are_the_sites_rotation_and_read_only() -> None:
    """``own_axes`` (cached per frame and site, as a tracker asks scan after scan) equals
    ``site_from_enu``'s rotation, and the shared array cannot be written: a caller changing it in
    place would have turned every later scan's view of that radar."""
    frame, position = Frame(51.5, 0.0), (-195e3, 1e3, 50.0)
    axes = own_axes(frame, position)
    np.testing.assert_array_equal(axes, site_from_enu(frame, np.array(position)).rotation)
    with pytest.raises(ValueError):
        axes[0, 0] = 2.0
    assert own_axes(frame, position) is axes
