"""What a peer the access control lets publish on the region centres' keys (a compromised or buggy
region centre or standby: every region centre runs as the ``fusion`` identity) can send (marker
``security``): hand-overs that are no track's record, and outputs of a primary that a cold standby
would number after. Each test shows the harm on the code before its fix (a ghost track in every
picture, a region that can no longer start a track) and that the service now refuses the message,
counted, with the pictures those of the run without it. The services run in-process through their
own dispatch (:class:`test_hostile_messages.Bus`).
"""

from __future__ import annotations

import copy
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any, NamedTuple

import numpy as np
import pytest
import zenoh
from test_hostile_messages import KEYS, OPTIONS, Bus
from test_hostile_semantics import hand_over, one_track_report, scan
from test_hostile_sequences import region_picture
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.deploy.launcher import Launcher
from fedtrack.deploy.plan import failover_scopes
from fedtrack.deploy.settings import load_settings
from fedtrack.fusion_center.mtt import picture_merge
from fedtrack.fusion_center.mtt.failover import ordered
from fedtrack.fusion_center.mtt.failover import standby as standby_module
from fedtrack.fusion_center.mtt.failover.standby import SILENT_S, Standby, claim_instance
from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.service import HANDOVERS_KEPT, MttCentreService
from fedtrack.fusion_center.mtt.shards import handover_to_wire
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.regions import load_regions
from fedtrack.services.base import BASE_COUNTERS, health_counters
from fedtrack.wire import (
    MAX_MAP_ITEMS,
    MAX_TRACKS,
    HandOver,
    Health,
    TrackPicture,
    TrackReport,
    TrackResets,
    decode,
    encode,
)

pytestmark = pytest.mark.security

SENSORS = ("s1", "s2", "s3")


def centre_of_x0y0(tmp_path: Path, standby: bool = False) -> tuple[Bus, MttCentreService]:
    """The (decentralized) centre of region ``x0y0`` (x < 0) of two, or its standby."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    svc = MttCentreService("mtt-decentralized", MttConfig(sensors=SENSORS, max_lag=3.0), 4, region="x0y0",
                           regions=load_regions(config), standby=standby, service_id="x0y0", options=OPTIONS,
                           deployment=KEYS.deployment)
    return Bus([svc]), svc


def report(sensor: str, k: int, x0: float = -2000.0, v: float = 10.0) -> TrackReport:
    """Scan ``k`` of ``sensor`` (at ``k`` s plus a third of a second per sensor): its local track 1
    of a target flying along x from ``x0`` at ``v`` (from region x0y0, x < 0)."""
    t = k + SENSORS.index(sensor) / 3.0
    x = np.array([[x0 + v * t, v, 0.0, 0.0]])
    return replace(one_track_report(sensor, k), t=t, x=x, obs_z=x[:, [0, 2]])


def scans(bus: Bus, ks: range, x0: float = -2000.0, v: float = 10.0) -> None:
    """Every sensor's region x0y0 report of scans ``ks`` (:func:`report`), put on ``bus``."""
    for k in ks:
        for s in SENSORS:
            bus.put(KEYS.region_report("x0y0", s), encode(report(s, k, x0, v)))


def shown(bus: Bus) -> list[tuple[float, tuple[int, ...]]]:
    """Each picture published on ``bus``: its time and track ids."""
    return [(p.t, p.ids) for p in bus.of(TrackPicture)]


def forged_copy(tmp_path: Path, k: int) -> tuple[Bus, Bus, MttCentreService, Any]:
    """The clean run's bus after 12 scans; a bus and centre after ``k``; the record of that centre's one track
    then (a forged copy of it: the track stays)."""
    clean_bus, _ = centre_of_x0y0(tmp_path)
    scans(clean_bus, range(12))
    bus, svc = centre_of_x0y0(tmp_path)
    scans(bus, range(k))
    centre = svc.engine.region.centre  # type: ignore[union-attr]
    (victim,) = list(centre.tracks)
    return clean_bus, bus, svc, copy.deepcopy(centre).hand_over(victim)


@pytest.mark.parametrize("forgery", ["ahead", "unsupported"])
def test_a_hand_over_that_is_no_tracks_record_is_refused(tmp_path: Path, forgery: str) -> None:
    """A hand-over's times and life counts were taken as sent. ``ahead``: the region's own track,
    as a neighbour's hand-over of a new id stamped 100 s ahead of the data, took its local tracks
    (a hand-over moves them) and the track was gone, while the new one, whose newest entry no report
    could follow and whose last support was in the future, stood frozen in every later picture
    (measured on the bus deployment of tests/test_mtt_regions_live.py, 10 targets: a ghost 400 m
    from its target for the 13 s to the end, the target under a new id). ``unsupported``: support
    for a sensor without any local track, never lost, and a last support after its newest entry:
    never deleted, its covariance growing in every picture. Now a hand-over whose newest entry is
    beyond what a report would be taken at (``time_lead``), whose support is not its local tracks'
    count or whose last support is after its newest entry (``wrong_model``) is refused, and the
    pictures are those of the run without it."""
    clean_bus, bus, svc, record = forged_copy(tmp_path, 5)
    msg = handover_to_wire(record, "x1y0", 0)
    if forgery == "ahead":
        ring = np.array(msg.ring)
        ring[:, 0] += 100.0
        msg = replace(msg, id=1001, ring=ring, last_support=msg.last_support + 100.0)
    else:
        msg = replace(msg, id=1001, member_sensors=(), member_ids=(), strikes=(), last_support=1e9)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(msg))
    scans(bus, range(5, 12))
    assert shown(bus) == shown(clean_bus) and len(shown(bus)) == 12
    for a, b in zip(bus.of(TrackPicture), clean_bus.of(TrackPicture)):
        np.testing.assert_array_equal(a.x, b.x)
    reason = "time_lead" if forgery == "ahead" else "wrong_model"
    assert svc.counters[f"rejected_{reason}"] == 1 and svc.counters.get("taken_over", 0) == 0


def test_an_honest_hand_over_still_passes(tmp_path: Path) -> None:
    """The checks above take a track's record at the data's time, of local tracks no track here holds
    (a neighbour's track of the same target, its trackers' other local tracks), as before."""
    bus, svc = centre_of_x0y0(tmp_path)
    scans(bus, range(5))
    centre = svc.engine.region.centre  # type: ignore[union-attr]
    record = copy.deepcopy(centre).hand_over(next(iter(centre.tracks)))
    msg = handover_to_wire(record, "x1y0", 0)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(replace(msg, id=1001, member_ids=(7,) * len(msg.member_ids))))
    assert svc.counters["taken_over"] == 1 and "rejected" not in {k for k, v in svc.counters.items() if v}
    assert 1001 in centre.tracks


def test_a_hand_over_of_a_track_in_another_region_is_refused(tmp_path: Path) -> None:
    """A region hands a track over to the region its newest estimate is in. x1y0 handing x0y0 the
    record of x0y0's own track moved 6 km along x (its newest estimate at x = 4,047 m, in x1y0): taken
    over with the track's local tracks, x0y0's track 0 deleted, its next report's fusion sent the
    forged track back to x1y0 (handed_over 1) and started the target afresh as track 2 (pictures from
    t = 5 on: track 2, not 0). Now refused (``wrong_region``); the pictures are the honest run's."""
    clean_bus, _ = centre_of_x0y0(tmp_path)
    scans(clean_bus, range(12))
    bus, svc = centre_of_x0y0(tmp_path)
    scans(bus, range(5))
    centre = svc.engine.region.centre  # type: ignore[union-attr]
    msg = handover_to_wire(copy.deepcopy(centre).hand_over(next(iter(centre.tracks))), "x1y0", 0)
    ring = np.array(msg.ring)
    ring[:, 1] += 6000.0  # every entry's x (after its time)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(replace(msg, id=1001, ring=ring)))
    scans(bus, range(5, 12))
    assert svc.counters["rejected_wrong_region"] == 1 and svc.counters.get("taken_over", 0) == 0
    assert shown(bus) == shown(clean_bus) and {ids for _, ids in shown(bus)} == {(0,)}
    for a, b in zip(bus.of(TrackPicture), clean_bus.of(TrackPicture)):
        np.testing.assert_array_equal(a.x, b.x)


@pytest.mark.parametrize("ahead", [300.0, 20.0, 0.0])
def test_a_hand_over_taking_a_tracks_local_tracks_elsewhere_is_refused(tmp_path: Path, ahead: float) -> None:
    """A hand-over moves the local tracks it names (its members) to the track it brings, from whichever
    track held them here. x1y0 sending x0y0, before each scan from t = 5 s on, the record of x0y0's track
    (its local tracks included) under a new id of its own, ``ahead`` 300 m ahead of it along x and still in
    x0y0, was taken over each time: the target's track was renamed at every scan and shown 208-435 m ahead of
    it (mean 283 m over the 7 pictures, against the clean run's track), as far as the forger liked, a
    tentative duplicate started at the target every third picture. A record naming a local track held here
    by a track it does not pass the association gate with (as the duplicate merge tests two tracks of one
    target) was then refused (``conflict``, the next picture contested), but within the gate it was still
    taken: 20 m ahead, or the track's own state (0), renamed the track at every scan (7 of 7 pictures under
    the forger's ids; 13.8-23.4 m off, and 0 m). A record naming a local track held here by a confirmed track
    is now refused whatever its state and time (redteam59), and the pictures are the clean run's; a record
    of local tracks no track here holds is still taken (:func:`test_an_honest_hand_over_still_passes`)."""
    clean_bus, _ = centre_of_x0y0(tmp_path)
    scans(clean_bus, range(12))
    bus, svc = centre_of_x0y0(tmp_path)
    scans(bus, range(5))
    centre = svc.engine.region.centre  # type: ignore[union-attr]
    for k in range(5, 12):
        (victim,) = list(centre.tracks)
        msg = handover_to_wire(copy.deepcopy(centre).hand_over(victim), "x1y0", k)
        assert len(msg.member_ids) == len(SENSORS)  # every sensor's local track of the target
        ring = np.array(msg.ring)
        ring[:, 1] += ahead  # every entry's x (after its time)
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(replace(msg, id=1001 + 2 * k, ring=ring)))
        scans(bus, range(k, k + 1))
    assert svc.counters["rejected_conflict"] == svc.counters["rejected"] == 7
    assert svc.counters.get("taken_over", 0) == 0 and svc.counters["contested"] == 7
    assert [p.contested for p in bus.of(TrackPicture)] == [False] * 5 + [True] * 7
    assert shown(bus) == shown(clean_bus) and {ids for _, ids in shown(bus)} == {(0,)}
    for a, b in zip(bus.of(TrackPicture), clean_bus.of(TrackPicture)):
        np.testing.assert_array_equal(a.x, b.x)


def test_a_hand_over_older_than_the_track_holding_its_local_tracks_is_refused(tmp_path: Path) -> None:
    """A record stamped in the past passes the association gate (its covariance predicted over the gap, and a
    target flying straight is where the old record predicts it): x1y0 sending x0y0, before each scan from
    t = 5 s on, the record x0y0's track had at t = 3 s, under a new id each time, had the track renamed at
    every scan (7 of 7 pictures, each under another id; 0 m off). A record naming a local track held here by
    a confirmed track whose newest state is after the record's newest entry (the holder has fused what the
    record's sender had not) is now refused (``conflict``, the next picture contested); the pictures are the
    clean run's."""
    clean_bus, bus, svc, record = forged_copy(tmp_path, 4)
    old = handover_to_wire(record, "x1y0", 0)
    scans(bus, range(4, 5))
    for k in range(5, 12):
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(replace(old, serial=k, id=1001 + 2 * k)))
        scans(bus, range(k, k + 1))
    assert svc.counters.get("taken_over", 0) == 0 and svc.counters["rejected_conflict"] == 7
    assert shown(bus) == shown(clean_bus) and {ids for _, ids in shown(bus)} == {(0,)}
    assert [p.contested for p in bus.of(TrackPicture)] == [False] * 5 + [True] * 7


def test_a_hand_over_whose_source_is_not_its_keys_is_refused(tmp_path: Path) -> None:
    """A hand-over's ``source`` was taken from the payload, and every region identity could put on
    every ``region/<rid>/handover``: 64 hand-overs to x0y0 claiming to be x1y0's, numbered from 10^6
    up, were all taken over and made x1y0's genuine hand-overs ``late`` (dropped, nothing rejected
    or contested: the tracks crossing from x1y0 vanished). A region now hands over on its own key,
    ``region/<rid>/handover/<src>`` (the access control lets ``region-<src>`` put on no other), and
    a hand-over whose ``source`` is not its key's ``<src>`` is rejected (``sender``): here x2y0's
    forgeries on its own key, and the genuine hand-over of x1y0 is taken."""
    config = tmp_path / "three.toml"
    config.write_text(REGIONS_CONFIG.replace("nx = 2", "nx = 3"))
    cfg = MttConfig(sensors=SENSORS, max_lag=3.0)
    svc = MttCentreService("mtt-decentralized", cfg, 4, region="x0y0", regions=load_regions(config),
                           service_id="x0y0", options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    P = np.diag([100.0, 25.0, 100.0, 25.0])
    for n in range(HANDOVERS_KEPT):  # ids 3n + 1: not x0y0's (region 0 of 3)
        forged = replace(hand_over(svc, cfg, 10**6 + n, [-4000.0 + 40.0 * n, 10.0, 0.0, 0.0], P), id=3 * n + 1)
        bus.put(KEYS.region_handover("x0y0", "x2y0"), encode(forged))
    genuine = replace(hand_over(svc, cfg, 0, [-2000.0, 10.0, 0.0, 0.0], P), id=3 * HANDOVERS_KEPT + 1)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(genuine))
    assert svc.counters["rejected_sender"] == svc.counters["rejected"] == HANDOVERS_KEPT
    assert svc.counters["taken_over"] == 1 and svc.counters.get("late", 0) == 0
    assert list(svc.engine.region.centre.tracks) == [genuine.id]  # type: ignore[union-attr]


def test_a_cold_standby_takes_a_track_of_its_region_handed_back_that_left_before_it_started(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A centre restarted as a standby (cold) has not seen the tracks its region handed away before it
    started: one handed back was refused as 'an id this region has not issued' (``conflict``, measured
    live: SIGKILL of x0y1's primary at a hand-over, 1 honest hand-over refused), and would have been
    lost at its take-over. A cold standby takes it, numbering after it; a hot one still refuses it,
    once its primary has not taken it within ``ORDER_WAIT_S`` (it holds its inputs for its primary's
    order: failover/ordered.py)."""
    primary_bus, primary = centre_of_x0y0(tmp_path)
    scans(primary_bus, range(5))
    centre = primary.engine.region.centre  # type: ignore[union-attr]
    record = copy.deepcopy(centre).hand_over(next(iter(centre.tracks)))
    back = replace(handover_to_wire(record, "x1y0", 0), id=40)  # x0y0's ids are even (region 0 of 2)
    for cold in (True, False):
        bus, svc = centre_of_x0y0(tmp_path, standby=True)
        bus.put(KEYS.region_picture("x0y0"), encode(TrackPicture(
            seq=3 if cold else 0, t=3.0 if cold else 0.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)),
            confirmed=(), sensors=(), fused_sensors=(), fused_seqs=(), left=(), stamp_ns=1, closing=False)))
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(back))
        region = svc.engine.region  # type: ignore[union-attr]
        if cold:
            assert svc.counters.get("taken_over") == 1 and "rejected" not in {k for k, v in svc.counters.items() if v}
            assert 40 in region.centre.tracks and region.centre.next_id == 42
        else:
            assert not svc.counters["rejected"] and len(svc.follow.held) == 1  # held for its primary's order
            monkeypatch.setattr(ordered, "ORDER_WAIT_S", 0.0)  # which has not listed it for that long
            svc.on_tick()
            assert svc.counters["rejected_conflict"] == 1 and 40 not in region.centre.tracks


@pytest.mark.parametrize("output", ["picture", "handover"])
def test_a_cold_standby_keeps_room_to_number_its_tracks(tmp_path: Path, output: str) -> None:
    """A cold standby numbers its tracks and hand-overs after every id and number of its region that
    its primary's outputs showed (so that none is issued twice after a take-over), and it took any
    message on those keys as its primary's. A picture of the region listing id 2^63 - 2 (a forgery
    by any ``fusion`` identity, or a primary's bug) moved its next id past the wire's integers: once
    it had taken over, every report that would start a track failed (``numerical``: 10 of the 24
    here, 4 pictures of 8, no track ever); after a hand-over numbered 2^63 - 1 its next hand-over was
    numbered 2^63, which every receiver refuses: the track handed over was in neither region. An id
    or number that leaves no room (2^62 and beyond) is now refused (``seq_jump``), and the standby
    numbers on as before."""
    bus, svc = centre_of_x0y0(tmp_path, standby=True)
    if output == "picture":
        forged = TrackPicture(seq=3, t=0.0, ids=(2**63 - 2,), x=np.zeros((1, 4)), P=np.eye(4), confirmed=(True,),
                              sensors=(("s1",),), fused_sensors=(), fused_seqs=(), left=(), stamp_ns=1, closing=False)
        bus.put(KEYS.region_picture("x0y0"), encode(forged))
        bus.put(KEYS.region_picture("x0y0"), encode(replace(forged, ids=(40,))))  # an honest cold start
    else:
        bus.put(KEYS.region_picture("x0y0"), encode(TrackPicture(
            seq=3, t=0.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(), fused_sensors=(),
            fused_seqs=(), left=(), stamp_ns=1, closing=False)))
        forged_h = HandOver(source="x0y0", serial=2**63 - 1, id=40, confirmed=True, ring=np.zeros((1, 1)), neg_inf=(),
                            sensors=(), support=(), streak=(), window=(), last_support=0.0, member_sensors=(),
                            member_ids=(), strikes=())
        bus.put(KEYS.region_handover("x1y0", "x0y0"), encode(forged_h))
    region = svc.engine.region  # type: ignore[union-attr]
    next_id, serial = region.centre.next_id, region.serial
    svc.standby.take_over()  # its primary gone
    scans(bus, range(8), x0=-60.0, v=20.0)  # the target crosses into x1y0: handed over
    (handed,) = bus.of(HandOver)
    assert decode(encode(handed), HandOver).serial == 0  # its new owner takes it
    assert len(bus.of(TrackResets)) == 24 and len(bus.of(TrackPicture)) == 8
    assert svc.counters["rejected"] == 1  # the forgery only
    assert svc.standby.cold and svc.counters["rejected_seq_jump"] == 1
    assert next_id == (42 if output == "picture" else 0) and serial == 0


def test_a_flood_on_the_primarys_keys_is_not_held_by_its_standby(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                                   ) -> None:
    """A standby remembers the outputs its primary sent before it made them itself (so as not to send
    them again after a take-over), for WITHHELD_S (10 s), and it kept each whole: any ``fusion``
    identity sending answers on the primary's keys had them held, 200 forged answers of 2,048 tracks
    81 MB (tracemalloc; a joined answer may have 131,072 tracks). Now it keeps an answer's or a
    hand-over's identity only, a picture whole only among the latest PICTURES_SETTLED (4: what it is
    compared with), and at most SETTLED_MAX outputs (QUEUE_SIZE: its lag behind the primary is at
    most its inbox; 16 here, for speed), the oldest forgotten."""
    monkeypatch.setattr(standby_module, "SETTLED_MAX", 16, raising=False)  # (absent before)
    bus, svc = centre_of_x0y0(tmp_path, standby=True)
    n = MAX_TRACKS
    answer = TrackResets(sensor="s1", seq=0, t=0.0, q_scale=1.0, ids=tuple(range(n)), x=np.zeros((n, 4)),
                         P=np.tile(np.eye(4), (n, 1)), region="x0y0")
    for k in range(40):
        bus.put(KEYS.region_resets("x0y0", "s1"), encode(replace(answer, seq=k)))
    for k in range(8):
        bus.put(KEYS.region_picture("x0y0"), encode(TrackPicture(
            seq=k, t=float(k), ids=(0,), x=np.zeros((1, 4)), P=np.eye(4), confirmed=(True,), sensors=(("s1",),),
            fused_sensors=(), fused_seqs=(), left=(), stamp_ns=1, closing=False)))
    settled = svc.standby.settled
    kept = [m for _, _, m in settled.values() if m is not None]
    assert all(isinstance(m, TrackPicture) for m in kept) and [m.t for m in kept] == [4.0, 5.0, 6.0, 7.0]
    assert len(settled) == 16 and "rejected" not in {k for k, v in svc.counters.items() if v}
    assert list(settled)[:8] == [("resets", "s1", k) for k in range(32, 40)]


def region_tracker(tmp_path: Path, federated: bool, reset_timeout_s: float, regions: bool = True) -> MttLocalService:
    """Sensor s1's local tracker with the two regions of ``test_mtt_regions_live`` (``regions``; else none)."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    return MttLocalService("s1", federated, MttConfig(sensors=("s1",), max_lag=3.0, clutter_density=1e-7),
                           reset_timeout_s, regions=load_regions(config) if regions else None, service_id="s1",
                           options=OPTIONS, deployment=KEYS.deployment)


def test_an_answer_holding_tracks_its_sub_report_did_not_carry_is_refused(tmp_path: Path) -> None:
    """A local tracker notes, for every local track a region's answer says it holds, that region as its
    holder, and forgets it only when the track is retired or the region stops holding it in a later
    answer: a region centre (any ``fusion`` identity, before per-region identities) answering with
    2,048 ids the tracker never had grew its routing table by as many with every report, for good,
    and the table is pickled with every message the tracker handles (10 answers of 131,072 ids in 64
    parts: 1.3 million entries, a 9.2 MB pickle, 0.32 s a scan instead of 0.007 and growing). An
    answer holding or resetting a local track its sub-report did not carry is now refused
    (``unexpected``); the tracker goes on without it after its reset timeout, as without any answer
    of that region."""
    svc = region_tracker(tmp_path, False, 0.0)
    bus = Bus([svc])
    for k in range(20):
        z = np.array([[-1000.0 + 10.0 * k, 0.0], [1000.0 - 10.0 * k, 50.0]])  # a target in each region
        bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", k, float(k), z)))
        for key, sub in bus.published[-2:]:
            rid = key.split("/")[3]
            held = sub.ids if rid == "x0y0" else tuple(range(10**6 + MAX_TRACKS * k, 10**6 + MAX_TRACKS * (k + 1)))
            bus.put(KEYS.region_resets(rid, "s1"), encode(TrackResets(
                sensor="s1", seq=k, t=sub.t, q_scale=1.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), region=rid,
                held=held)))
        with svc.guarded("on_tick", svc.tick_state_attrs):  # its reset timeout (0 here) is over
            svc.on_tick()
    assert svc.router is not None and len(svc.router.holder) <= 2
    assert svc.counters["reports"] == 20 and svc.counters["rejected_unexpected"] == 20


def test_an_answer_naming_another_region_than_its_key_is_refused(tmp_path: Path) -> None:
    """Each region's centres publish under their own identity (``region-<rid>``), which the router lets
    publish on their region's keys only; but a local tracker took the answering region from the
    payload's ``region``: x0y0's centre answering on its own key in x1y0's name would have been taken
    as x1y0's answer (x1y0's genuine one then refused as a second). Now a payload's region must be its
    key's (``sender``), and the genuine answer is taken."""
    svc = region_tracker(tmp_path, False, 10.0)
    bus = Bus([svc])
    bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", 0, 0.0, np.array([[-1000.0, 0.0], [1000.0, 50.0]]))))
    subs = {key.split("/")[3]: sub for key, sub in bus.published[-2:]}

    def answer_of(rid: str) -> TrackResets:
        return TrackResets(sensor="s1", seq=0, t=subs[rid].t, q_scale=1.0, ids=(), x=np.zeros((0, 4)),
                           P=np.zeros((0, 4)), region=rid, held=subs[rid].ids)

    bus.put(KEYS.region_resets("x0y0", "s1"), encode(answer_of("x1y0")))  # in x1y0's name on x0y0's key
    assert svc.counters["rejected_sender"] == 1 and not svc.answers
    bus.put(KEYS.region_resets("x1y0", "s1"), encode(answer_of("x1y0")))
    assert list(svc.answers) == [1] and svc.counters.get("rejected_unexpected", 0) == 0


@pytest.mark.parametrize("with_regions", [False, True])
def test_resets_that_come_after_their_wait_timed_out_are_late_not_rejected(tmp_path: Path,
                                                                           with_regions: bool) -> None:
    """An honest centre slow under load answered after the tracker's ``--reset-timeout``: the tracker
    had gone on, and counted the answer ``rejected_unexpected``, as it would a forgery (seen in a
    ``demo --scenario traffic`` at load average 62). An answer to one of the reports whose wait timed
    out is now counted ``late_resets`` and dropped; one for a report never sent is still refused."""
    svc = region_tracker(tmp_path, True, 0.0, with_regions)
    bus = Bus([svc])
    bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", 0, 0.0, np.array([[-1000.0, 0.0], [1000.0, 50.0]]))))
    with svc.guarded("on_tick", svc.tick_state_attrs):  # the wait (0 s here) is over
        svc.on_tick()
    assert svc.counters["reset_timeouts"] == 1 and svc.awaiting is None
    reports = bus.published[-2:] if with_regions else bus.published[-1:]
    for key, sent in reports:
        rid = key.split("/")[3] if with_regions else None
        late = TrackResets(sensor="s1", seq=0, t=sent.t, q_scale=1.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)),
                           region=rid, held=sent.ids if rid else ())
        bus.put(KEYS.region_resets(rid, "s1") if rid else KEYS.mtt_resets("s1"), encode(late))
        bus.put(KEYS.region_resets(rid, "s1") if rid else KEYS.mtt_resets("s1"), encode(replace(late, seq=99)))
    assert svc.counters["late_resets"] == len(reports)
    assert svc.counters["rejected"] == svc.counters["rejected_unexpected"] == len(reports)


# ---------------------------------------------------------------- primary tokens that serve nobody

def picture_at(t: float) -> TrackPicture:
    """An empty picture at ``t`` (numbered ``int(t)``)."""
    return TrackPicture(seq=int(t), t=t, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(),
                        fused_sensors=(), fused_seqs=(), left=(), stamp_ns=1, closing=False)


def answer(seq: int) -> TrackResets:
    """An empty answer to sensor s1's report ``seq`` (at ``seq`` s)."""
    return TrackResets(sensor="s1", seq=seq, t=float(seq), q_scale=1.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)))


FORGED = "9" * 20  # a primary token's instance claimed after any other (claim_instance)


def test_a_forged_primary_token_cannot_silence_a_region() -> None:
    """Any ``fusion`` identity may declare a primary token (``alive/mtt-primary/<region>/<instance>``).
    One with a late claim (``99...9``) makes the region's primary step down (a primary yields to a later
    claim: the split-brain rule) and its standby wait (a token stood): nothing of the region was
    published again while the token stood, and a dead region's standby never took over. Now a standby
    that made an answer SILENT_S (5 s) ago while nothing of its primary arrived for as long takes
    over beside the token, which serves nobody (``silent``: no primary yields to it) until it is
    withdrawn; a live primary, or a frozen one that wakes and publishes, keeps the old rules."""
    primary = Standby("x0y0", 0.0, instance=claim_instance("b", 1), primary=True)
    standby = Standby("x0y0", 0.0, instance=claim_instance("c", 2))
    standby.token(True, 0.0, primary.instance)
    for sb in (primary, standby):
        sb.token(True, 1.0, FORGED)
    assert primary.yields()  # the split-brain rule: it steps down
    primary.step_down(1.0)
    primary.token(False, 1.0, primary.instance)
    standby.token(False, 1.0, primary.instance)
    for k in range(2, 10):  # reports keep coming: both make their answers, nobody publishes them
        for sb in (primary, standby):
            sb.hold("res", answer(k), float(k))
        if 1.0 + SILENT_S <= k:
            break
        assert not primary.due(float(k)) and not standby.due(float(k))
    assert primary.due(1.0 + SILENT_S + 1.0) and standby.due(1.0 + SILENT_S + 1.0)
    assert [msg.seq for _, msg in primary.take_over()] == list(range(2, 7))
    standby.take_over()  # the two take over at once ...
    assert primary.silent == standby.silent == {FORGED} and not primary.yields() and not standby.yields()
    standby.token(True, 7.01, primary.instance)  # ... and see each other's tokens: the later claim keeps the region
    primary.token(True, 7.01, standby.instance)
    assert primary.yields() and not standby.yields()
    primary.token(False, 20.0, FORGED)  # withdrawn: a token of that instance is judged afresh
    assert primary.silent == set()


def test_a_live_primary_keeps_its_standby_waiting_and_a_woken_one_its_region() -> None:
    """The silence rule needs both: no output of the primary for SILENT_S and an answer made that long
    ago. A primary frozen past SILENT_S and woken (its token never went) publishes again: the standby
    that took over beside it hears another session on the region's keys and the instance order
    decides again: the standby's claim, the later, keeps the region (the woken primary missed the reports
    of its freeze; with the session ids' order it kept the region when its id was the lower)."""
    frozen = claim_instance("a-lower-session", 1)
    standby = Standby("x0y0", 0.0, instance=claim_instance("z-higher-session", 2))
    standby.token(True, 0.0, frozen)
    standby.hold("res", answer(0), 0.0)
    standby.token(True, SILENT_S, "a0")  # another token, fresh: it may be a primary that just took over
    assert not standby.due(SILENT_S + 0.5)
    standby.token(False, SILENT_S + 0.5, "a0")
    standby.sent(answer(0), SILENT_S + 0.5)
    for k in range(1, 20):
        standby.hold("res", answer(k), float(k))
        standby.sent(answer(k), k + 0.01)  # the primary answers too
        assert not standby.due(k + 0.01)
    standby.hold("res", answer(20), 20.0)  # a report the primary did not take: its answer stays withheld ...
    assert not standby.due(20.0 + SILENT_S - 0.1)
    standby.sent(answer(21), 21.0)  # ... but the primary publishes (and went past it: not held any more)
    assert not standby.due(20.0 + SILENT_S + 0.5)
    standby.hold("res", answer(22), 21.0)  # the next report: the primary froze before answering it
    assert standby.due(21.0 + SILENT_S)  # then falls silent (frozen): taken over beside its token
    standby.take_over()
    assert standby.silent == {frozen} and not standby.yields()
    standby.heard_remote(30.0)  # the frozen primary woke and publishes: the later claim keeps the region
    assert standby.silent == set() and not standby.yields()


# ---------------------------------------------------------------- Health

def test_a_standby_counting_many_kinds_of_rejection_still_reports_its_health(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A Health carries at most 32 counters (MAX_MAP_ITEMS) and a region standby counts 25 from its
    first picture: what sensor s1's own identity can send it (another sensor's name, a 6-D state, a
    value at the wire's edge, a number far ahead, a repeat, a different repeat, a time far ahead, a
    part that differs: 7 rejection reasons, ``duplicate`` and ``contested``) made 33, and its Health
    could not be made: the worker loop raised (measured with a service over a router: ``fatal:
    Health.counters: 34 entries exceed the limit of 32``, exit 1). A Health now carries the base
    counters and every rejection first, then the other counters that are not zero, as many as fit."""
    monkeypatch.setattr(ordered, "ORDER_WAIT_S", 0.0)  # its primary lists nothing: it takes them as they come
    bus, svc = centre_of_x0y0(tmp_path, standby=True)
    scans(bus, range(6))
    good = report("s1", 6)
    for msg in (replace(good, sensor="s2"),
                replace(good, x=np.zeros((1, 6)), P=np.eye(6), obs_H=np.zeros((2, 6))),
                replace(good, seq=20, t=good.t + 0.1, x=np.array([[1e50, 0.0, 0.0, 0.0]]), P=np.eye(4) * 1e100,
                        obs_z=np.array([[1e50, 0.0]])),
                replace(good, seq=10**6), good, good, replace(good, x=good.x + 1.0),
                replace(good, seq=7, t=1000.0), replace(report("s1", 7), seq=8),
                replace(good, seq=9, part=0, parts=2), replace(good, seq=9, ids=(2,), part=0, parts=2)):
        bus.put(KEYS.region_report("x0y0", "s1"), encode(msg))
    assert len(svc.counters) > MAX_MAP_ITEMS
    health = decode(encode(svc._health()), Health)
    rejections = {k: v for k, v in svc.counters.items() if k.startswith("rejected")}
    assert len(rejections) == 8 and {k: health.counters[k] for k in rejections} == rejections  # 7 reasons, total


def test_a_health_of_more_counters_than_fit_says_how_many_it_left_out() -> None:
    counters = {**dict.fromkeys(BASE_COUNTERS, 1), **{f"c{i}": i for i in range(40)}, "rejected_scale": 2}
    carried = health_counters(counters)
    assert len(carried) == MAX_MAP_ITEMS and carried["counters_omitted"] == 44 - (MAX_MAP_ITEMS - 1)
    assert carried["rejected_scale"] == 2 and "c0" not in carried and carried["c1"] == 1  # zero ones go first
    assert health_counters({"received": 3}) == {"received": 3}


# ---------------------------------------------------------------- serve picture

def picture_merger(tmp_path: Path) -> tuple[PictureMergeService, Bus, list[str]]:
    """``serve picture`` of the two regions of ``REGIONS_CONFIG`` on a bus, and their picture keys."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    svc = PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS, deployment=KEYS.deployment)
    return svc, Bus([svc]), [KEYS.region_picture(rid) for rid in regions.ids]

def test_a_region_picture_off_the_picture_grid_is_refused(tmp_path: Path) -> None:
    """Every region centre makes its pictures at multiples of ``[mtt] period`` (PictureClock). A region
    (its ``fusion`` identity, or a centre configured with another period) publishing pictures between
    them made a merged picture of each such time from that region alone: every other merged picture
    held none of the other regions' tracks (here 5 empty pictures among 11), uncounted and not
    contested. ``serve picture`` now refuses a picture off the grid (``time_jump``)."""
    svc, bus, (a, b) = picture_merger(tmp_path)
    for k in range(6):
        bus.put(a, encode(region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
        bus.put(b, encode(region_picture(k + 0.5, ())))
    assert [(p.t, p.ids) for p in bus.of(TrackPicture)] == [(float(k), (0, 1, 2, 3)) for k in range(6)]
    assert svc.counters["rejected_time_jump"] == 6


def test_a_region_picture_passed_over_is_counted_missing_and_contested(tmp_path: Path) -> None:
    """A picture time is merged once every region has sent its picture of that time or a later one (a
    region that started later has none). A region that had sent pictures before and whose next one is
    later (its picture of that time lost, or held as stamped far ahead and dropped) was taken for one that
    started later: the merged picture lacked its tracks, uncounted and not ``contested``. It is now
    counted ``missing_region`` and the merged picture ``contested``, as a region absent past ``--wait``."""
    svc, bus, (a, b) = picture_merger(tmp_path)
    for k in range(5):
        if k != 1:  # region x0y0's picture at t = 1 never comes
            bus.put(a, encode(region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
    merged = [(p.t, p.ids, p.contested) for p in bus.of(TrackPicture)]
    assert merged == [(0.0, (0, 1, 2, 3), False), (1.0, (1, 3), True)] + [(float(k), (0, 1, 2, 3), False)
                                                                       for k in range(2, 5)]
    assert svc.counters["missing_region"] == 1


def test_a_region_picture_numbered_off_the_grid_cannot_number_the_merged_pictures(tmp_path: Path) -> None:
    """``serve picture`` numbers its pictures as the first region picture it takes (a merger started again
    numbers on from the last one's). Region x0y0 (its identity) sending its first picture numbered 2**63 - 1
    at t = 0 made every later merged picture's number 2**63 and more: each refused by every receiver, for
    the whole run. A region picture numbered NUMBER_ROOM (2**62) or more, or at NUMBER_ROOM / 2 periods or
    more from t = 0, is refused (``seq_jump``): no centre numbers so."""
    svc, bus, (a, b) = picture_merger(tmp_path)
    for k in range(4):
        first = replace(region_picture(0.0, (0, 2)), seq=2**63 - 1)
        bus.put(a, encode(first if k == 0 else region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
    merged = bus.of(TrackPicture)
    assert [p.seq for p in merged] == [0, 1, 2, 3] and svc.counters["rejected_seq_jump"] == 1
    assert all(decode(encode(p), TrackPicture) for p in merged)


def merged_after_a_first_picture(tmp_path: Path,
                                  forged: TrackPicture) -> tuple[PictureMergeService, list[tuple[float, Any, bool]]]:
    """``serve picture`` of two regions given ``forged`` on x1y0's key first, then 4 genuine pictures of each
    region: the merger and its merged pictures' (t, ids, contested)."""
    svc, bus, (a, b) = picture_merger(tmp_path)
    bus.put(b, encode(forged))
    for k in range(4):
        bus.put(a, encode(region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
    return svc, [(p.t, p.ids, p.contested) for p in bus.of(TrackPicture)]


def test_a_first_region_picture_stamped_far_ahead_cannot_shut_its_region_out(tmp_path: Path) -> None:
    """The lead guard holds a region picture stamped far ahead of the data, but took the first picture of all
    as it came (nothing to lead yet; and no region's interval known): x1y0's identity sending first a picture
    at t = 10^9 made x1y0 a region that started later, and each of its genuine pictures came after its time
    was merged without it and was refused (``conflict``: 4 of 4 merged pictures without its tracks,
    contested). The first pictures now wait until two regions have sent one (or ``--wait``) and go through
    the guard in time order, each region's interval its period from the start: the far one is held, dropped
    when x1y0's genuine picture comes (``time_lead``), and the merged pictures are the clean run's."""
    svc, merged = merged_after_a_first_picture(tmp_path, replace(region_picture(1e9, (1, 3)), seq=10**9))
    assert merged == [(float(k), (0, 1, 2, 3), False) for k in range(4)]
    assert svc.counters["rejected"] == svc.counters["rejected_time_lead"] == 1


def test_a_first_region_picture_stamped_far_behind_is_not_merged(tmp_path: Path) -> None:
    """The lead guard took the first picture of all as it came: x1y0's identity sending, before any other, a
    picture at t = -10^12 had it merged alone as a picture of that time (x0y0 taken for a region that
    started later; uncounted, not contested), then the clean run's (before the redteam60 session). The first
    pictures now wait until two agree within ``max_time_jump_s`` (lead.py, the start): it is dropped and
    counted (``time_behind``) and the merged pictures are the clean run's."""
    svc, merged = merged_after_a_first_picture(tmp_path, replace(region_picture(0.0, (1, 3)), t=-1e12))
    assert merged == [(float(k), (0, 1, 2, 3), False) for k in range(4)]
    assert svc.counters["rejected"] == svc.counters["rejected_time_behind"] == 1


def test_a_forged_token_cannot_silence_a_centre_that_answers_nothing() -> None:
    """The unsharded decentralized centre publishes pictures only (no answers): its standby judges the
    token by them."""
    standby = Standby("all", 0.0, instance="c2")
    standby.token(True, 0.0, "0")  # forged; the primary is dead
    for k in range(1, 8):
        standby.hold("pic", picture_at(float(k)), float(k))
    assert not standby.due(SILENT_S) and standby.due(1.0 + SILENT_S)


# ---------------------------------------------------------------- the launcher's report

class TokenSample(NamedTuple):
    key_expr: str
    kind: zenoh.SampleKind


def test_the_launcher_reports_failovers_of_its_own_centres_only(tmp_path: Path) -> None:
    """The launcher listed a failover for every scope whose last primary token went: any ``fusion``
    identity declaring and withdrawing tokens of made-up scopes grew its report (and ``summary.json``)
    by one failover each, for good, and made every picture walk that list (1,000 tokens: 1,000
    failovers of scopes no centre has). It now counts the scopes of its deployment's centres only
    (each region of ``[regions]``, or ``all``)."""
    config = tmp_path / "regions.toml"
    config.write_text("[multitarget]\nstandby = true\n" + REGIONS_CONFIG)
    settings = load_settings(config)
    assert failover_scopes(settings, config) == {"x0y0", "x1y0"}
    launcher = Launcher(settings, [], quiet=True, scopes=failover_scopes(settings, config))
    put, gone = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    for k in range(1000):
        for kind in (put, gone):
            launcher._on_primary_token(TokenSample(launcher.keys.primary(f"zz{k}", "0"), kind))
    for instance, kind in (("a", put), ("a", gone), ("b", put)):  # a primary of x0y0 dies, its standby takes over
        launcher._on_primary_token(TokenSample(launcher.keys.primary("x0y0", instance), kind))
    assert [(f.scope, f.took_over_ns is not None) for f in launcher.watch.failovers] == [("x0y0", True)]


def test_a_flood_of_primary_tokens_is_followed_a_bounded_number(tmp_path: Path) -> None:
    """Any ``fusion`` identity may declare any ``alive/mtt-primary/<rid>/*``, and a region's standby (its
    ``present`` a copy of the holders at each token) and the launcher (a copy of the scope's tokens at each
    claim) followed them all: 20,000 forged tokens cost each 2.6-2.7 s of CPU. Each now follows at most
    ``CENTRE_TOKENS_KEPT`` of a region's, as ``serve picture`` its centre tokens, and counts the rest
    (``tokens_ignored``; the launcher's ``summary.json``: ``primary_tokens_ignored``); the genuine primary,
    declared first, still keeps its standby waiting, and its death is still a failover."""
    kept = getattr(standby_module, "CENTRE_TOKENS_KEPT", 0)
    n = 5_000
    _, svc = centre_of_x0y0(tmp_path, standby=True)
    config = tmp_path / "launch.toml"
    config.write_text("[multitarget]\nstandby = true\n" + REGIONS_CONFIG)
    settings = load_settings(config)
    launcher = Launcher(settings, [], quiet=True, scopes=failover_scopes(settings, config))
    put, gone = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    genuine = claim_instance("a", 1)
    svc.primary_seen.append((True, 0.0, genuine))
    launcher._on_primary_token(TokenSample(launcher.keys.primary("x0y0", genuine), put))
    for i in range(n):
        svc.primary_seen.append((True, 0.5, f"forged{i}"))
        launcher._on_primary_token(TokenSample(launcher.keys.primary("x0y0", f"forged{i}"), put))
    svc._failover_tick()
    standby = svc.standby
    assert len(standby.holders) == kept and genuine in standby.holders and not standby.due(100.0)
    assert svc.counters["tokens_ignored"] == n + 1 - kept
    assert len(launcher.watch.primaries["x0y0"]) == kept and launcher.watch.tokens_ignored == n + 1 - kept
    for i in range(n):  # withdrawn, then the genuine primary dies: its standby takes over, a failover
        svc.primary_seen.append((False, 1.0, f"forged{i}"))
        launcher._on_primary_token(TokenSample(launcher.keys.primary("x0y0", f"forged{i}"), gone))
    svc.primary_seen.append((False, 2.0, genuine))
    launcher._on_primary_token(TokenSample(launcher.keys.primary("x0y0", genuine), gone))
    while svc.primary_seen:
        alive, now, instance = svc.primary_seen.popleft()
        standby.token(alive, now, instance)
    assert not standby.holders and standby.due(2.0 + 1.0)
    assert [f.scope for f in launcher.watch.failovers] == ["x0y0"]


def test_a_flood_of_primary_tokens_between_two_ticks_is_queued_a_bounded_number(tmp_path: Path) -> None:
    """A centre's Zenoh thread queues every change of its region's primary tokens for its worker's next tick
    (50 ms), and the queue had no bound: 20,000 forged tokens declared between two ticks were 20,000 entries
    (the bound on the tokens followed applies only when the worker reads them). At most
    ``PRIMARY_CHANGES_KEPT`` (each token it may follow appearing and going within one tick) now wait, the rest
    dropped and counted ``tokens_dropped``; the genuine primary, declared first, still keeps its standby waiting."""
    kept = getattr(standby_module, "PRIMARY_CHANGES_KEPT", 0)
    _, svc = centre_of_x0y0(tmp_path, standby=True)
    key = KEYS.primary("x0y0", claim_instance("a", 1))
    svc._on_primary(TokenSample(key, zenoh.SampleKind.PUT))  # type: ignore[arg-type]
    n = 20_000
    for i in range(n):
        svc._on_primary(TokenSample(KEYS.primary("x0y0", f"forged{i}"), zenoh.SampleKind.PUT))  # type: ignore[arg-type]
    assert len(svc.primary_seen) == kept == 2 * standby_module.CENTRE_TOKENS_KEPT
    svc._failover_tick()
    assert svc.counters["tokens_dropped"] == n + 1 - kept
    assert claim_instance("a", 1) in svc.standby.holders and not svc.standby.due(100.0)
    assert not svc.primary_seen


# ---------------------------------------------------------------- an id a third region issues later

THREE_REGIONS = """[regions]
margin = 500.0
grid = {origin = [-7500.0, -5000.0], cell = [5000.0, 10000.0], nx = 3, ny = 1}
"""


def rows_report(sensor: str, k: int, targets: list[tuple[int, float, float]]) -> TrackReport:
    """Scan ``k`` of ``sensor`` (at ``k`` s plus a third of a second per sensor): a confirmed local track
    ``(id, x0, y)`` of each target flying along x from ``(x0, y)`` at 10 m/s."""
    t = k + SENSORS.index(sensor) / 3.0
    base = one_track_report(sensor, k)
    n = len(targets)
    x = np.array([[x0 + 10.0 * t, 10.0, y, 0.0] for _, x0, y in targets]).reshape(n, 4)
    return replace(base, t=t, ids=tuple(i for i, _, _ in targets), x=x, P=np.tile(base.P, (n, 1)),
                   confirmed=(True,) * n, detected=(True,) * n, obs_H=np.tile(base.obs_H, (n, 1)),
                   obs_R=np.tile(base.obs_R, (n, 1)), obs_z=x[:, [0, 2]], started=(k == 0,) * n)


def three_regions(tmp_path: Path, c_id: int, target_d: bool = False, restart_at: int | None = None
                  ) -> tuple[list[TrackPicture], PictureMergeService]:
    """Three regions in a row (x0y0, x1y0, x2y0; ids 0, 3, ... / 1, 4, ... / 2, 5, ...), their centres and
    ``serve picture`` on one bus, 30 scans of three sensors: target A in x1y0 from the start, target B in x2y0
    from scan 10, and target C in x1y0 that a hand-over of x0y0 brings under id ``c_id`` after scan 4 (its
    record made by a centre of x1y0 on its own over scans 0-4; the trackers' rows of it from scan 5 on);
    x0y0 sees none, or (``target_d``) target D from scan 10. ``restart_at``: the merger (``--snapshot``) is
    killed before that scan and another started with its snapshot. Returns the merged pictures and the merger."""
    config = tmp_path / "three.toml"
    config.write_text(THREE_REGIONS)
    regions = load_regions(config)
    assert regions is not None and regions.ids == ("x0y0", "x1y0", "x2y0")

    def centre(rid: str) -> MttCentreService:
        return MttCentreService("mtt-decentralized", MttConfig(sensors=SENSORS, max_lag=3.0), 4, region=rid,
                                regions=regions, service_id=rid, options=OPTIONS, deployment=KEYS.deployment)

    def merging() -> PictureMergeService:
        return PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS,
                                   deployment=KEYS.deployment, snapshot=tmp_path / "picture.snapshot")

    centres, merger, merged = [centre(rid) for rid in regions.ids], merging(), []
    bus, aside = Bus([*centres, merger]), centre("x1y0")
    target_c = [(3, -1000.0, -3000.0)]
    for k in range(5):
        for s in SENSORS:
            Bus([aside]).put(KEYS.region_report("x1y0", s), encode(rows_report(s, k, target_c)))
    held = aside.engine.region.centre  # type: ignore[union-attr]
    record = handover_to_wire(held.hand_over(next(iter(held.tracks))), "x0y0", 0)
    for k in range(30):
        if k == restart_at:  # killed (no stop), started again: the snapshot tells what it merged
            merged += [m for key, m in bus.published if key == KEYS.mtt_picture()]
            merger = merging()
            bus = Bus([*centres, merger])
            merger.on_start()
            merger.settle_until = time.monotonic()  # HISTORY_SETTLE_S later (no cache here to settle)
        if k == 5:
            bus.put(KEYS.region_handover("x1y0", "x0y0"), encode(replace(record, id=c_id)))
        for s in SENSORS:
            for rid, targets in (("x0y0", [(4, -6000.0, -2000.0)] if target_d and k >= 10 else []),
                                 ("x1y0", [(1, -1000.0, 0.0)] + (target_c if k >= 5 else [])),
                                 ("x2y0", [(2, 4000.0, 2000.0)] if k >= 10 else [])):
                bus.put(KEYS.region_report(rid, s), encode(rows_report(s, k, targets)))
        with merger.guarded("on_tick", merger.tick_state_attrs):
            merger.on_tick()
    assert centres[1].counters["taken_over"] == 1
    return merged + [m for key, m in bus.published if key == KEYS.mtt_picture()], merger


def shown_ids(picture: TrackPicture) -> list[set[int]]:
    """The ids of the confirmed tracks of the merged picture within 50 m of target A, of B, of C, of D."""
    at = np.array([[-1000.0, 0.0], [4000.0, 2000.0], [-1000.0, -3000.0], [-6000.0, -2000.0]]) + [10.0 * picture.t, 0.0]
    near = np.hypot(*(picture.x[:, None, [0, 2]] - at).transpose(2, 0, 1)) < 50.0  # (tracks, targets)
    return [{i for i, c, n in zip(picture.ids, picture.confirmed, near[:, j]) if c and n} for j in range(len(at))]


def shown_targets(picture: TrackPicture) -> tuple[bool, bool, bool]:
    """Whether a confirmed track of the merged picture lies within 50 m of target A, of B, of C."""
    return tuple(bool(ids) for ids in shown_ids(picture)[:3])  # type: ignore[return-value]


def test_a_hand_over_naming_an_id_a_third_region_issues_later_drops_no_target(tmp_path: Path) -> None:
    """A region's identity may hand a neighbour a track under any id, and ids are unique only as each
    region numbers its own (region r of R: r, r + R, ...): x0y0 handing x1y0 its own track A under id 2,
    which x2y0 gives target B five scans later, had the merger show id 2 once (the first region's,
    ``seen_twice``): B was missing from the 16 merged pictures from t = 14 s on (A in all, 20 ids ``seen_twice``;
    without the forgery both in all). The merger now tells a hand-over's two copies of one track (one
    target: within the association gate, as the duplicate merge tests two tracks) from two tracks under
    one id: the id's issuing region keeps it, the other is shown under an alias (``id_collision``, the
    picture contested). (Since the redteam59 session x1y0 refuses a record naming its confirmed track A's
    local tracks; here the forged id comes with a track C that x1y0 holds nothing of.)"""
    clean, _ = three_regions(tmp_path, 0)  # x0y0's first id
    merged, merger = three_regions(tmp_path, 2)
    assert len(clean) == len(merged) >= 25
    late = [p for p in clean if p.t >= 14.0]
    assert all(shown_targets(p) == (True, True, True) for p in late)
    shown_late = [shown_targets(p) for p in merged if p.t >= 14.0]
    assert shown_late == [(True, True, True)] * len(late), f"(A, B, C) shown: {shown_late}"
    assert all(len(set(p.ids)) == len(p.ids) for p in merged)
    assert merger.counters["id_collision"] > 0 and any(p.contested for p in merged)


def test_an_id_planted_by_its_issuing_region_does_not_rename_the_track_shown_under_it(tmp_path: Path) -> None:
    """A region's identity may hand a neighbour a track under an id it issues itself later: x0y0 handing x1y0
    target C under id 0, which x0y0 gives target D five scans later. The merger kept an id for its issuing
    region's track, so from then on C, shown under 0 since t = 5 s, was shown under an alias (its id changed
    once, 20 pictures ``id_collision``). Whichever region is the forger, the track shown under an id in the
    previous merged picture now keeps it and the newcomer is shown under an alias from its first picture:
    no target's id changes (``id_collision`` counted, the pictures contested, as before)."""
    merged, merger = three_regions(tmp_path, 0, target_d=True)
    per_target = [set().union(*(shown_ids(p)[j] for p in merged if p.t >= 6.0)) for j in range(4)]
    assert all(len(ids) == 1 for ids in per_target), f"ids of A, B, C, D: {per_target}"
    assert per_target[2] == {0} and per_target[3] != {0}
    assert merger.counters["id_collision"] > 0 and any(p.contested for p in merged)


def test_a_restarted_merger_keeps_an_id_with_the_track_shown_under_it(tmp_path: Path) -> None:
    """The same forgery, the merger killed at scan 20 (C under id 0, D under an alias since scan 10) and
    started again with its ``--snapshot``: the snapshot held the last merged time alone, so the new merger
    gave id 0 to its issuing region's D and showed C under an alias, both ids changed (redteam63). It now
    keeps the region that showed each id too: every merged picture is the one without the restart."""
    (tmp_path / "clean").mkdir()
    clean, _ = three_regions(tmp_path / "clean", 0, target_d=True)
    merged, merger = three_regions(tmp_path, 0, target_d=True, restart_at=20)
    per_target = [set().union(*(shown_ids(p)[j] for p in merged if p.t >= 6.0)) for j in range(4)]
    assert all(len(ids) == 1 for ids in per_target), f"ids of A, B, C, D: {per_target}"
    assert [(p.seq, p.t, p.ids, p.x.tobytes()) for p in merged] == [(p.seq, p.t, p.ids, p.x.tobytes()) for p in clean]
    assert merger.counters["id_collision"] > 0 and len(clean) >= 25


# ---------------------------------------------------------------- a start of one region's pictures

def merged_after_a_forged_start(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, config: str,
                                forged: tuple[float, ...] = (), wait_out: bool = False
                                ) -> tuple[list[tuple[Any, ...]], PictureMergeService]:
    """``serve picture`` of ``config``'s regions (x0y0 first) on a bus, its clock a fake one: x0y0's pictures at the
    times ``forged`` first (numbered 10^9 on), then (``wait_out``: 5 s later, the merger ticking every half second,
    so that they are released and merged alone after ``--wait``) 12 genuine pictures of each region, one period
    apart, in the order x1y0, ..., x0y0. The merger and its merged pictures' (seq, t, ids, x, contested, missing)."""
    now = [100.0]
    monkeypatch.setattr(picture_merge, "time", SimpleNamespace(monotonic=lambda: now[0]))
    tmp_path.mkdir()
    (tmp_path / "r.toml").write_text(config)
    regions = load_regions(tmp_path / "r.toml")
    assert regions is not None
    svc = PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS, deployment=KEYS.deployment)
    bus, keys = Bus([svc]), [KEYS.region_picture(rid) for rid in regions.ids]
    R = len(keys)
    for j, t in enumerate(forged):
        bus.put(keys[0], encode(replace(region_picture(0.0, (0, R), x=7.0), t=t, seq=10**9 + j)))
    for _ in range(10 if wait_out else 0):
        now[0] += 0.5
        svc.on_tick()
    for k in range(12):
        for r in [*range(1, R), 0]:
            bus.put(keys[r], encode(region_picture(float(k), (r, r + R), x=float(k))))
        now[0] += 1.0
        svc.on_tick()
    svc.on_stop()
    return [(p.seq, p.t, p.ids, p.x.tobytes(), p.contested, p.missing) for p in bus.of(TrackPicture)], svc


@pytest.mark.parametrize("config", [THREE_REGIONS, REGIONS_CONFIG], ids=["3 regions", "2 regions"])
@pytest.mark.parametrize(("forged", "wait_out"), [((1e9, 1e9 + 1.0), False), ((1e9,), True), ((1e9, 1e9 + 1.0), True),
                                                  ((-1e12, -1e12 + 1.0), False), ((-1e12,), True)])
def test_a_start_of_one_regions_pictures_is_abandoned_when_two_regions_agree_against_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, config: str, forged: tuple[float, ...],
        wait_out: bool) -> None:
    """x0y0's identity sending first two pictures that agree with each other (10^9 s ahead, or 10^12 s before the
    data), or one more than ``--wait`` before any other region's (released alone: a region's first picture starts),
    set the merger's start (lead.py, the start): 10^9 ahead, the genuine pictures came behind it and, once the forged
    one was merged after ``--wait``, every one was late (``conflict``): 2 to 5 merged, 0 of 12 the clean run's;
    10^12 before, 1 or 2 forged pictures merged and every genuine one numbered from them: 0 of 12. The
    merger now abandons a start of one region's pictures when two regions' pictures agree against it, more than
    ``max_time_jump_s`` away (lead.SoleStart, as serve mtt-centre): its state put back as before its first picture,
    every genuine picture merged as in the clean run (those merged from the forged start before, when the genuine
    ones came after ``--wait``, stay published)."""
    clean, _ = merged_after_a_forged_start(tmp_path / "clean", monkeypatch, config)
    attacked, merger = merged_after_a_forged_start(tmp_path / "attacked", monkeypatch, config, forged, wait_out)
    extra = len(attacked) - len(clean)
    assert attacked[extra:] == clean and len(clean) == 12
    assert [p[1] for p in attacked[:extra]] == list(forged)[:extra]
    assert merger.counters["start_abandoned"] == 1
    assert merger.counters["rejected"] == 1  # the first genuine picture held against the start, then taken again
