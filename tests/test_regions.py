"""Regions of a deployment (local_filters/regions.py): config, ownership, margins."""

from __future__ import annotations

import dataclasses
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fedtrack.config import ConfigError
from fedtrack.geodetic import Frame, enu_from_geodetic
from fedtrack.keys import check_id
from fedtrack.local_filters import regions as regions_module
from fedtrack.local_filters.mtt.local import LocalReport
from fedtrack.local_filters.mtt.routing import RegionRouter
from fedtrack.local_filters.regions import (
    PolygonConfig,
    RegionsConfig,
    _crossings,
    _inside_and_edge,
    _inside_and_edge_of,
    distances,
    grid_over,
    grid_regions,
    load_regions,
    near_regions,
    parse_grid_spec,
    region_of,
    regions_of_config,
)


def test_grid_owner_is_the_cell_by_floor_and_margin_reaches_neighbours() -> None:
    regions = grid_regions((-100.0, -50.0), (100.0, 50.0), 2, 2, margin=10.0)
    assert regions.ids == ("x0y0", "x1y0", "x0y1", "x1y1")
    assert all(check_id(i) == i for i in regions.ids)
    rng = np.random.default_rng(5)
    pos = rng.uniform((-100, -50), (100, 50), (2000, 2))
    i = np.floor((pos[:, 0] + 100) / 100).astype(int)
    j = np.floor((pos[:, 1] + 50) / 50).astype(int)
    assert np.array_equal(region_of(regions, pos), i + 2 * j)
    near = near_regions(regions, pos)
    # a position within the margin of the x = 0 border is also in the cell across it
    across = np.abs(pos[:, 0]) <= 10.0
    assert np.all(near[across, (1 - i[across]) + 2 * j[across]])
    far = (np.abs(pos[:, 0]) > 10.0) & (np.abs(pos[:, 1]) > 10.0)
    assert np.all(near[far].sum(axis=1) == 1)


def test_distance_to_a_rectangle_matches_the_closed_form() -> None:
    regions = grid_regions((0.0, 0.0), (4.0, 2.0), 1, 1, margin=0.0)
    rng = np.random.default_rng(1)
    pos = rng.uniform(-10, 10, (500, 2))
    dx = np.maximum.reduce([0 - pos[:, 0], pos[:, 0] - 4, np.zeros(500)])
    dy = np.maximum.reduce([0 - pos[:, 1], pos[:, 1] - 2, np.zeros(500)])
    assert np.allclose(distances(regions, pos)[:, 0], np.hypot(dx, dy), atol=1e-12)


def test_outside_every_region_the_nearest_owns(tmp_path: Path) -> None:
    regions = grid_regions((0.0, 0.0), (10.0, 10.0), 3, 1, margin=1.0)
    assert region_of(regions, np.array([[-50.0, 5.0], [100.0, 5.0], [15.0, 40.0]])).tolist() == [0, 2, 1]


def jagged_border_regions(n: int) -> RegionsConfig:
    """Two regions sharing a border of ``n`` vertices, zigzagging north-south (a real border's detail)."""
    border = np.stack([300.0 * np.sin(np.arange(n) * 0.7), np.linspace(-50e3, 50e3, n)], axis=1)
    west = np.concatenate([border, [[-60e3, 50e3], [-60e3, -50e3]]])
    east = np.concatenate([border[::-1], [[60e3, -50e3], [60e3, 50e3]]])
    return RegionsConfig(margin=100.0, polygon=(PolygonConfig("w", points=tuple(map(tuple, west.tolist()))),
                                                PolygonConfig("e", points=tuple(map(tuple, east.tolist())))))


def test_a_border_of_many_vertices_is_checked_in_bounded_memory() -> None:
    """The simple-polygon and overlap checks took memory in the square of the vertices (every edge
    against every edge, every probe against every edge at once): 258 MB at 1,500 vertices, 1 GB at
    3,000 (the process's peak RSS), so each service of a deployment whose regions follow a real
    border ran out of memory at start. Now 60 MB (CHUNK) whatever the size."""
    tracemalloc.start()
    try:
        regions = regions_of_config(jagged_border_regions(1500), None)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert regions.vertices.shape == (2, 1502, 2)
    assert peak < 100e6
    cfg = jagged_border_regions(300)  # the east region's border moved 1 km west, over the west one
    east = tuple(map(tuple, (np.array(cfg.polygon[1].points) - [1000.0, 0.0]).tolist()))
    moved = dataclasses.replace(cfg, polygon=(cfg.polygon[0], dataclasses.replace(cfg.polygon[1], points=east)))
    with pytest.raises(ConfigError, match="regions.polygon.e.points: overlaps region w"):
        regions_of_config(moved, None)


def test_crossings_tested_by_boxes_are_every_pair_tested_at_once() -> None:
    """``_crossings`` tests only edges whose bounding boxes meet: the same pairs as the test of every
    edge against every edge, on random polygons with shared vertices and collinear edges."""
    rng = np.random.default_rng(7)

    def dense(a: np.ndarray, b: np.ndarray, tol: float) -> np.ndarray:
        a0, a1, b0, b1 = a[:, None], np.roll(a, -1, axis=0)[:, None], b[None], np.roll(b, -1, axis=0)[None]

        def side(o: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
            cross = ((p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1])
                     - (p[..., 1] - o[..., 1]) * (q[..., 0] - o[..., 0]))
            return np.where(np.abs(cross) > tol * np.hypot(p[..., 0] - o[..., 0], p[..., 1] - o[..., 1]),
                            np.sign(cross), 0.0)

        return np.argwhere((side(b0, b1, a0) * side(b0, b1, a1) < 0) & (side(a0, a1, b0) * side(a0, a1, b1) < 0))

    found = 0
    for _ in range(200):
        a = rng.integers(0, 6, (int(rng.integers(3, 12)), 2)).astype(float)  # on a small lattice: touching, collinear
        b = np.concatenate([a[: int(rng.integers(1, len(a)))], rng.integers(0, 6, (int(rng.integers(2, 9)), 2))])
        for x, y in ((a, a), (a, b.astype(float))):
            got = _crossings(x, y, 1e-9)
            assert np.array_equal(got, dense(x, y, 1e-9))
            found += len(got)
    assert found > 1000


def test_distances_in_chunks_are_the_one_pass_distances(monkeypatch: pytest.MonkeyPatch) -> None:
    regions = regions_of_config(jagged_border_regions(100), None)
    pos = np.random.default_rng(3).uniform(-70e3, 70e3, (300, 2))
    monkeypatch.setattr(regions_module, "CHUNK", 5000)  # 24 positions of 2 x 102 edges a chunk: 13 chunks
    inside, edge = _inside_and_edge(regions, pos)
    once_inside, once_edge = _inside_and_edge_of(regions, pos)
    assert np.array_equal(inside, once_inside) and np.array_equal(edge, once_edge)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


def test_concave_polygons_from_config(tmp_path: Path) -> None:
    path = write(tmp_path, """
[regions]
margin = 1.0
[[regions.polygon]]
id = "ell"
points = [[0, 0], [10, 0], [10, 2], [2, 2], [2, 10], [0, 10]]
[[regions.polygon]]
id = "rest"
points = [[2, 2], [10, 2], [10, 10], [2, 10]]
""")
    regions = load_regions(path)
    assert regions is not None and regions.ids == ("ell", "rest")
    pos = np.array([[0.5, 9.0], [9.0, 0.5], [5.0, 5.0], [2.5, 5.0], [20.0, 20.0]])
    assert region_of(regions, pos).tolist() == [0, 0, 1, 1, 1]
    assert near_regions(regions, pos).tolist() == [[True, False], [True, False], [False, True], [True, True],
                                                   [False, True]]


def test_lat_lon_polygons_go_through_the_frame(tmp_path: Path) -> None:
    path = write(tmp_path, """
[frame]
origin = [52.0, 4.0, 0.0]
[regions]
margin = 100.0
[[regions.polygon]]
id = "box"
lat_lon = [[51.99, 3.99], [51.99, 4.01], [52.01, 4.01], [52.01, 3.99]]
""")
    regions = load_regions(path)
    corner = enu_from_geodetic(Frame(52.0, 4.0, 0.0), np.array([51.99]), np.array([3.99]), np.zeros(1))[0, :2]
    assert np.allclose(regions.vertices[0, 0], corner, atol=1e-9)
    assert region_of(regions, np.zeros((1, 2))).tolist() == [0]


def test_sectors_meeting_at_a_pole_given_at_their_own_longitudes_share_it(tmp_path: Path) -> None:
    """The pole is one place whatever longitude names it; converted, [90, 0] and [90, 45] lie some
    1e-10 m apart, and two sectors sharing the edge to it were refused as overlapping (192 of 200
    random such caps before 2026-11-27)."""
    path = write(tmp_path, """
[frame]
origin = [89.5, 0.0, 0.0]
[regions]
margin = 2000.0
""" + "".join(f"""[[regions.polygon]]
id = "s{k}"
lat_lon = [[88.0, {lo}], [88.0, {hi}], [90.0, {pole}]]
""" for k, (lo, hi, pole) in enumerate([(0, 90, 0), (90, 180, 90), (180, 270, 180), (270, 360, 45)])))
    regions = load_regions(path)
    lon = np.array([45.0, 135.0, 225.0, 315.0])
    xy = enu_from_geodetic(Frame(89.5, 0.0), np.full(4, 88.5), lon, np.zeros(4))[:, :2]
    assert region_of(regions, xy).tolist() == [0, 1, 2, 3]


def test_two_regions_meeting_on_a_third_ones_side_along_a_parallel_share_its_border(tmp_path: Path) -> None:
    """A south region and two north ones split at a meridian: the north ones' corner on the south one's
    side (a T-junction) split that side, so the three share one border. Before 2026-11-27 each edge was the
    chord between its ends: the south side's chord (2.7 deg) ran north of the north ones' (1.3 deg each)
    and the config was refused as overlapping."""
    path = write(tmp_path, """
[frame]
origin = [46.954, 7.738, 0.0]
[regions]
margin = 2000.0
[[regions.polygon]]
id = "south"
lat_lon = [[46.0, 6.4], [46.0, 9.1], [46.954, 9.1], [46.954, 6.4]]
[[regions.polygon]]
id = "nw"
lat_lon = [[46.954, 6.4], [46.954, 7.738], [47.9, 7.738], [47.9, 6.4]]
[[regions.polygon]]
id = "ne"
lat_lon = [[46.954, 7.738], [46.954, 9.1], [47.9, 9.1], [47.9, 7.738]]
""")
    regions = load_regions(path)
    frame = Frame(46.954, 7.738, 0.0)
    corner = enu_from_geodetic(frame, np.array([46.954]), np.array([7.738]), np.zeros(1))[0, :2]
    assert any(np.array_equal(v, corner) for v in regions.vertices[0])  # the south side split at the corner
    lat, lon = np.array([46.5, 47.5, 47.5, 46.96, 46.96]), np.array([7.0, 7.0, 8.5, 6.5, 9.0])
    xy = enu_from_geodetic(frame, lat, lon, np.zeros(5))[:, :2]
    assert [regions.ids[i] for i in region_of(regions, xy)] == ["south", "nw", "ne", "nw", "ne"]
    assert (distances(regions, xy) == 0).sum(axis=1).tolist() == [1] * 5  # inside exactly one


def test_a_lat_lon_vertex_on_the_far_side_of_the_earth_is_an_error(tmp_path: Path) -> None:
    """Beyond 90 deg from the origin the local frame's x, y fold back: this box in the South Pacific
    (the mirror image of the area 1-2 deg east of Paris) took aircraft over Reims."""
    path = write(tmp_path, """
[frame]
origin = [48.8, 2.3, 0.0]
[regions]
margin = 1000.0
[[regions.polygon]]
id = "home"
lat_lon = [[48.3, 1.8], [48.3, 2.8], [49.3, 2.8], [49.3, 1.8]]
[[regions.polygon]]
id = "far"
lat_lon = [[-49.29, -178.92], [-49.26, -179.94], [-48.26, -179.85], [-48.29, -178.88]]
""")
    with pytest.raises(ConfigError) as exc:
        load_regions(path)
    assert str(exc.value).startswith(f"{path}: regions.polygon.far.lat_lon: vertex 1 [-49.29, -178.92] is 90 deg")
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("body, message", [
    ("[regions]\ngrid = {origin = [0, 0], cell = [1, 1], nx = 2, ny = 2}\n", "missing config key regions.margin"),
    ("[regions]\nmargin = 1.0\n", "give exactly one of grid, polygon"),
    ("[regions]\nmargin = -1.0\ngrid = {origin = [0, 0], cell = [1, 1], nx = 2, ny = 2}\n", "margin: must be >= 0"),
    ("[regions]\nmargin = 1.0\ngrid = {origin = [0, 0], cell = [0, 1], nx = 2, ny = 2}\n", "cell: both sizes"),
    ("[regions]\nmargin = 1.0\ngrid = {origin = [0, 0], cell = [1, 1], nx = 0, ny = 2}\n", "nx, ny"),
    ("[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"a/b\"\npoints = [[0, 0], [1, 0], [0, 1]]\n",
     "forbidden character"),
    # a key chunk, but not a TLS identity's name: launch with [zenoh] tls_dir refused it only after simulating
    # the scenario, naming zenoh.tls_dir
    ("[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"Côte_d'Azur\"\npoints = [[0, 0], [1, 0], [0, 1]]\n",
     "regions.polygon[0].id \"Côte_d'Azur\": letters, digits, . _ - only"),
    ("[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"a\"\npoints = [[0, 0], [1, 0]]\n", "at least 3"),
    ("[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"a\"\nlat_lon = [[0, 0], [1, 0], [0, 1]]\n",
     "needs [frame] origin"),
    (("[frame]\norigin = [48.0, 2.0, 0.0]\n[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"a\"\n"
      "lat_lon = [[48, 2], [48, 1e300], [49, 2]]\n"), "a: lat_lon vertex 2 [48.0, 1e"),
    # a cap about the pole as a box of latitudes and longitudes: two pairs of vertices, each one place
    (("[frame]\norigin = [89.6, 2.4, 0.0]\n[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = \"cap\"\n"
      "lat_lon = [[89.0, -180.0], [89.0, 180.0], [90.0, 180.0], [90.0, -180.0]]\n"),
     "cap.lat_lon: encloses no area: vertices 1 [89.0, -180.0] and 2 [89.0, 180.0] are one place"),
    ("[regions]\nmargin = 1.0\nsize = 3\ngrid = {origin = [0, 0], cell = [1, 1], nx = 2, ny = 2}\n",
     "unknown config key regions.size"),
])
def test_bad_regions_config_names_the_key(tmp_path: Path, body: str, message: str) -> None:
    path = write(tmp_path, body)
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")) as exc:
        load_regions(path)
    assert str(exc.value).startswith(str(path))


def test_grid_spec_and_grid_over_the_data() -> None:
    assert parse_grid_spec("2x4") == (2, 4)
    for bad in ("2", "0x2", "ax2", "2x2x2", "200x200", "\u00b2x2"):  # a superscript 2 is a digit to isdigit, not to int
        with pytest.raises(ConfigError, match="--regions"):
            parse_grid_spec(bad)
    pos = np.array([[0.0, 0.0], [10.0, 4.0], [3.0, 1.0]])
    regions = grid_over(pos, 2, 2, 0.5)
    assert np.allclose(regions.vertices[3, 2], [10.0, 4.0])
    assert region_of(regions, pos).tolist() == [0, 3, 0]


def test_a_row_goes_to_its_believed_holder_however_far_beyond_the_margin() -> None:
    """The hand-over hysteresis keeps a track with its holder up to ``margin`` outside the holder's
    region: the holder must keep getting the row there, and beyond (the router's belief, not the
    margin, sends it), flagged not ``elsewhere`` for the holder and ``elsewhere`` for the rest."""
    regions = grid_regions((0.0, 0.0), (1000.0, 1000.0), 3, 1, 100.0)
    x = np.array([[150.0, 0.0, 500.0, 0.0], [1050.0, 0.0, 500.0, 0.0], [2950.0, 0.0, 500.0, 0.0]])
    report = LocalReport("s1", 1.0, np.array([4, 5, 6]), x, np.tile(np.eye(4), (3, 1, 1)), np.ones(3, bool),
                         np.zeros(3, bool), np.zeros((0, 2, 4)), np.zeros((0, 2, 2)), np.zeros((0, 2)),
                         np.zeros(0, bool), np.zeros(0, np.int64))
    router = RegionRouter(regions, 5.0, holder={4: 0, 5: 0, 6: 0})  # 6: 1,950 m beyond region 0, margin 100 m
    (r0, e0), (r1, e1), (r2, e2) = router.split(report)
    assert r0.ids.tolist() == [4, 5, 6] and e0.tolist() == [False, False, False]
    assert r1.ids.tolist() == [5] and e1.tolist() == [True]  # 5 is 50 m inside region 1: by position too
    assert r2.ids.tolist() == [6] and e2.tolist() == [True]
