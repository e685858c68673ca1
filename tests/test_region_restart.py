"""A region centre started again without a standby (issue 27: the launcher's restart of a crashed
``serve mtt-centre --region RID`` with ``[multitarget] standby = false``, or an operator's) numbers
its tracks and hand-overs after every one its former process issued, from the numbers that process
reserved in its ``--numbers`` file (fusion_center/mtt/numbers.py). In-process, on the bus of
``test_hostile_messages``: region x0y0's centre hands a target over to x1y0's, is replaced by a
fresh process, and a second target crosses."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support import assert_same_pictures
from test_hostile_messages import KEYS, OPTIONS, Bus, _matches
from test_hostile_regions import SENSORS, report
from test_hostile_semantics import hand_over
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG
from test_mtt_regions_live import LAUNCH, scenario, services

from fedtrack.cli import main
from fedtrack.deploy.plan import service_plan
from fedtrack.deploy.settings import load_settings
from fedtrack.fusion_center.mtt.numbers import RESERVE_AHEAD, Numbers, read_numbers, reservation
from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.keys import Keys
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.wire import HandOver, encode


def regions_of(tmp_path: Path) -> Regions:
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    return regions


def centre(tmp_path: Path, rid: str, numbers: Path | None) -> MttCentreService:
    """Region ``rid``'s (decentralized) centre, reserving its numbers in ``numbers``."""
    return MttCentreService("mtt-decentralized", MttConfig(sensors=SENSORS, max_lag=3.0), 4, region=rid,
                            regions=regions_of(tmp_path), numbers=numbers, service_id=rid, options=OPTIONS,
                            deployment=KEYS.deployment)


def put(bus: Bus, rid: str, k: int, targets: list[tuple[int, float, int]]) -> None:
    """Scan ``k`` of every sensor, sent to region ``rid``'s centre: per target ``(local track id, x0,
    first scan)``, its local track of a target flying along x from ``x0`` at 50 m/s."""
    for s in SENSORS:
        rows = [replace(report(s, k, x0, 50.0), ids=(lid,), started=(k == first,)) for lid, x0, first in targets]
        x = np.concatenate([r.x for r in rows])
        bus.put(KEYS.region_report(rid, s), encode(replace(
            rows[0], ids=tuple(r.ids[0] for r in rows), x=x, P=np.concatenate([r.P for r in rows]),
            confirmed=(True,) * len(rows), detected=(True,) * len(rows), obs_H=np.tile(rows[0].obs_H, (len(rows), 1)),
            obs_R=np.tile(rows[0].obs_R, (len(rows), 1)), obs_z=x[:, [0, 2]],
            started=tuple(r.started[0] for r in rows))))


def test_a_restarted_region_centre_numbers_after_its_former_process(tmp_path: Path) -> None:
    """Target 1 crosses from x0y0 into x1y0 (x0y0's track 0, its hand-over 0); x0y0's centre
    SIGKILLed and started again; target 2 starts in x0y0 and crosses too. Before, the fresh process
    numbered from 0 again: target 2 was track 0, which x1y0 held for target 1 (the merged pictures
    at t = 5-10 showed one of the two, ``seen_twice``), and its hand-over 0 was a second, different
    hand-over 0 of x0y0 at x1y0 (``rejected_conflict``, ``contested``): target 2's track was lost,
    and x1y0 started a new one from the next report. Now the fresh process numbers after what its
    former one reserved: x1y0 takes target 2's hand-over, and every merged picture shows both
    targets, under two ids."""
    numbers = tmp_path / "x0y0.numbers"
    first, b = centre(tmp_path, "x0y0", numbers), centre(tmp_path, "x1y0", None)
    merger = PictureMergeService(regions_of(tmp_path), 4, 5.0, 1.0, service_id="picture", options=OPTIONS,
                                 deployment=KEYS.deployment)
    bus = Bus([first, b, merger])
    one, two = (1, -100.0, 0), (2, -500.0, 5)  # target 1 in x1y0 from t = 2, target 2 from t = 10
    for k in range(3):
        put(bus, "x0y0", k, [one])
    for k in range(3, 5):
        put(bus, "x1y0", k, [one])
    assert [(h.source, h.serial, h.id) for h in bus.of(HandOver)] == [("x0y0", 0, 0)]
    assert b.counters["taken_over"] == 1
    reserved = read_numbers(numbers, "x0y0", 0, 2)  # what its process had issued, and more
    region = first.engine.region  # type: ignore[union-attr]
    assert reserved is not None and reserved.next_id > region.centre.next_id and reserved.serial > region.serial
    before = len(bus.published)
    again = centre(tmp_path, "x0y0", numbers)  # the same command line, started again
    restarted = Bus([again, b, merger])
    restarted.published = bus.published
    for k in range(5, 11):
        put(restarted, "x0y0", k, [two])
        put(restarted, "x1y0", k, [one])
    put(restarted, "x1y0", 11, [one, two])
    handed = [(h.source, h.serial, h.id) for h in restarted.of(HandOver)][1:]
    assert len(handed) == 1 and handed[0][1] > 0 and handed[0][2] != 0  # after its former process's
    assert b.counters["taken_over"] == 2 and b.counters.get("contested", 0) == 0
    assert b.counters.get("rejected", 0) == 0 and b.counters.get("late", 0) == 0
    merged = [p for key, p in restarted.published[before:]
              if key == KEYS.mtt_picture() and not p.closing and p.t >= 5]  # (t = 3, 4: target 1 alone)
    assert [p.t for p in merged] == [float(t) for t in range(5, 11)]  # (t = 11: none from x0y0 yet)
    assert all(set(p.ids) == {0, handed[0][2]} for p in merged)  # both targets in every merged picture


def test_the_reservation_covers_every_id_and_hand_over_a_sub_report_can_issue() -> None:
    """Before a sub-report of ``rows`` rows is fused, the file reserves at least ``rows`` more ids
    (in steps) and hand-overs than issued; it is written again only when that would pass it."""
    issued = Numbers(next_id=5, serial=3)
    first = reservation(issued, None, 4, 10)
    assert first == Numbers(5 + 4 * (10 + RESERVE_AHEAD), 3 + 10 + RESERVE_AHEAD)
    assert reservation(Numbers(5 + 4 * 100, 3 + 100), first, 4, 10) is None  # still covered: no write
    late = Numbers(first.next_id - 4, first.serial - 1)
    assert reservation(late, first, 4, 2) == Numbers(late.next_id + 4 * (2 + RESERVE_AHEAD),
                                                     late.serial + 2 + RESERVE_AHEAD)


@pytest.mark.parametrize(("content", "field"), [
    ('{"region": "x1y0", "next_id": 8, "serial": 0}', "region"),  # another region's file
    ('{"region": "x0y0", "next_id": 7, "serial": 0}', "next_id"),  # not x0y0's sequence (even ids)
    ('{"region": "x0y0", "next_id": 4611686018427387904, "serial": 0}', "next_id"),  # 2^62: no room after it
    ('{"region": "x0y0", "next_id": 8, "serial": true}', "serial"),
    ('{"region": "x0y0", "next_id": 8}', '{"region", "next_id", "serial"}'),
    ('{"region": "x0y0", "next_', "not a JSON object"),
])
def test_a_numbers_file_it_cannot_number_after_is_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, field: str) -> None:
    """``serve mtt-centre --region x0y0 --numbers FILE`` with a file that is not x0y0's numbers (a
    file edited or mixed up: another region's would make x0y0 issue x1y0's ids) ends before it starts,
    with exit 2 and one line naming the file and the field."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    numbers = tmp_path / "x0y0.numbers"
    numbers.write_text(content)
    code = main(["serve", "mtt-centre", "--algorithm", "mtt-decentralized", "--region", "x0y0", "--config",
                 str(config), "--numbers", str(numbers), "--connect", "tcp/127.0.0.1:1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and err.startswith(f"fedtrack: error: {numbers}:1: ") and field in err


@pytest.mark.parametrize(("make", "reason"), [
    (lambda p: p.write_bytes(b'\xff{"region": "x0y0"}'), ":1: not UTF-8 text (byte 0)"),
    (lambda p: p.write_text("[" * 2000 + "]" * 2000), ":1: not a JSON object (nested too deeply)"),
    (lambda p: p.write_text(" " * 5000 + '{"region": "x0y0", "next_id": 8, "serial": 0}'), ": larger than 4096 bytes"),
    (lambda p: p.symlink_to("/dev/zero"), ": not a regular file"),  # read whole: a MemoryError
    (lambda p: os.mkfifo(p), ": not a regular file"),  # opened to read: the start blocked for good
    (lambda p: p.mkdir(), ": not a regular file"),
])
def test_a_numbers_file_that_is_no_small_text_file_is_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], make: Callable[[Path], None], reason: str) -> None:
    """A numbers file that is not UTF-8, nests deeply, or is no short regular file ends the start with
    exit 2 and one line naming the file (before: a traceback, a MemoryError, or a start that hung)."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    numbers = tmp_path / "x0y0.numbers"
    make(numbers)
    code = main(["serve", "mtt-centre", "--algorithm", "mtt-decentralized", "--region", "x0y0", "--config",
                 str(config), "--numbers", str(numbers), "--connect", "tcp/127.0.0.1:1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and err.startswith(f"fedtrack: error: {numbers}{reason}")


def test_a_numbers_file_that_cannot_be_written_is_counted_and_fusion_goes_on(tmp_path: Path) -> None:
    """A reservation that cannot be written (here: its folder is missing) is counted
    ``numbers_unsaved`` per sub-report; the centre fuses and answers as without the file."""
    svc = centre(tmp_path, "x0y0", tmp_path / "missing" / "x0y0.numbers")
    bus = Bus([svc])
    for k in range(3):
        put(bus, "x0y0", k, [(1, -2000.0, 0)])
    assert svc.counters["numbers_unsaved"] == 9 and svc.counters.get("rejected", 0) == 0
    assert list(svc.engine.region.centre.tracks) == [0]  # type: ignore[union-attr]


def test_the_launcher_gives_each_region_centre_and_standby_a_numbers_file_of_its_own(tmp_path: Path) -> None:
    """``fedtrack launch`` of regions with standbys: every region centre, and every standby (which
    numbers as itself until it takes over), reserves in ``OUT/<id>.numbers``; the unsharded-centre
    roles and the rest get none."""
    config = tmp_path / "launch.toml"
    config.write_text(LAUNCH.format(port=7447).replace('duration = 8.0', 'duration = 8.0\nstandby = true'))
    plan = service_plan(load_settings(config), config, tmp_path / "out", tmp_path / "logs")
    numbers = {sp.id: sp.argv[sp.argv.index("--numbers") + 1] for sp in plan if "--numbers" in sp.argv}
    assert numbers == {sid: str(tmp_path / "out" / f"{sid}.numbers")
                       for sid in ("x0y0", "x1y0", "x0y0-standby", "x1y0-standby")}


def test_a_track_of_the_former_process_handed_back_is_taken(tmp_path: Path) -> None:
    """A track the former process numbered (0) and handed away, handed back to the new process by
    x1y0: the new process, numbering from 0 again, refused it as 'an id this region has not issued'
    (``rejected_conflict``: the track was lost); numbering after the reservation, it takes it."""
    numbers = tmp_path / "x0y0.numbers"
    first = centre(tmp_path, "x0y0", numbers)
    bus = Bus([first])
    for k in range(2):
        put(bus, "x0y0", k, [(1, -2000.0, 0)])
    assert list(first.engine.region.centre.tracks) == [0]  # type: ignore[union-attr]
    again = centre(tmp_path, "x0y0", numbers)
    bus = Bus([again])
    back = replace(hand_over(again, again.cfg, 0, [-2000.0, 50.0, 0.0, 0.0], np.diag([100.0, 25.0, 100.0, 25.0])),
                   id=0)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(back))
    assert again.counters.get("taken_over") == 1 and again.counters.get("rejected", 0) == 0
    assert list(again.engine.region.centre.tracks) == [0]  # type: ignore[union-attr]


def test_numbers_are_a_region_centres_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The one centre of the whole area has no hand-overs and no neighbours: ``--numbers`` without
    ``--region`` is refused (exit 2), not ignored."""
    code = main(["serve", "mtt-centre", "--numbers", str(tmp_path / "all.numbers"), "--connect", "tcp/127.0.0.1:1"])
    assert code == 2 and "--numbers: a region centre's (--region) only" in capsys.readouterr().err


def test_a_region_centre_started_again_empty_replays(tmp_path: Path) -> None:
    """Region x0y0's centre stopped at t = 8 s (SIGTERM: its last pictures and its closing record; no
    standby) and a fresh process of it started at t = 14 s, empty, numbering after its former one's
    reservation: the recording replays to the live merged pictures across the restart. Before, the
    recording did not say where the new process began: the replay ran the former centre on, x0y0's
    tracks were missing from the replayed picture of t = 8 and every later picture differed."""
    msgs, cfg, config = scenario(tmp_path)
    regions = load_regions(config)
    assert regions is not None
    numbers = tmp_path / "x0y0.numbers"
    centres, local, merger, recorder = services(tmp_path, "mtt-federated", config, cfg,
                                                {"options": OPTIONS, "deployment": "hostile"})
    first = MttCentreService("mtt-federated", cfg, 4, region="x0y0", regions=regions, numbers=numbers,
                             service_id="x0y0", options=OPTIONS, deployment="hostile")
    recorder.on_start()
    bus = Bus([first, centres[1], *local, merger, recorder])
    keys = Keys("hostile")

    def reaches(key: str) -> bool:
        return any(_matches(sub.key, key) for svc in bus.services for sub in svc._subscriptions)

    for svc in local:
        svc.reaches = reaches  # type: ignore[method-assign]
    again = None
    for m in (m for m in msgs if m.t < 22.0):
        if m.t >= 8.0 and first in bus.services:  # stopped (SIGTERM): its last pictures and closing record
            first.on_stop()
            bus.drain()
            bus.services.remove(first)
            bus._routes.clear()
        if m.t >= 14.0 and again is None:
            again = MttCentreService("mtt-federated", cfg, 4, region="x0y0", regions=regions, numbers=numbers,
                                     service_id="x0y0", options=OPTIONS, deployment="hostile")
            again._subscriptions = again.subscriptions()
            again.session = first.session
            again.publish = first.publish  # type: ignore[method-assign]
            bus.services.insert(0, again)
            bus._routes.clear()
        bus.put(keys.sensor_meas(m.sensor), encode(m))
    assert again is not None
    for svc in [*local, again, centres[1], merger]:
        svc.on_stop()
        bus.drain()
    recorder.on_stop()
    assert all(svc.counters.get("rejected", 0) == 0 for svc in [again, centres[1], *local, merger, recorder])
    assert again.counters.get("pictures", 0) >= 7
    live = [json.loads(x) for x in (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()]
    assert any(tr["id"] >= RESERVE_AHEAD for tr in live[-1]["tracks"])  # the new process's, numbered after
    replayed = tmp_path / "replayed.jsonl"
    replay_mtt("mtt-federated", tmp_path / "out" / "measurements.jsonl", config, replayed, regions="config")
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])
