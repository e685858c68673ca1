"""The track-to-track centre sharded by region (fusion_center/mtt/shards.py, issue 27 item 2):
one region equals the unsharded centre; on a grid, every track is in exactly one region's centre,
hand-overs keep ids and estimates, and GOSPA stays within 2 % of the unsharded run. About 15 s."""

from __future__ import annotations

import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest

from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
from fedtrack.fusion_center.mtt.evaluation import evaluate
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.mtt.shards import RegionCentre, ShardedCentre
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("shards")
    simulate(Scenario(targets=40, duration=60.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 3, out)
    (out / "config.toml").write_text((out / "config.toml").read_text() + '\nmaneuver = "vdie"\n')
    return out


def pictures(path: Path) -> list[dict]:
    return [orjson.loads(line) for line in path.read_text().splitlines()]


def run(data: Path, algorithm: str, regions: str | None, name: str) -> Path:
    out = data / f"{name}.jsonl"
    replay_mtt(algorithm, data / "measurements.jsonl", data / "config.toml", out, regions=regions)
    return out


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_one_region_is_the_unsharded_centre(data: Path, algorithm: str) -> None:
    plain = pictures(run(data, algorithm, None, f"{algorithm}-plain"))
    one = pictures(run(data, algorithm, "1x1", f"{algorithm}-one"))
    assert len(plain) == len(one) == 60
    for a, b in zip(plain, one):
        assert [t["id"] for t in a["tracks"]] == [t["id"] for t in b["tracks"]]
        for ta, tb in zip(a["tracks"], b["tracks"]):
            assert np.allclose(ta["x"], tb["x"], rtol=0, atol=1e-9) and np.allclose(ta["P"], tb["P"], rtol=0, atol=1e-9)
            assert ta["sensors"] == tb["sensors"] and ta["status"] == tb["status"]


class Watch:
    """Around every report: no track in two centres; every hand-over taken over with its estimate
    unbroken."""

    def __init__(self) -> None:
        self.moves = 0
        self.duplicated = 0

    def answer(self, original: Callable[..., Any]) -> Callable[..., Any]:
        def answer(centre: ShardedCentre, report: Any) -> Any:
            out = original(centre, report)
            ids = [cid for c in centre.centres for cid in c.centre.tracks]
            self.duplicated += len(ids) - len(set(ids))
            return out
        return answer

    def take_over(self, original: Callable[..., None]) -> Callable[..., None]:
        def take_over(rc: RegionCentre, record: Any) -> None:
            original(rc, record)
            self.moves += 1
            tracks = rc.centre.tracks
            assert np.array_equal(tracks.latest(np.array([tracks.slot[record.id]]))[1][0], record.entries[1][-1])
        return take_over


@pytest.mark.parametrize("spec", ["2x2", "4x4"])
def test_grid_hands_tracks_over_losing_and_duplicating_none(data: Path, spec: str,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    watch = Watch()
    monkeypatch.setattr(ShardedCentre, "answer", watch.answer(ShardedCentre.answer))
    monkeypatch.setattr(RegionCentre, "take_over", watch.take_over(RegionCentre.take_over))
    sharded = run(data, "mtt-federated", spec, f"fed-{spec}")
    plain = data / "mtt-federated-plain.jsonl"
    if not plain.exists():
        run(data, "mtt-federated", None, "mtt-federated-plain")
    assert watch.moves >= (5 if spec == "2x2" else 15)  # 10 and 21 on this seed
    assert watch.duplicated == 0
    # ids unchanged across hand-overs: an unsharded track is one sharded track all along (where
    # their estimates are equal: both fused the same observations)
    ids: dict[int, int] = {}
    shown = equal = 0
    for a, b in zip(pictures(plain), pictures(sharded)):
        assert len({t["id"] for t in b["tracks"]}) == len(b["tracks"])  # no id twice in a picture
        by_state = {tuple(np.round(t["x"], 6)): t["id"] for t in b["tracks"]}
        for t in a["tracks"]:
            if t["status"] == "confirmed":
                shown += 1
                j = by_state.get(tuple(np.round(t["x"], 6)))
                if j is not None:
                    equal += 1
                    assert ids.setdefault(t["id"], j) == j
    # 2 x 2: 1988 of 2088; 4 x 4: 1820 of 2088 (the rows of a handed-over track's other sensors are
    # not fused until their trackers learn the new owner: docs/multitarget.md#regions)
    assert equal >= (0.9 if spec == "2x2" else 0.8) * shown
    g_plain = evaluate(plain, data / "truth.jsonl")["mean"]["gospa"]
    g_sharded = evaluate(sharded, data / "truth.jsonl")["mean"]["gospa"]
    # 2 x 2 (the acceptance): within 2 %; 4 x 4 cells of 2.5 km on this 10 km scenario: not
    # worse by more than 2 % (81.59 and 79.62 m against 81.55 m: docs/multitarget.md#regions)
    assert (abs(g_sharded - g_plain) if spec == "2x2" else g_sharded - g_plain) <= 0.02 * g_plain


def test_hand_over_record_round_trip_is_exact(data: Path) -> None:
    """A track handed to another centre and back is the track it was, to the bit."""
    from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
    from fedtrack.fusion_center.mtt.replay import read_scans

    cfg = MttConfig(maneuver="vdie")
    engine = TrackToTrackEngine(cfg, 4, feedback=True)
    for scan in read_scans(data / "measurements.jsonl", cfg)[:60]:
        engine.ingest(scan)
    a = engine.centre
    other = TrackToTrackCentre(cfg, 4, True)
    cid = max(a.tracks, key=lambda c: len(a.members.get(c, ())))
    entries, members = a.tracks.entries(cid), dict(a.mapping)
    record = a.hand_over(cid)
    assert cid not in a.tracks and not any(v == cid for v in a.mapping.values())
    other.take_over(record)
    back = other.hand_over(cid)
    a.take_over(back)
    assert a.mapping == members and back.members == record.members and back.strikes == record.strikes
    for x, y in zip(entries, a.tracks.entries(cid)):
        assert np.array_equal(x, y)
    slot = a.tracks.slot[cid]
    cols = [a.sensor_names.index(s) for s in record.sensors]
    assert np.array_equal(a.support[slot, cols], record.support)


def test_regions_option_errors_name_the_option(data: Path, tmp_path: Path) -> None:
    from fedtrack.config import ConfigError

    out = tmp_path / "p.jsonl"
    for spec, message in (("3", "--regions: expected NXxNY"), ("config", "has no \\[regions\\] table")):
        with pytest.raises(ConfigError, match=message):
            replay_mtt("mtt-federated", data / "measurements.jsonl", data / "config.toml", out, regions=spec)
        assert not out.exists()
    config = tmp_path / "c.toml"
    config.write_text((data / "config.toml").read_text()
                      + "\n[regions]\nmargin = 100.0\ngrid = {origin = [-5000, -5000], cell = [5000, 5000], nx = 2, ny = 2}\n")
    assert replay_mtt("mtt-decentralized", data / "measurements.jsonl", config, out, regions="config") == 60


def test_a_scan_without_rows_leaves_what_the_full_path_leaves(data: Path) -> None:
    """A report without detected rows (a region's sub-report of a scan that saw nothing there)
    takes :meth:`TrackToTrackCentre.ingest`'s short path: the centre it leaves, its resets and its
    pictures are those of the full path (``_fuse_rows``), to the bit."""
    from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine, centre_picture
    from fedtrack.fusion_center.mtt.replay import read_scans
    from fedtrack.local_filters.mtt.routing import sub_report

    cfg = MttConfig(maneuver="vdie")
    engine = TrackToTrackEngine(cfg, 4, feedback=True)
    reports: list[Any] = []
    fuse = engine.fuse
    engine.fuse = lambda report: reports.append(report) or fuse(report)  # type: ignore[method-assign]
    for scan in read_scans(data / "measurements.jsonl", cfg)[:90]:
        engine.ingest(scan)
    short, full = TrackToTrackCentre(cfg, 4, True), TrackToTrackCentre(cfg, 4, True)
    emptied = retired = 0
    for k, report in enumerate(reports):
        # every third scan's rows are in another region (retired ids kept); every fifth saw none of them
        if k % 3 == 1:
            report = sub_report(report, np.zeros(report.ids.size, dtype=bool))
        elif k % 5 == 2:
            report = report._replace(detected=np.zeros(report.ids.size, dtype=bool), obs_H=report.obs_H[:0],
                                     obs_R=report.obs_R[:0], obs_z=report.obs_z[:0], started=report.started[:0])
        empty = not report.detected.any()
        emptied += empty
        retired += empty and report.retired.size > 0
        a, qa = short.answer(report)
        if empty:
            b = full._fuse_rows(report, report.detected.nonzero()[0], full._note_scan(report))
            qb = float(max(len(full.live_sensors(report.t)), 1))
            full.prune(report.t)  # the rest of answer()
        else:
            b, qb = full.answer(report)
        assert qa == qb and np.array_equal(a.ids, b.ids) and np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
        assert pickle.dumps(short) == pickle.dumps(full)  # every array, table and counter
    assert emptied >= 40 and retired >= 5 and len(short.tracks) >= 30
    pa, pb = centre_picture(short, reports[-1].t + 0.5), centre_picture(full, reports[-1].t + 0.5)
    assert pa is not None and pb is not None and pa.ids == pb.ids and np.array_equal(pa.P, pb.P)
