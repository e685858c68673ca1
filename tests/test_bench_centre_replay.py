"""``fedtrack bench scale``'s centres in their own processes (benchmarks/centre_replay.py): the calls
recorded from the in-process sharded run, replayed on a centre built as ``serve mtt-centre`` builds
it, give each region centre's pictures (and the unsharded centre's) to 1e-9 and to the bit; a
replay that differs stops the bench. About 10 s."""

from __future__ import annotations

import numpy as np
import pytest

from fedtrack.benchmarks.centre_replay import (
    CentreReplay,
    Recording,
    ReplayDiffers,
    check_pictures,
    picture_rows,
    read_calls,
    regions_config,
    replay,
)
from fedtrack.config import load_tables
from fedtrack.fusion_center.mtt.engines import PictureTracks, TrackToTrackEngine, centre_picture, no_tracks
from fedtrack.fusion_center.mtt.regional import RegionEngine
from fedtrack.fusion_center.mtt.replay import data_regions, pictures, read_scans, state_dim
from fedtrack.fusion_center.mtt.service import service_from_args
from fedtrack.fusion_center.mtt.shards import ShardedCentre
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A 2 x 2 run and a one-region run of 40 targets over 30 s (maneuver detector on, margin 300 m):
    each region centre's calls recorded, and its in-process pictures kept."""
    out = tmp_path_factory.mktemp("centre-replay")
    simulate(Scenario(targets=40, duration=30.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 3, out)
    text = (out / "config.toml").read_text()
    (out / "config.toml").write_text(text.replace("[mtt]\n", '[mtt]\nmaneuver = "vdie"\n', 1))
    (out / "margin.toml").write_text((out / "config.toml").read_text() + "\n[regions]\nmargin = 300.0\n"
                                     "grid = {origin = [0, 0], cell = [1, 1], nx = 1, ny = 1}\n")
    cfg = load_tables(out / "config.toml", MttSettings).mtt
    scans = read_scans(out / "measurements.jsonl", cfg)
    dim = state_dim(scans)
    runs = {}
    for spec in ("1x1", "2x2"):
        regions = data_regions(spec, scans, out / "margin.toml")
        centre = ShardedCentre(cfg, dim, True, regions)
        engine = TrackToTrackEngine(cfg, dim, feedback=True, regions=regions, centre=centre)
        recording = Recording(out / spec, centre)
        own: list[list[PictureTracks]] = [[] for _ in regions.ids]
        for T, tracks in pictures(engine, scans, cfg.period, cfg.picture_delay):
            recording.picture(T, tracks)
            for r, c in enumerate(centre.centres):
                own[r].append(centre_picture(c.centre, T) or no_tracks(dim))
        recording.close()
        runs[spec] = {"recording": recording, "regions": regions, "own": own, "centre": centre, "reports": engine.scans,
                      "config": regions_config(out / "config.toml", regions, out / f"{spec}.toml")}
    return {"runs": runs, "dim": dim}


def built(run: dict, dim: int, region: str | None) -> RegionEngine | TrackToTrackEngine:
    """The centre as ``serve mtt-centre --config ... [--region RID]`` builds it."""
    args = ["--config", str(run["config"]), "--dim", str(dim), "--id", "test"]
    return service_from_args(args + (["--region", region] if region else [])).engine


def assert_same(a: PictureTracks, b: PictureTracks) -> None:
    assert a.ids == b.ids and a.confirmed == b.confirmed and a.sensors == b.sensors and a.models == b.models
    assert np.allclose(a.x, b.x, rtol=0, atol=1e-9) and np.allclose(a.P, b.P, rtol=0, atol=1e-9)
    assert (a.maneuver is None) == (b.maneuver is None)
    if a.maneuver is not None:
        assert np.allclose(a.maneuver, b.maneuver, rtol=0, atol=1e-9, equal_nan=True)  # NaN: no maneuver


def test_each_region_centre_replayed_alone_gives_its_in_process_pictures(recorded: dict) -> None:
    """Every region centre of the 2 x 2 run, replayed on its recorded calls by the engine the live
    region centre builds, gives the in-process centre's pictures to 1e-9; hand-overs out and in were
    replayed (the run handed tracks over), and the regions' pictures together are the run's to the bit."""
    run, dim = recorded["runs"]["2x2"], recorded["dim"]
    parts = []
    for r, rid in enumerate(run["regions"].ids):
        rep = CentreReplay(built(run, dim, rid))
        got = [p for p in map(rep.call, read_calls(run["recording"].path(r))) if p is not None]
        assert len(got) == len(run["own"][r]) == 30
        for a, b in zip(got, run["own"][r]):
            assert_same(a, b)
        assert rep.count["take_over"] == run["centre"].centres[r].taken_over
        parts.append([picture_rows(p) for p in got])
    assert sum(c.handed_over for c in run["centre"].centres) > 0
    check_pictures("2x2", parts, run["recording"].digests)


def test_the_one_region_and_the_unsharded_centre_replayed(recorded: dict) -> None:
    """The one region's calls replayed on its region centre and on the unsharded centre (``serve
    mtt-centre`` without ``--region``): both give the one-region pictures, to the bit; the replay
    measures CPU seconds of each kind and an RSS peak not below the RSS before."""
    run, dim = recorded["runs"]["1x1"], recorded["dim"]
    for region in ("x0y0", None):
        engine = built(run, dim, region)
        assert isinstance(engine, RegionEngine if region else TrackToTrackEngine)
        out = replay(engine, read_calls(run["recording"].path(0)))
        check_pictures(str(region), [out["pictures"]], run["recording"].digests)
        assert out["count"]["answer"] == run["reports"] > 0 and out["count"]["picture"] == 30
        assert out["cpu_s"]["answer"] > 0 and out["rss_peak_kb"] >= out["rss_before_kb"] > 0


def test_a_replay_that_differs_stops(recorded: dict) -> None:
    """A picture that differs in one track's row, a picture missing, or a sub-report whose hand-overs
    out are not the recorded ones: ReplayDiffers."""
    run, dim = recorded["runs"]["2x2"], recorded["dim"]
    parts = [replay(built(run, dim, rid), read_calls(run["recording"].path(r)))["pictures"]
             for r, rid in enumerate(run["regions"].ids)]
    check_pictures("2x2", parts, run["recording"].digests)
    k = next(k for k, p in enumerate(parts[0]) if p)
    changed = [list(p) for p in parts[0]]
    changed[k][0] = (changed[k][0][0], bytes(16))
    with pytest.raises(ReplayDiffers, match=f"picture {k} differs"):
        check_pictures("2x2", [changed, *parts[1:]], run["recording"].digests)
    with pytest.raises(ReplayDiffers, match="pictures replayed"):
        check_pictures("2x2", [parts[0][:-1], *parts[1:]], run["recording"].digests)
    calls = list(read_calls(run["recording"].path(0)))
    k = next(k for k, c in enumerate(calls) if c[0] == "answer" and c[3])
    calls[k] = (*calls[k][:3], [])  # recorded as sending nothing out
    with pytest.raises(ReplayDiffers, match="hand-overs out"):
        replay(built(run, dim, run["regions"].ids[0]), calls)
