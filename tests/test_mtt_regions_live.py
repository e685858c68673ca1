"""Live region centres (issue 27): local trackers publishing by region, one centre per region
(``serve mtt-centre --region``), the pictures merged (``serve picture``) and recorded; the
recording replays (``replay --regions config``) to the merged pictures, with hand-overs and no
track lost or duplicated at them. Two deployments: on the in-process bus of
``test_hostile_messages`` (every service through its own dispatch, one message at a time) and over
a loopback Zenoh router, every service in its own thread (real interleavings). About 15 s."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any, Callable

import pytest
from support import WAIT_S, assert_same_pictures, feed_one_by_one, free_port, numbered_measurements, wait_until
from test_hostile_messages import OPTIONS, Bus, _matches

from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.keys import Keys
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.regions import load_regions
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate
from fedtrack.services.base import Service
from fedtrack.services.recorder import Recorder
from fedtrack.wire import HandOver, encode
from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive

CONFIG = """[mtt]
sensors = ["s1", "s2", "s3"]
max_lag = 3.0
clutter_density = 1.2e-7

[regions]
margin = 500.0
grid = {origin = [-5000.0, -5000.0], cell = [5000.0, 10000.0], nx = 2, ny = 1}
"""


def scenario(tmp_path: Path) -> tuple[list[Any], MttConfig, Path]:
    out = tmp_path / "scenario"
    simulate(Scenario(targets=10, duration=30.0, clutter=3.0, late=0.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 4, out)
    msgs = numbered_measurements(out / "measurements.jsonl")
    config = tmp_path / "config.toml"
    config.write_text(CONFIG)
    return msgs, MttConfig(sensors=("s1", "s2", "s3"), max_lag=3.0, clutter_density=1.2e-7), config


def services(tmp_path: Path, algorithm: str, config: Path, cfg: MttConfig, common: dict[str, Any]
             ) -> tuple[list[MttCentreService], list[MttLocalService], PictureMergeService, Recorder]:
    regions = load_regions(config)
    assert regions is not None
    centres = [MttCentreService(algorithm, cfg, 4, region=rid, regions=regions, service_id=rid, **common)
               for rid in regions.ids]
    local = [MttLocalService(s, algorithm == "mtt-federated", cfg, 5.0, regions=regions, service_id=s, **common)
             for s in ("s1", "s2", "s3")]
    merger = PictureMergeService(regions, 4, 5.0, cfg.period, service_id="picture", **common)
    recorder = Recorder(tmp_path / "rec.db", tmp_path / "out", service_id="rec", **common)
    return centres, local, merger, recorder


def check(tmp_path: Path, algorithm: str, config: Path, live: list[dict[str, Any]]) -> None:
    """The recording replays to the live merged pictures; no id twice in a picture, none missing
    for one picture while shown before and after (a track lost at a hand-over)."""
    replayed = tmp_path / "replayed.jsonl"
    replay_mtt(algorithm, tmp_path / "out" / "measurements.jsonl", config, replayed, regions="config")
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])
    shown = [{t["id"] for t in p["tracks"]} for p in live]
    assert all(len(s) == len(p["tracks"]) for s, p in zip(shown, live))
    gaps = [i for k in range(1, len(shown) - 1) for i in shown[k - 1] & shown[k + 1] - shown[k]]
    assert gaps == []
    assert len(live) >= 25 and sum(len(s) for s in shown) > 150


def run_on_bus(tmp_path: Path, algorithm: str, config: Path, cfg: Any, msgs: list[Any],
               prepare: Callable[[list[Any]], None] | None = None, lost: type | None = None
               ) -> tuple[Any, Any, Any, Any, Bus]:
    """The region deployment's services on the in-process bus: every scan published, then each
    service stopped in order (trackers, centres, merger; the recorder last, writing its files);
    returns the services and the bus (what crossed it). ``prepare``: called with the local trackers
    before the first scan; ``lost``: the centres' messages of this type never arrive."""
    centres, local, merger, recorder = services(tmp_path, algorithm, config, cfg,
                                                {"options": OPTIONS, "deployment": "hostile"})
    recorder.on_start()
    bus = Bus([*centres, *local, merger, recorder])
    for c in centres if lost is not None else []:
        c.publish = (lambda key, msg, publish=c.publish:  # type: ignore[method-assign]
                     None if isinstance(msg, lost) else publish(key, msg))
    if prepare is not None:
        prepare(local)
    for m in msgs:
        bus.put(Keys("hostile").sensor_meas(m.sensor), encode(m))
    for svc in [*local, *centres, merger]:
        svc.on_stop()
        bus.drain()
    recorder.on_stop()
    return centres, local, merger, recorder, bus


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_region_centres_on_the_bus_equal_the_replay_of_their_recording(tmp_path: Path, algorithm: str) -> None:
    msgs, cfg, config = scenario(tmp_path)
    centres, local, merger, recorder, bus = run_on_bus(tmp_path, algorithm, config, cfg, msgs)
    assert sum(c.counters.get("handed_over", 0) for c in centres) >= 2
    assert sum(c.counters.get("taken_over", 0) for c in centres) == sum(c.counters.get("handed_over", 0)
                                                                        for c in centres)
    assert merger.counters.get("seen_twice", 0) == 0 and merger.counters.get("missing_region", 0) == 0
    assert all(svc.counters.get("rejected", 0) == 0 for svc in [*centres, *local, merger, recorder])
    assert bus.of(HandOver)
    live = [json.loads(x) for x in (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()]
    merged = [p for key, p in bus.published if key == Keys("hostile").mtt_picture() and not p.closing]
    assert len(live) == len(merged)
    print(algorithm, {c.id: {k: c.counters.get(k, 0) for k in ("handed_over", "taken_over", "in_flight")}
                      for c in centres}, len(live))
    check(tmp_path, algorithm, config, live)


def test_a_region_without_a_centre_holds_no_tracker_up_and_the_recording_still_replays(tmp_path: Path) -> None:
    """Region x0y0's centre gone from t = 8 to 14 s (its centre and standby dead: nothing takes its
    sub-reports, as Zenoh's matching status tells the trackers), then back with its state: each tracker
    goes on at once with the answer of x1y0 (counted ``unreached``), and the recording replays to the
    merged pictures (the replay waits for the regions whose entries list a report). Before, every
    tracker waited for x0y0's answer to a report it never got, ``--reset-timeout`` live (every region
    late), here for ever: no report after t = 8 s, and the replay stopped ('cannot be replayed')."""
    msgs, cfg, config = scenario(tmp_path)
    centres, local, merger, recorder = services(tmp_path, "mtt-federated", config, cfg,
                                                {"options": OPTIONS, "deployment": "hostile"})
    recorder.on_start()
    bus = Bus([*centres, *local, merger, recorder])
    gone, keys = centres[0], Keys("hostile")

    def reaches(key: str) -> bool:
        return any(_matches(sub.key, key) for svc in bus.services for sub in svc._subscriptions)

    for svc in local:
        svc.reaches = reaches  # type: ignore[method-assign]
    for m in msgs:
        away = 8.0 <= m.t < 14.0
        if away == (gone in bus.services):
            bus.services = [svc for svc in bus.services if svc is not gone] if away else [gone, *bus.services]
            bus._routes.clear()
        bus.put(keys.sensor_meas(m.sensor), encode(m))
        # none waits while x0y0 is gone (after, its first report waits for another sensor's: the lead guard)
        assert not away or all(svc.awaiting is None for svc in local), m.t
    for svc in [*local, *centres, merger]:
        svc.on_stop()
        bus.drain()
    recorder.on_stop()
    away_reports = sum(8.0 <= m.t < 14.0 for m in msgs)
    assert sum(svc.counters.get("unreached", 0) for svc in local) == away_reports
    assert sum(svc.counters.get("reports", 0) for svc in local) == len(msgs)
    assert all(svc.counters.get("rejected", 0) == 0 for svc in [*centres, *local, merger, recorder])
    live = [json.loads(x) for x in (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()]
    assert len(live) >= 29
    replayed = tmp_path / "replayed.jsonl"
    replay_mtt("mtt-federated", tmp_path / "out" / "measurements.jsonl", config, replayed, regions="config")
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])


def test_a_region_not_yet_known_to_a_tracker_is_waited_for(tmp_path: Path) -> None:
    """A tracker's session learns the centres' subscribers some time after it opens (under load, after
    its first reports): Zenoh's matching status says no subscriber while the centres do take its
    sub-reports. Every region is waited for until one of its sub-reports reached it, so the trackers
    adopt the answers the replay adopts. Before, with no match for its first two reports' regions, each
    tracker went on without their answers (``unreached``), and the live pictures left the replay's."""
    msgs, cfg, config = scenario(tmp_path)

    def unknown_at_first() -> Any:
        asked = {"n": 0}

        def reaches(key: str) -> bool:  # no match for the first two reports' sub-reports (2 regions each)
            asked["n"] += 1
            return asked["n"] > 4
        return reaches

    def unmatched(local: list[Any]) -> None:
        for svc in local:
            svc.reaches = unknown_at_first()

    _, local, _, _, _ = run_on_bus(tmp_path, "mtt-federated", config, cfg, msgs, unmatched)
    live = [json.loads(x) for x in (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()]
    check(tmp_path, "mtt-federated", config, live)  # the replay's pictures, none lost at a hand-over
    assert sum(svc.counters.get("unreached", 0) for svc in local) == 0


def test_the_merger_stopped_awaits_every_regions_closing_record(tmp_path: Path) -> None:
    """At its stop the merger holds on (``held``, bounded by ``drain_deadline_s``) while a region that sent
    pictures has not sent its closing record, the entries its centre processed after its last picture: before,
    a merger stopped with x0y0's still on its way (the trackers, then the centres, stopped as the launcher
    does) recorded a closing record without them, and the recording did not replay to the live pictures."""
    msgs, cfg, config = scenario(tmp_path)
    centres, local, merger, recorder = services(tmp_path, "mtt-federated", config, cfg,
                                                {"options": OPTIONS, "deployment": "hostile"})
    recorder.on_start()
    bus = Bus([*centres, *local, merger, recorder])
    for m in msgs:
        bus.put(Keys("hostile").sensor_meas(m.sensor), encode(m))
    for svc in local:
        svc.on_stop()
        bus.drain()
    assert merger.held()  # pictures of both regions, no closing record yet
    centres[1].on_stop()
    bus.drain()
    assert merger.held() and merger.closing[1] is not None  # x1y0's came, x0y0's is on its way
    centres[0].on_stop()
    bus.drain()
    assert not merger.held()


def test_hand_overs_that_never_arrive_are_counted_expired_by_their_trackers(tmp_path: Path) -> None:
    """Every ``HandOver`` lost on its way: each tracker flags a handed-over track's rows as awaiting its new
    owner for ``[mtt] unsupported_s`` of data time, then frees them, counted ``handover_expired`` by the
    tracker service, one per local track (before: its router counted them, the service never did: it looked
    around the split of a report, and they expire where the answers are learnt)."""
    msgs, cfg, config = scenario(tmp_path)
    centres, local, _, _, _ = run_on_bus(tmp_path, "mtt-federated", config, cfg, msgs, lost=HandOver)
    expired = [svc.router.expired for svc in local]
    assert sum(c.counters.get("handed_over", 0) for c in centres) >= 2 and sum(expired) >= 2
    assert [svc.counters.get("handover_expired", 0) for svc in local] == expired


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_region_centres_over_zenoh_equal_the_replay_of_their_recording(tmp_path: Path, algorithm: str) -> None:
    """Every service in its own thread over a loopback router: the centres see the sub-reports and
    hand-overs in whatever order Zenoh gives them; the recording still replays to the pictures."""
    msgs, cfg, config = scenario(tmp_path)
    port = free_port()
    keys = Keys("regionlive")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    opts = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=5.0)
    centres, local, merger, recorder = services(tmp_path, algorithm, config, cfg,
                                                {"options": opts, "deployment": "regionlive"})
    everyone: list[Service] = [recorder, merger, *centres, *local]
    threads = {svc.id: threading.Thread(target=svc.run, daemon=True) for svc in everyone}
    for th in threads.values():
        th.start()
    session = open_session(opts)
    try:
        assert wait_alive(session, [keys.alive(svc.role, svc.id) for svc in everyone], WAIT_S) == set()
        trackers = {svc.sensor: svc for svc in local}
        fed: dict[str, int] = {}
        for m in msgs:
            fed[m.sensor] = fed.get(m.sensor, 0) + 1
            feed_one_by_one(session, keys.sensor_meas(m.sensor), encode(m), trackers.get(m.sensor), fed[m.sensor])
        sent = {s: sum(m.sensor == s for m in msgs) for s in ("s1", "s2", "s3")}
        assert wait_until(lambda: all(svc.counters.get("reports", 0) + svc.counters.get("late", 0) == sent[svc.sensor]
                                      and svc.awaiting is None for svc in local), timeout=30.0), \
            str({svc.id: (dict(svc.counters), getattr(svc, "awaiting", None)) for svc in [*local, *centres]})
        assert all(svc.counters.get("reset_timeouts", 0) == 0 for svc in local)
        for group in (local, centres, [merger]):
            for svc in group:
                svc.stop()
            for svc in group:
                threads[svc.id].join(WAIT_S)
        assert wait_until(lambda: recorder.counters.get("pictures_recorded", 0) == merger.counters["pictures"]), \
            str((dict(recorder.counters), dict(merger.counters)))
        recorder.stop()
        threads[recorder.id].join(WAIT_S)
    finally:
        close_session(session)
        close_session(router)
    assert sum(c.counters.get("handed_over", 0) for c in centres) >= 2
    # an id in both regions' pictures of one time (a region made its picture before handing the track
    # over, the other after taking it over) is shown once: counted, and replayed the same way
    assert merger.counters.get("missing_region", 0) == 0
    assert all(svc.counters.get("rejected", 0) == 0 for svc in everyone)
    live = [json.loads(x) for x in (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()]
    check(tmp_path, algorithm, config, live)


LAUNCH = """
[deployment]
name = "regionlaunch{port}"
seed = 4
pacing = "realtime"
speed = 4.0
router_listen = "tls/127.0.0.1:{port}"
ready_timeout_s = 60.0

[zenoh]
tls_dir = "certs"

[multitarget]
algorithm = "mtt-federated"
targets = 10
sensors = "pos:1.0,pos:0.7,pos:1.3"
duration = 8.0
clutter = 3.0

[mtt]
clutter_density = 1.2e-7
sensors = ["s1", "s2", "s3"]

[regions]
margin = 500.0
grid = {{origin = [-5000.0, -5000.0], cell = [5000.0, 10000.0], nx = 2, ny = 1}}
"""


def test_launch_starts_a_centre_per_region_and_the_merger(tmp_path: Path) -> None:
    """``fedtrack launch`` with ``[regions]``: every role a process; the recorded merged pictures
    equal ``replay --regions config`` of the recording. With mutual TLS and the router's access
    control: each region's centre under its own identity (``region-<rid>``) is let publish its
    region's outputs and hand-overs."""
    import subprocess
    import sys

    config = tmp_path / "regions.toml"
    config.write_text(LAUNCH.format(port=free_port()))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "launch", str(config), "--out", str(out)],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert {"mtt-centre/x0y0", "mtt-centre/x1y0", "picture/picture"} <= set(summary["exit_codes"])
    assert set(summary["exit_codes"].values()) == {0} and summary["rejected"] == 0
    live = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
    replayed = tmp_path / "replayed.jsonl"
    replay_mtt("mtt-federated", out / "measurements.jsonl", out / "config.toml", replayed, regions="config")
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])
    assert len(live) >= 5 and summary["health"]["picture/picture"]["pictures"] == len(live) + 1  # + closing
    assert sorted(p.name for p in (tmp_path / "certs").glob("region-*.pem")) == ["region-x0y0.pem", "region-x1y0.pem"]
    assert sum(h.get("taken_over", 0) for k, h in summary["health"].items() if k.startswith("mtt-centre/")) > 0


@pytest.mark.parametrize("extra", [{"maneuver": "vdie"}, {"process_noise": "imm"}])
def test_a_hand_over_crosses_the_wire_exactly(tmp_path: Path, extra: dict[str, str]) -> None:
    """A central track's record (maneuver detector banks with their minus infinities, or the two
    motion modes) encoded, decoded and placed in another centre is the track it was, to the bit; a
    record that does not fit the receiving centre is refused."""
    import dataclasses

    import numpy as np

    from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
    from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
    from fedtrack.fusion_center.mtt.shards import handover_from_wire, handover_to_wire
    from fedtrack.local_filters.mtt.scan import parse_line
    from fedtrack.wire import decode

    _, cfg, _ = scenario(tmp_path)
    cfg = dataclasses.replace(cfg, **extra)
    engine = TrackToTrackEngine(cfg, 4, feedback=True)
    lines = (tmp_path / "scenario" / "measurements.jsonl").read_text().splitlines()[:60]
    for line in lines:
        engine.ingest(parse_line(json.loads(line), "test"))
    a = engine.centre
    assert isinstance(a, TrackToTrackCentre)
    cid = max(a.tracks, key=lambda c: len(a.members.get(c, ())))
    record = a.hand_over(cid)
    back = handover_from_wire(decode(encode(handover_to_wire(record, "x0y0", 7)), HandOver), a)
    assert back.members == record.members and back.strikes == record.strikes
    for x, y in zip(record.entries, back.entries):
        assert x.dtype == y.dtype and np.array_equal(x, y)

    def per_sensor(r: Any) -> dict[str, tuple[int, int]]:  # the sensors with support or misses (others: none)
        return {s: (int(a), int(b)) for s, a, b in zip(r.sensors, r.support, r.streak) if a or b}
    assert per_sensor(back) == per_sensor(record) and per_sensor(back)
    assert np.array_equal(back.window, record.window)
    other = TrackToTrackCentre(cfg if "maneuver" not in extra else dataclasses.replace(cfg, maneuver="off"), 4, True)
    if "maneuver" in extra:
        with pytest.raises(ValueError, match="do not fit"):
            handover_from_wire(handover_to_wire(record, "x0y0", 7), other)


def test_one_region_live_equals_the_unsharded_replay(tmp_path: Path) -> None:
    """With one region, the live region centre, its tracker routing and the merge give the
    unsharded centre's pictures: ``replay`` without regions of the recorded scans (their region
    tags dropped, and the region centre's start line) equals them, ids included."""
    msgs, cfg, config = scenario(tmp_path)
    config.write_text(CONFIG.replace("cell = [5000.0, 10000.0], nx = 2", "cell = [10000.0, 10000.0], nx = 1"))
    centres, local, merger, recorder, _ = run_on_bus(tmp_path, "mtt-federated", config, cfg, msgs)
    out = tmp_path / "out"
    plain = tmp_path / "plain.jsonl"
    lines = [json.loads(x) for x in (out / "measurements.jsonl").read_text().splitlines()]
    plain.write_text("".join(json.dumps({k: v for k, v in x.items() if k not in ("region", "seq")}) + "\n"
                             for x in lines if "began" not in x))
    replayed = tmp_path / "replayed.jsonl"
    replay_mtt("mtt-federated", plain, config, replayed)
    live = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
    assert len(live) >= 25
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])


def test_copies_of_tracks_handed_over_expire_even_when_they_share_a_local_track(tmp_path: Path) -> None:
    """Two tracks handed over shortly one after the other with a local track moved between them
    (it is a member of the later copy only): both copies are shown, for ``unsupported_s``, then expire, without
    error (a region centre once failed on every report after this)."""
    from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
    from fedtrack.fusion_center.mtt.regional import RegionEngine
    from fedtrack.local_filters.mtt.scan import parse_line

    _, cfg, config = scenario(tmp_path)
    engine = TrackToTrackEngine(cfg, 4, feedback=True)
    for line in (tmp_path / "scenario" / "measurements.jsonl").read_text().splitlines()[:60]:
        engine.ingest(parse_line(json.loads(line), "test"))
    c = engine.centre
    a, b = sorted(c.tracks, key=lambda cid: -len(c.members.get(cid, ())))[:2]
    first = c.hand_over(a)
    second = c.hand_over(b)
    second = second._replace(members=second.members + first.members[:1], strikes=second.strikes + (0,))
    region = RegionEngine(cfg, 4, feedback=True, regions=load_regions(config), index=0)
    region.high = 10.0
    region.remember(first)
    region.remember(second)
    shown = region.region_picture(10.0).flying
    assert shown is not None and sorted(shown.ids) == sorted([a, b])
    assert cfg.unsupported_s > 2 * cfg.period
    # a record taken late by its new owner is still covered two periods on (before flake60: no copy then)
    assert region.region_picture(10.0 + 2 * cfg.period).flying is not None
    assert region.region_picture(10.0 + cfg.unsupported_s).flying is None and not region.handed_t


def test_a_region_recording_needs_its_regions(tmp_path: Path) -> None:
    """A region run's recording replayed without ``--regions config`` is a one-line error naming it."""
    from fedtrack.config import ConfigError

    (tmp_path / "m.jsonl").write_text('{"t": 1.0, "region": "x0y0", "handover": 0, "from": "x1y0"}\n')
    (tmp_path / "c.toml").write_text(CONFIG)
    for regions in (None, "2x2"):
        with pytest.raises(ConfigError, match="region run's recording"):
            replay_mtt("mtt-federated", tmp_path / "m.jsonl", tmp_path / "c.toml", tmp_path / "p.jsonl", regions=regions)
    assert not (tmp_path / "p.jsonl").exists()


def test_without_regions_the_messages_carry_no_region_field() -> None:
    """The region fields are left out while empty: an unsharded deployment's reports, resets and
    pictures are the bytes they were before regions existed (and decode as before)."""
    import numpy as np

    from fedtrack.wire import TrackPicture, TrackReport, TrackResets, decode

    report = TrackReport(sensor="s1", seq=1, t=1.0, ids=(0,), x=np.zeros((1, 4)), P=np.eye(4), confirmed=(True,),
                         detected=(False,), obs_H=np.zeros((0, 4)), obs_R=np.zeros((0, 2)), obs_z=np.zeros((0, 2)),
                         started=(), retired=(), stamp_ns=1)
    resets = TrackResets(sensor="s1", seq=1, t=1.0, q_scale=2.0, ids=(0,), x=np.zeros((1, 4)), P=np.eye(4))
    picture = TrackPicture(seq=0, t=1.0, ids=(0,), x=np.zeros((1, 4)), P=np.eye(4), confirmed=(True,),
                           sensors=(("s1",),), fused_sensors=("s1",), fused_seqs=(1,), stamp_ns=1)
    for msg in (report, resets, picture):
        payload = encode(msg)
        assert not any(name in payload for name in (b"elsewhere", b"held", b"moved", b"region", b"handovers",
                                                     b"in_flight"))
        assert encode(decode(payload, type(msg))) == payload


def test_the_merged_picture_carries_the_tracks_on_the_earth(tmp_path: Path) -> None:
    """With ``[frame]``, ``serve picture``'s merged tracks carry ``lla`` as a centre's pictures do, so
    the recorder's ``tracks.jsonl`` has the ``lat``, ``lon``, ``alt`` that ``replay --regions config``
    writes (before 2026-11-27 a live region run recorded none: its 7,369 track rows on 120 s of the
    traffic package's quickstart sample had no ``lat``)."""
    import numpy as np

    from fedtrack.fusion_center.mtt.picture_merge import service_from_args
    from fedtrack.geodetic import Frame, geodetic_of_states
    from fedtrack.wire import TrackPicture

    config = tmp_path / "c.toml"
    config.write_text(CONFIG + "\n[frame]\norigin = [48.878, 2.423, 35.0]\n")
    merger = service_from_args(["--config", str(config), "--dim", "6", "--id", "picture", "--deployment", "hostile"])
    recorder = Recorder(tmp_path / "rec.db", tmp_path / "out", service_id="rec", options=OPTIONS, deployment="hostile")
    recorder.on_start()
    bus = Bus([merger, recorder])
    x = np.array([[-2500.0, 100.0, 300.0, 0.0, 3000.0, 0.0], [2500.0, -100.0, -300.0, 0.0, 9000.0, 0.0]])
    for k, rid in enumerate(("x0y0", "x1y0")):
        bus.put(Keys("hostile").region_picture(rid), encode(TrackPicture(
            seq=0, t=1.0, ids=(k,), x=x[k:k + 1], P=np.eye(6), confirmed=(True,), sensors=(("r1",),),
            fused_sensors=("r1",), fused_seqs=(0,), stamp_ns=1)))
    merger.on_stop()
    bus.drain()
    recorder.on_stop()
    merged = [p for key, p in bus.published if key == Keys("hostile").mtt_picture() and not p.closing]
    assert len(merged) == 1 and merged[0].lla is not None
    assert np.array_equal(merged[0].lla, geodetic_of_states(Frame(48.878, 2.423, 35.0), x))
    rows = json.loads((tmp_path / "out" / "tracks.jsonl").read_text().splitlines()[0])["tracks"]
    written = np.array([(r["lat"], r["lon"], r["alt"]) for r in rows])  # 1e-9 deg, 0.1 mm (docs/geodetic.md)
    assert np.allclose(written[:, :2], merged[0].lla[:, :2], rtol=0, atol=1e-9)
    assert np.allclose(written[:, 2], merged[0].lla[:, 2], rtol=0, atol=1e-4)
