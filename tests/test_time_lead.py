"""Scans stamped far ahead of the data (fedtrack/services/lead.py): one forged or broken time must
not stop the tracking, in the multi-target replay and services and in the single-target services;
data resuming after a gap must still be taken."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_fuzz_handlers import MEASUREMENTS, SENSORS
from test_fuzz_trackers import sonar_stream
from test_hostile_messages import (
    KEYS,
    MTT_SENSORS,
    OPTIONS,
    Bus,
    fused,
    mtt_lines,
    mtt_services,
    paper_run,
    pictures,
    same_tracks,
)
from test_mtt_regions_live import scenario as region_scenario
from test_mtt_regions_live import services as region_services

from fedtrack.fusion_center.mtt.engines import Engine, PictureClock, make_engine
from fedtrack.fusion_center.mtt.replay import pictures as replay_pictures
from fedtrack.fusion_center.mtt.replay import silent
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.keys import Keys
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import SensorScan, parse_line
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.service import RadarLocalFilterService
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate
from fedtrack.sensors.radar import RadarConfig, radar_scans
from fedtrack.services.lead import HELD_BYTES, HELD_MAX, LEAD_INTERVALS, LeadGuard, NumberedLeadGuard, SoleStart
from fedtrack.wire import FusedTrack, LocalEstimate, Measurement, TrackPicture, encode

CFG = MttConfig(sensors=("s1", "s2", "s3"), max_lag=3.0, clutter_density=3.0 / 5000.0**2)
ALGORITHMS = [("mtt-centralized", None), ("mtt-federated", None), ("mtt-decentralized", None), ("mtt-local", "s1")]


@pytest.fixture(scope="module")
def scans(tmp_path_factory: pytest.TempPathFactory) -> list[SensorScan]:
    out = tmp_path_factory.mktemp("lead")
    simulate(Scenario(targets=6, duration=25.0, clutter=3.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 5, out)
    return [parse_line(json.loads(x), "test") for x in (out / "measurements.jsonl").read_text().splitlines()]


def run(algorithm: str, sensor: str | None, scans: list[SensorScan]) -> tuple[list[tuple], Engine]:
    """The replay's pictures (its lead guard in front of the engine) and the engine."""
    engine = make_engine(algorithm, CFG, 4, sensor)
    return [(T, p.ids, p.x, p.P) for T, p in replay_pictures(engine, scans, CFG.period, CFG.picture_delay)], engine


def unguarded(algorithm: str, sensor: str | None, scans: list[SensorScan]) -> tuple[list[tuple], Engine]:
    """The same without the guard: every scan straight to the clock and the engine (a sensor
    silent beyond its bound at a picture's time left, as in the replay: ``replay.silent`` on the
    times of the scans taken)."""
    engine, clock, out = make_engine(algorithm, CFG, 4, sensor), PictureClock(CFG.period, CFG.picture_delay), []
    times: LeadGuard[None] = LeadGuard(CFG.max_lag)  # only its times: nothing is held
    heard: dict[str, float] = {}
    for scan in scans:
        for T in clock.due(scan.t):
            for gone in silent(times, heard, T, CFG.central_timeout):
                times.leave(gone)
                engine.leave(gone, at_once=True)
            out.append((T, *_pic(engine, T)))
        engine.ingest(scan)
        times.took(scan.sensor, scan.t)
        heard[scan.sensor] = times.newest
    return out + [(T, *_pic(engine, T)) for T in clock.final()], engine


def _pic(engine: Engine, T: float) -> tuple:
    p = engine.picture(T)
    return p.ids, p.x, p.P


def assert_same(a: list[tuple], b: list[tuple]) -> None:
    assert [p[0] for p in a] == [p[0] for p in b]
    for (_, ids_a, x_a, P_a), (_, ids_b, x_b, P_b) in zip(a, b):
        assert ids_a == ids_b
        np.testing.assert_allclose(x_a, x_b, rtol=0, atol=1e-9)
        np.testing.assert_allclose(P_a, P_b, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("algorithm", "sensor"), ALGORITHMS)
def test_scans_stamped_far_ahead_change_no_picture(scans: list[SensorScan], algorithm: str, sensor: str | None) -> None:
    """A copy of a genuine scan of s1 re-stamped 1,000 s ahead, and one of s2 50 s ahead, mid-run:
    every picture equals the clean run's, both counted; without the guard the forged scan makes
    the rest of the data late (what the guard prevents)."""
    k = len(scans) // 3
    s1 = next(s for s in scans[:k][::-1] if s.sensor == "s1")
    s2 = next(s for s in scans[:2 * k][::-1] if s.sensor == "s2")
    forged = scans[:k] + [s1._replace(t=s1.t + 1000.0)] + scans[k:2 * k] + [s2._replace(t=s2.t + 50.0)] + scans[2 * k:]
    clean, clean_engine = run(algorithm, sensor, scans)
    got, engine = run(algorithm, sensor, forged)
    assert_same(got, clean)
    assert clean_engine.counters()["lead"] == 0 and engine.counters()["lead"] == 2
    assert engine.counters()["late"] == clean_engine.counters()["late"]
    steered, steered_engine = unguarded(algorithm, sensor, forged)
    assert steered_engine.counters()["late"] > clean_engine.counters()["late"] + 10 and len(steered) > len(clean) + 900


@pytest.mark.parametrize(("algorithm", "sensor"), ALGORITHMS)
def test_data_resuming_after_a_gap_is_taken(scans: list[SensorScan], algorithm: str, sensor: str | None) -> None:
    """Every sensor silent for 600 s (the data after t = 12 s moved on by 600 s): the guard holds the
    first scan after the gap until a witness and is otherwise transparent, so the pictures equal
    those of the engine fed without it, to 1e-9, and nothing is dropped."""
    gap = [s._replace(t=s.t + 600.0) if s.t > 12.0 else s for s in scans]
    got, engine = run(algorithm, sensor, gap)
    assert engine.counters()["lead"] == 0
    assert_same(got, unguarded(algorithm, sensor, gap)[0])
    assert max(p[0] for p in got) > 600.0 and any(p[1] for p in got if p[0] > 620.0)  # tracked after the gap


@pytest.mark.parametrize(("algorithm", "sensor"), ALGORITHMS[:3])
def test_a_sensor_whose_clock_jumped_is_left_out(scans: list[SensorScan], algorithm: str, sensor: str | None) -> None:
    """s1's clock jumps 1,000 s ahead at t = 10 s and stays there: its scans from then on are held
    and dropped (no other sensor witnesses them), the others tracked as if s1 had stopped there."""
    broken = [s._replace(t=s.t + 1000.0) if s.sensor == "s1" and s.t > 10.0 else s for s in scans]
    stopped = [s for s in scans if not (s.sensor == "s1" and s.t > 10.0)]
    got, engine = run(algorithm, sensor, broken)
    assert_same(got, run(algorithm, sensor, stopped)[0])
    assert engine.counters()["lead"] == len(scans) - len(stopped) > 5


def test_a_lone_sensor_witnesses_itself_only_with_a_later_scan() -> None:
    """One sensor: its scan after a gap waits for its next (a repeat of it is no witness); with a
    second live sensor, only that sensor's scan witnesses it, and once that sensor left, the
    first sensor's own next scan does."""
    guard: LeadGuard[str] = LeadGuard(max_lag=3.0)
    for k in range(5):
        assert guard.admit("s1", float(k), f"a{k}") == [f"a{k}"]
        guard.took("s1", float(k))
    assert guard.bound("s1") == max(3.0, LEAD_INTERVALS * 1.0)
    assert guard.admit("s1", 100.0, "b") == [] and guard.admit("s1", 100.0, "b again") == []
    assert guard.admit("s1", 101.0, "c") == ["b", "b again", "c"]
    for t, item in ((100.0, "b"), (100.0, "b again"), (101.0, "c")):
        guard.took("s1", t)
    guard.took("s2", 101.5)
    assert guard.admit("s1", 300.0, "d") == [] and guard.admit("s1", 301.0, "e") == []
    assert guard.admit("s2", 300.5, "f") == ["d", "e", "f"]
    for t, s in ((300.0, "s1"), (301.0, "s1"), (300.5, "s2")):
        guard.took(s, t)
    assert guard.admit("s1", 500.0, "g") == [] and guard.admit("s2", 302.0, "h") == ["h"]  # contradicted
    assert guard.dropped == 1
    guard.took("s2", 302.0)
    guard.leave("s2")
    assert guard.admit("s1", 700.0, "i") == [] and guard.admit("s1", 701.0, "j") == ["i", "j"]


def admitted(guard: LeadGuard[tuple[str, float]], scans: list[tuple[str, float]],
             arrival: bool = False) -> list[tuple[str, float]]:
    """The ``(sensor, t)`` scans in time order (or as listed: ``arrival``) through ``guard``: those it took, in
    the order it took them."""
    taken = []
    for sensor, t in scans if arrival else sorted(scans, key=lambda item: item[1]):
        for got in guard.admit(sensor, t, (sensor, t)):
            guard.took(*got)
            taken.append(got)
    return taken


def test_a_burst_after_a_pause_longer_than_the_bound_is_taken_when_the_data_resumes() -> None:
    """s2 sends bursts of 4 scans 0.05 s apart every 4 s (its usual interval 0.05 s, so its bound is
    ``max_lag``, 3 s); s1 (0.7 s) stops at 89.6 s and resumes at 100.2 s. s2's burst at 96.5 s leads
    (3.85 s after the newest time) and is held; s1's scan at 100.2 s leads too and witnesses it with
    s2's next burst. The held burst lies before the witness, behind the resumed data: it is taken.
    It was dropped as not near the witness (4 scans lost; every track left the pictures of 98-100 s,
    untuned5)."""
    guard: LeadGuard[tuple[str, float]] = LeadGuard(max_lag=3.0)
    s1 = [("s1", round(0.7 * k, 2)) for k in range(1, 129)] + [("s1", round(100.2 + 0.7 * k, 2)) for k in range(20)]
    s2 = [("s2", round(0.5 + 4.0 * k + 0.05 * j, 2)) for k in range(26) for j in range(4)]
    taken = [t for _, t in admitted(guard, s1 + s2)]
    assert guard.usual["s2"] == pytest.approx(0.05) and guard.bound("s2") == 3.0
    assert guard.dropped == 0 and len(taken) == len(s1) + len(s2)
    assert taken[taken.index(96.5):taken.index(100.5) + 1] == [96.5, 96.55, 96.6, 96.65, 100.2, 100.5]


def test_a_burst_led_by_a_slow_sensors_bound_is_taken_when_that_sensor_passes_it() -> None:
    """s2 scans every 12 s (bound 48 s), s3 sends bursts of 4 scans 0.05 s apart every 8 s (bound
    ``max_lag``, 3 s): a burst more than 3 s after the newest time is held, and s2's next scan, which
    does not lead, comes after it: the burst is behind the data and is taken before it. Each such
    burst was dropped (32 of these 60 scans of s3; untuned5)."""
    guard: LeadGuard[tuple[str, float]] = LeadGuard(max_lag=3.0)
    s2 = [("s2", 0.1 + 12.0 * k) for k in range(10)]
    s3 = [("s3", round(0.5 + 8.0 * k + 0.05 * j, 2)) for k in range(15) for j in range(4)]
    taken = admitted(guard, s2 + s3)
    guard.end()
    held_last = [item for item in s3 if item[1] > s2[-1][1] + 3.0]  # after s2's last scan: never passed
    assert guard.bound("s3") == 3.0 and guard.dropped == len(held_last) == 4
    assert sorted(taken, key=lambda item: item[1]) == taken and len(taken) == len(s2) + len(s3) - 4


def test_held_scans_are_bounded() -> None:
    """A flood of leading scans from one of two live sensors: at most HELD_MAX held, every one of
    them counted once dropped."""
    guard: LeadGuard[int] = LeadGuard(max_lag=3.0)
    for k in range(10):
        for s in ("s1", "s2"):
            assert guard.admit(s, float(k), k) == [k]
            guard.took(s, float(k))
    for k in range(1000):
        assert guard.admit("s1", 1e4 + k, k) == []
        assert len(guard.held) <= HELD_MAX
    assert guard.admit("s2", 10.0, -1) == [-1] and guard.dropped == 1000 and not guard.held
    for k in range(10):  # and at most HELD_BYTES: 10 leading reports of a third of it each
        guard.admit("s1", 2e4 + k, k, HELD_BYTES // 3)
        assert len(guard.held) <= 3
    assert guard.dropped == 1007


def test_live_services_drop_a_forged_scan_and_report_far_ahead(tmp_path: Path) -> None:
    """The live services (in-process bus): a scan of s1 and a report of s2 re-stamped 1,000 s ahead
    (numbers of their own, so no conflict) are each counted ``rejected_time_lead`` by the service
    they reached, and every picture equals the clean run's."""
    msgs = mtt_lines(tmp_path)
    at = len(msgs) // 2
    runs = []
    for name, forge in (("clean", False), ("forged", True)):
        services = mtt_services(tmp_path / name)
        bus = Bus(list(services.values()))
        for i, m in enumerate(msgs):
            if forge and i == at:
                s1 = next(x for x in msgs[:at][::-1] if x.sensor == "s1")
                bus.put(KEYS.sensor_meas("s1"), encode(replace(s1, seq=s1.seq + 500, t=s1.t + 1000.0)))
                report = [r for key, r in bus.published if key == KEYS.mtt_report("s2")][-1]
                bus.put(KEYS.mtt_report("s2"), encode(replace(report, seq=report.seq + 500, t=report.t + 1000.0)))
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
        runs.append((bus, services))
    (clean, clean_services), (forged, services) = runs
    assert services["s1"].counters.get("rejected_time_lead") == 1
    assert services["centre"].counters.get("rejected_time_lead") == 1
    assert all(svc.counters.get("rejected", 0) == 0 for svc in clean_services.values())
    assert pictures(forged) == pictures(clean) and len(pictures(clean)) > 5


def test_a_scan_far_ahead_before_any_interval_is_known_waits_for_another_sensor() -> None:
    """The guard on the data's first interval: three sensors have one scan each, none an interval yet,
    and a second scan of one of them comes 10^9 s ahead. It led by no bound (none without an interval)
    and was corroborated by any other sensor (their reach, ``max_lag`` + an unknown usual interval, was
    infinite). It now waits for another sensor's data within ``max_lag`` of it, and the others' second
    scans, and its sensor's genuine one, are taken as they come."""
    guard: LeadGuard[str] = LeadGuard(max_lag=3.0, corroborate=True)
    for s in ("a", "b", "c"):
        assert guard.admit(s, 0.0, f"{s}0") == [f"{s}0"]
        guard.took(s, 0.0)
    assert guard.admit("a", 1e9, "forged") == [] and guard.newest == 0.0
    for s, t in (("b", 0.7), ("a", 1.0), ("c", 1.3)):
        assert guard.admit(s, t, f"{s}{t}") == [f"{s}{t}"]
        guard.took(s, t)
    assert guard.end() == 1 and guard.newest == 1.3


def test_the_centre_drops_a_second_scan_far_ahead_at_its_start(tmp_path: Path) -> None:
    """The live multi-target centre (in-process bus, ``mtt-centralized``): once every sensor has sent its
    first scan, a second scan of s1 stamped 1,000 s ahead (a sensor's own key, which the access control
    admits) made the centre publish a picture for every period up to it, 1,000 s of pictures (10^9 s:
    the centre busy for good), and every genuine scan after it was late (no picture after t = 1,000).
    It now waits for a corroboration that never comes (``rejected_time_lead`` at the stop) and every
    picture equals the clean run's."""
    msgs = mtt_lines(tmp_path)
    at = next(i for i, m in enumerate(msgs) if {x.sensor for x in msgs[:i + 1]} == {"s1", "s2", "s3"})
    runs = []
    for name, forge in (("clean", False), ("forged", True)):
        services = mtt_services(tmp_path / name, "mtt-centralized")
        bus = Bus(list(services.values()))
        for i, m in enumerate(msgs):
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
            if forge and i == at:
                s1 = next(x for x in msgs[:at + 1][::-1] if x.sensor == "s1")
                bus.put(KEYS.sensor_meas("s1"), encode(replace(s1, seq=s1.seq + 500, t=s1.t + 1000.0)))
        services["centre"].on_stop()
        runs.append((pictures(bus), services["centre"]))
    (clean, _), (forged, centre) = runs
    assert forged == clean and len(clean) > 5
    assert centre.counters.get("rejected_time_lead") == 1


def clean_run(tmp_path: Path, algorithm: str) -> tuple[list[Measurement], dict[str, Any], Bus]:
    """``mtt_lines``' messages, and the services and bus of their clean run at ``algorithm`` (its centre stopped)."""
    msgs = mtt_lines(tmp_path)
    services = mtt_services(tmp_path / "clean", algorithm)
    bus = Bus(list(services.values()))
    for m in msgs:
        bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    services["centre"].on_stop()
    return msgs, services, bus


def first_forged(tmp_path: Path, algorithm: str, dt: float, forged: int = 1, opened: bool = False
                 ) -> tuple[list[tuple], list[tuple], MttCentreService]:
    """The clean run's pictures and those of a run whose first message of all at the centre is s1's first one (a
    scan at ``mtt-centralized``, the clean run's first report else) re-stamped ``dt`` s off and
    numbered 500 on (``forged`` 2: and a second such message half a second after it, numbered 501; ``opened``: the
    start's wait runs out before any honest message comes); and the attacked run's centre, stopped."""
    msgs, clean_services, clean = clean_run(tmp_path, algorithm)
    services = mtt_services(tmp_path / "forged", algorithm)
    forged_bus = Bus(list(services.values()))
    centre = services["centre"]
    assert isinstance(centre, MttCentreService)
    for k in range(forged):
        if algorithm == "mtt-centralized":
            s1 = next(m for m in msgs if m.sensor == "s1")
            forged_bus.put(KEYS.sensor_meas("s1"), encode(replace(s1, seq=s1.seq + 500 + k, t=s1.t + dt + 0.5 * k)))
        else:
            first = next(r for key, r in clean.published if key == KEYS.mtt_report("s1"))
            forged_bus.put(KEYS.mtt_report("s1"), encode(replace(first, seq=first.seq + 500 + k,
                                                                  t=first.t + dt + 0.5 * k)))
    if opened and centre.start_held_at is not None:  # start_wait_s later, nothing else come
        centre.start_held_at -= centre.start_wait_s
        centre.on_tick()
        forged_bus.drain()
    for m in msgs:
        forged_bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    centre.on_stop()
    return pictures(clean), pictures(forged_bus), centre


@pytest.mark.parametrize("algorithm", ["mtt-centralized", "mtt-federated", "mtt-decentralized"])
@pytest.mark.parametrize("dt", [1e9, -1e12])
def test_the_first_message_of_all_far_off_sets_no_start(tmp_path: Path, algorithm: str, dt: float) -> None:
    """The first message of all at the live centre, s1's, stamped 10^9 s ahead or 10^12 s behind (redteam60's
    table): taken as it came, it froze the centre (10^9: 1 picture of 12, every honest scan or report ``late``;
    -10^12: 3,612 pictures, 3,600 before the data). It now waits until two agree within max_time_jump_s (two
    other sensors' first messages do) and is dropped, counted; every picture is the clean run's."""
    clean, forged, centre = first_forged(tmp_path, algorithm, dt)
    assert forged == clean and len(clean) > 5
    assert centre.counters.get("rejected_time_lead" if dt > 0 else "rejected_time_behind") == 1
    assert centre.counters.get("start_unwitnessed", 0) == 0


@pytest.mark.parametrize("algorithm", ["mtt-centralized", "mtt-federated", "mtt-decentralized"])
@pytest.mark.parametrize(("dt", "forged", "opened"), [(1e9, 2, False), (-1e12, 2, False), (1e9, 1, True),
                                                      (-1e12, 1, True)])
def test_a_start_of_one_sensor_is_abandoned_when_two_others_agree_against_it(
        tmp_path: Path, algorithm: str, dt: float, forged: int, opened: bool) -> None:
    """The attacks the start rule left open (redteam63): two forged first messages of s1 that agree with each other
    (10^9 s ahead or 10^12 s behind) set the start, and so did one taken unwitnessed when ``start_wait_s`` ran out
    before any honest message came: every honest message was then late (10^9; 0 pictures of 12) or the centre made
    up to 3,600 pictures before the data (-10^12). Now the centre abandons such a start, every message taken of one
    sensor, when two other sensors' messages agree against it (``start_abandoned``): every picture is the clean
    run's."""
    clean, attacked, centre = first_forged(tmp_path, algorithm, dt, forged, opened)
    assert attacked == clean and len(clean) > 5
    assert centre.counters.get("start_abandoned") == 1
    assert centre.counters.get("start_unwitnessed", 0) == (1 if opened else 0)


@pytest.mark.parametrize("algorithm", ["mtt-centralized", "mtt-federated", "mtt-decentralized"])
@pytest.mark.parametrize("dt", [1e9, -1e12])
def test_what_an_abandoned_start_published_keeps_its_numbers(tmp_path: Path, algorithm: str, dt: float) -> None:
    """s1's first 6 s of messages (scans, or its tracker's reports), re-stamped ``dt`` s off and numbered 500 on,
    sent before any honest one: the centre publishes 5 pictures from that start, then abandons it (two other
    sensors agree against it) with its state put back as before its first message. Its ids came again: of the 22
    ids those 5 pictures showed, 18 (centralized) or 22 were shown again by the honest pictures, other tracks; and at
    -10^12 s its pictures took the numbers 0-4, so the recorder refused 4 honest pictures as ``conflict``
    (redteam65). Now no id nor number a published picture had is given again: every honest picture is recorded, and
    each is the clean run's but for its track ids (one new id for each of the clean run's) and, at -10^12 s, its
    number (the forged pictures' grid)."""
    msgs, clean_services, clean = clean_run(tmp_path, algorithm)
    services = mtt_services(tmp_path / "forged", algorithm)
    bus = Bus(list(services.values()))
    if algorithm == "mtt-centralized":
        for m in (m for m in msgs if m.sensor == "s1" and m.t <= 6.0):
            bus.put(KEYS.sensor_meas("s1"), encode(replace(m, seq=m.seq + 500, t=m.t + dt)))
    else:
        for r in (r for key, r in clean.published if key == KEYS.mtt_report("s1") and r.t <= 6.0):
            bus.put(KEYS.mtt_report("s1"), encode(replace(r, seq=r.seq + 500, t=r.t + dt)))
    forged = bus.of(TrackPicture)
    for m in msgs:
        bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    services["centre"].on_stop()
    honest, expected = bus.of(TrackPicture)[len(forged):], clean.of(TrackPicture)
    assert services["centre"].counters.get("start_abandoned") == 1 and len(forged) == 5
    shown = {i for p in forged for i in p.ids}
    assert len(shown) > 10 and not shown & {i for p in honest for i in p.ids}
    assert not {p.seq for p in forged} & {p.seq for p in honest}
    recorder = services["recorder"].counters
    assert recorder.get("conflict", 0) == 0
    assert recorder["pictures_recorded"] == len(forged) + clean_services["recorder"].counters["pictures_recorded"]
    renamed: dict[int, int] = {}
    assert len(honest) == len(expected) > 5
    for got, want in zip(honest, expected):
        assert (got.t, got.x.tobytes(), got.P.tobytes(), got.fused_sensors, got.fused_seqs) == \
            (want.t, want.x.tobytes(), want.P.tobytes(), want.fused_sensors, want.fused_seqs)
        assert got.seq - honest[0].seq == want.seq - expected[0].seq and (dt < 0 or got.seq == want.seq)
        for new, old in zip(got.ids, want.ids):
            assert renamed.setdefault(old, new) == new
    assert len(set(renamed.values())) == len(renamed)


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
@pytest.mark.parametrize("dt", [1e9, -1e12])
def test_a_region_centre_issues_no_id_its_abandoned_start_showed(tmp_path: Path, algorithm: str, dt: float) -> None:
    """Two region centres and ``serve picture`` on the in-process bus: s1's first 6 s of sub-reports to x0y0,
    re-stamped ``dt`` s off and numbered 500 on, sent first. x0y0 publishes 5 pictures from that start and abandons
    it; its engine put back, it showed the same 15 (federated) or 16 ids again, for other tracks (redteam65). Now
    none; its later pictures are at the clean run's times with as many tracks (their states differ in 18 of 31 at
    10^9 s, federated: not investigated, docs/multitarget.md)."""
    msgs, cfg, config = region_scenario(tmp_path)
    keys, runs = Keys("hostile"), []
    for name in ("clean", "forged"):
        centres, local, merger, recorder = region_services(tmp_path / name, algorithm, config, cfg,
                                                           {"options": OPTIONS, "deployment": "hostile"})
        recorder.on_start()
        bus = Bus([*centres, *local, merger, recorder])
        for key, r in runs[0][2] if runs else []:
            bus.put(key, encode(replace(r, seq=r.seq + 500, t=r.t + dt)))
        forged = [p for key, p in bus.published if key == keys.region_picture("x0y0")]
        for m in msgs:
            bus.put(keys.sensor_meas(m.sensor), encode(m))
        for svc in [*local, *centres, merger]:
            svc.on_stop()
            bus.drain()
        pictures = [p for key, p in bus.published if key == keys.region_picture("x0y0")][len(forged):]
        first = [(key, r) for key, r in bus.published if key == keys.region_report("x0y0", "s1") and r.t <= 6.0]
        runs.append((forged, pictures, first, centres[0]))
    (_, expected, _, _), (forged, honest, _, centre) = runs
    assert centre.counters.get("start_abandoned") == 1 and len(forged) == 5
    shown = {i for p in forged for i in p.ids}
    assert len(shown) > 10 and not shown & {i for p in honest for i in p.ids}
    assert len(honest) == len(expected) > 20
    assert [(p.t, len(p.ids)) for p in honest] == [(p.t, len(p.ids)) for p in expected]


def test_a_start_of_one_sensor_holds_what_contradicts_it_within_bounds_and_ends_when_witnessed() -> None:
    """:class:`SoleStart`: a flood of messages contradicting the start (one sensor's, so never two agreeing) is held
    within HELD_MAX messages and HELD_BYTES; two other sensors' that agree give the held ones near them; a message of
    another sensor taken ends the rule, so nothing after contradicts it."""
    sole: SoleStart[int] = SoleStart(3600.0)
    sole.took("s1", 1e9)
    for k in range(HELD_MAX + 10):
        assert sole.contradicts(float(k)) and sole.contradicted("s2", float(k), k, 100) == []
    assert len(sole.against) == HELD_MAX
    big = HELD_BYTES // 4 + 1
    for k in range(5):
        sole.contradicted("s2", 1.0, -k, big)
    assert sum(h[3] for h in sole.against) <= HELD_BYTES and len(sole.against) < 5
    assert sole.contradicted("s3", 2.0, 99, 0) == [h[2] for h in sole.against] + [99]
    witnessed: SoleStart[int] = SoleStart(3600.0)
    witnessed.took("s1", 0.0)
    witnessed.took("s2", 0.5)
    assert not witnessed.contradicts(1e9) and not witnessed.contradicts(-1e12)


@pytest.mark.parametrize("sensors", [MTT_SENSORS, ("s1",)])
def test_a_first_report_nothing_witnesses_is_answered_after_leave_after_s(tmp_path: Path,
                                                                         sensors: tuple[str, ...]) -> None:
    """A federated tracker waits for the answer to its first report, so with only s1 running of the three
    sensors allowed, nothing witnesses its first report: the centre holds it for ``start_wait_s`` of wall-clock
    time (here: its clock set that far on), then takes it as it came (``start_unwitnessed``) and answers.
    With one sensor allowed the start rule is off and the report is answered at once."""
    cfg = MttConfig(sensors=sensors, max_lag=3.0, clutter_density=2.0 / 5000.0**2)
    common = {"options": OPTIONS, "deployment": KEYS.deployment}
    centre = MttCentreService("mtt-federated", cfg, 4, service_id="centre", **common)
    tracker = MttLocalService("s1", True, cfg, 5.0, service_id="s1", **common)
    bus = Bus([centre, tracker])
    s1 = [m for m in mtt_lines(tmp_path) if m.sensor == "s1"]
    bus.put(KEYS.sensor_meas("s1"), encode(s1[0]))

    def answered() -> int:
        return sum(key == KEYS.mtt_resets("s1") for key, _ in bus.published)
    if len(sensors) == 1:
        assert answered() == 1 and centre.start_held_at is None
        return
    assert answered() == 0 and centre.start_held_at is not None
    centre.on_tick()  # within leave_after_s: still held
    assert answered() == 0
    assert centre.start_wait_s == 1.0  # min(leave_after_s 5 s, the trackers' --reset-timeout 2 s / 2)
    centre.start_held_at -= centre.start_wait_s
    centre.on_tick()
    bus.drain()
    assert answered() == 1 and centre.counters.get("start_unwitnessed") == 1 and centre.start_held_at is None
    for m in s1[1:4]:  # and it goes on as without the rule
        bus.put(KEYS.sensor_meas("s1"), encode(m))
    assert answered() == 4 and centre.counters.get("rejected", 0) == 0


def test_no_picture_is_made_more_than_max_time_jump_before_the_data() -> None:
    """The picture clock makes a picture a period from its first scan on: a first scan 1,000 s before the
    data made 1,000 pictures at the data's first scan (10^9 s: the centre busy for good). None is made more
    than ``max_gap`` (``[deployment] max_time_jump_s``) before the data now (counted ``skipped``), and the
    pictures are numbered from the first one made, as a centre that never saw that scan numbers them."""
    clock, honest = PictureClock(1.0, 0.0), PictureClock(1.0, 0.0)
    clock.max_gap = honest.max_gap = 10.0
    assert clock.due(-1000.0) == [] and clock.due(0.5) == [float(k) for k in range(-9, 1)]
    assert clock.skipped == 991 and clock.number(0.0) == 9
    assert honest.due(-9.0) == [] and honest.due(0.5) == [float(k) for k in range(-9, 1)] and honest.skipped == 0
    assert honest.number(0.0) == clock.number(0.0)


def test_a_first_scan_far_before_the_data_costs_the_centre_a_bounded_number_of_pictures(
        tmp_path: Path) -> None:
    """The live multi-target centre (in-process bus, ``mtt-centralized``): a sensor's first scan, the first
    the centre took, stamped 2,000 s before the others' (a scan needs no witness before any is taken) made
    2,012 pictures, one a period from it (10^9 s before: the centre busy for good). With ``max_time_jump_s =
    60`` it makes those of the last 60 s before the data and goes on with every honest scan."""
    msgs = mtt_lines(tmp_path)
    cfg = MttConfig(sensors=("s1", "s2", "s3"), max_lag=3.0, clutter_density=2.0 / 5000.0**2)
    centre = MttCentreService("mtt-centralized", cfg, 4, service_id="centre", options=OPTIONS,
                              deployment=KEYS.deployment)
    centre.clock.max_gap = 60.0  # --config's [deployment] max_time_jump_s (service_from_args)
    bus = Bus([centre])
    bus.put(KEYS.sensor_meas(msgs[0].sensor), encode(replace(msgs[0], seq=0, t=-2000.0)))
    for m in msgs:
        bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    made = [p.t for p in bus.of(TrackPicture)]
    assert made[0] >= -60.0 - cfg.period and made[-1] >= 10.0 and len(made) <= 60 / cfg.period + 14
    assert centre.counters["skipped_pictures"] > 1900 and centre.engine.counters()["late"] == 0


def test_honest_first_scans_are_taken_as_they_came() -> None:
    """The start rule holds the first scan until a second agrees with it, then gives both in arrival order
    (a late one first too): what the guard without it took, in the same order."""
    for order in ([("a", 0.0), ("b", 0.4), ("c", 0.2), ("a", 1.0)], [("a", 0.7), ("a", 0.0), ("b", 0.5)]):
        plain: LeadGuard[tuple[str, float]] = LeadGuard(max_lag=3.0, corroborate=True)
        started: LeadGuard[tuple[str, float]] = LeadGuard(max_lag=3.0, corroborate=True, start_gap=3600.0)
        assert admitted(started, order, True) == admitted(plain, order, True) == order
    guard: LeadGuard[tuple[str, float]] = LeadGuard(max_lag=3.0, start_gap=3600.0)
    assert admitted(guard, [("a", -1e12), ("a", 1e9), ("b", 0.3), ("a", 0.5)], True) == [("b", 0.3), ("a", 0.5)]
    assert guard.behind == guard.dropped == 1


def test_a_time_whose_picture_number_leaves_the_wire_is_refused(tmp_path: Path) -> None:
    """A first scan at t = 1e20 s (a valid time) became the multi-target centre's clock: its closing picture,
    number 1e20, did not fit msgpack's integers and the centre's stop failed (``OverflowError``); at 1e19 its
    pictures carried a number every receiver refuses. A time whose picture number would leave the wire's
    integers is refused (``time_jump``) before it is taken, and the run is the clean one."""
    msgs = mtt_lines(tmp_path)
    runs = []
    for forge in (False, True):
        services = mtt_services(tmp_path / str(forge), "mtt-centralized")
        bus = Bus(list(services.values()))
        if forge:
            bus.put(KEYS.sensor_meas("s1"), encode(replace(msgs[0], sensor="s1", seq=500, t=1e20)))
        for m in msgs:
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
        services["centre"].on_stop()
        bus.drain()
        runs.append((pictures(bus), services))
    (clean, _), (forged, services) = runs
    assert forged == clean and len(clean) > 5
    assert services["centre"].counters["rejected_time_jump"] == 1 and services["recorder"].counters["rejected"] == 0


def same_tracker_tracks(attacked: Bus, clean: Bus) -> None:
    """The IMM's and the HPDA tracker's tracks of the two runs are the same, and there are some."""
    for role in ("imm", "hpda"):
        got = [m for key, m in attacked.published if isinstance(m, FusedTrack) and f"/{role}/" in key]
        want = [m for key, m in clean.published if isinstance(m, FusedTrack) and f"/{role}/" in key]
        assert len(got) == len(want) > 0
        same_tracks(got, want)


def test_single_target_services_drop_a_scan_and_an_estimate_far_ahead(tmp_path: Path) -> None:
    """The paper pipeline and the single-sensor trackers (in-process bus): a measurement of sensor 1,
    a sonar scan and a local estimate of sensor 2, each a genuine one re-stamped 1,000 s ahead with a
    later scan number, mid-run: each is counted ``rejected_time_lead`` by the service it reached,
    and every fused track, IMM and HPDA track equals the clean run's (before the guard the first
    stopped the local filter and the fusion: 20 of 34 scans fused)."""
    sonar = sonar_stream()
    clean, clean_services = paper_run(tmp_path / "clean")

    def forge(bus: Bus, k: int) -> None:
        if k == 12:
            m = MEASUREMENTS[SENSORS[0]][k]
            bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, seq=m.seq + 3, t=m.t + 1000.0)))
            est = [e for e in bus.of(LocalEstimate) if e.sensor == SENSORS[1]][-1]
            bus.put(KEYS.local_estimate(est.sensor), encode(replace(est, seq=est.seq + 3, t=est.t + 1000.0)))
        if k == 4:
            s = sonar[k]
            bus.put(KEYS.sensor_meas(s.sensor), encode(replace(s, seq=s.seq + 2, t=s.t + 1000.0)))

    attacked, services = paper_run(tmp_path / "attacked", forge)
    for name in (f"local-{SENSORS[0]}", "centre", "hpda"):
        assert services[name].counters.get("rejected_time_lead") == 1, name
    assert services["imm"].counters.get("rejected_time_lead") == 1  # the IMM tracks sensor 1 too
    same_tracks(fused(attacked), fused(clean))
    same_tracker_tracks(attacked, clean)
    assert all(svc.counters.get("rejected", 0) == 0 for svc in clean_services.values())


def test_the_picture_merger_drops_a_region_picture_far_ahead(tmp_path: Path) -> None:
    """Two region centres and ``serve picture`` on the in-process bus: a copy of region x0y0's
    last picture re-stamped 1,000 s ahead, mid-run, is counted ``rejected_time_lead`` by the merger
    and every merged picture equals the clean run's (before: the region's later pictures queued
    behind it and its tracks left the merged picture)."""
    msgs, cfg, config = region_scenario(tmp_path)
    runs = []
    for name, forge in (("clean", False), ("forged", True)):
        centres, local, merger, recorder = region_services(tmp_path / name, "mtt-federated", config, cfg,
                                                           {"options": OPTIONS, "deployment": "hostile"})
        recorder.on_start()
        bus = Bus([*centres, *local, merger, recorder])
        keys = Keys("hostile")
        for i, m in enumerate(msgs):
            if forge and i == len(msgs) // 2:
                region = centres[0].region
                last = [p for key, p in bus.published if key == keys.region_picture(region)][-1]
                bus.put(keys.region_picture(region), encode(replace(last, seq=last.seq + 1000, t=last.t + 1000.0)))
            bus.put(keys.sensor_meas(m.sensor), encode(m))
        for svc in [*local, *centres, merger]:
            svc.on_stop()
            bus.drain()
        merged = [(p.t, p.ids, p.x.tobytes(), p.P.tobytes()) for key, p in bus.published if key == keys.mtt_picture()]
        runs.append((merged, merger))
    (clean, clean_merger), (forged, merger) = runs
    assert forged == clean and len(clean) > 20
    assert merger.counters.get("rejected_time_lead") == 1 and clean_merger.counters.get("rejected", 0) == 0


def test_single_target_services_drop_a_scan_and_an_estimate_numbered_far_ahead(tmp_path: Path) -> None:
    """The same with a plausible time (half a period on) but a scan number 1,000 ahead: each held
    for a witness and dropped (``rejected_time_lead``), every track as the clean run's (before: the
    local filter counted 999 scans missing, took the forged one and every genuine scan after it was
    late; the centre fused 12 of 34 scans)."""
    sonar = sonar_stream()
    clean, _ = paper_run(tmp_path / "clean")

    def forge(bus: Bus, k: int) -> None:
        if k == 12:
            m = MEASUREMENTS[SENSORS[0]][k - 1]
            bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, seq=m.seq + 1000, t=m.t + 0.5)))
            est = [e for e in bus.of(LocalEstimate) if e.sensor == SENSORS[1]][-1]
            bus.put(KEYS.local_estimate(est.sensor), encode(replace(est, seq=est.seq + 1000, t=est.t + 0.5)))
        if k == 4:
            s = sonar[k - 1]
            bus.put(KEYS.sensor_meas(s.sensor), encode(replace(s, seq=s.seq + 1000, t=s.t + 0.5)))

    attacked, services = paper_run(tmp_path / "attacked", forge)
    for name in (f"local-{SENSORS[0]}", "centre", "hpda", "imm"):
        assert services[name].counters.get("rejected_time_lead") == 1, name
    same_tracks(fused(attacked), fused(clean))
    same_tracker_tracks(attacked, clean)


def tracker_tracks(bus: Bus, role: str) -> list[FusedTrack]:
    return [m for key, m in bus.published if isinstance(m, FusedTrack) and f"/{role}/" in key]


def test_one_sensor_trackers_abandon_a_first_scan_numbered_far_ahead(tmp_path: Path) -> None:
    """The paper pipeline (in-process bus): the first message of all is a genuine measurement of sensor 1
    (and of the sonar) numbered 50 ahead. Taken as it came, every honest scan after it was ``late``: the local
    filter fused none of 34, the IMM tracked 1 (the forged one), the HPDA 0 of 4 (redteam60's table). Now the
    next two scans, each more than LEAD_INTERVALS behind it and agreeing with each other, abandon it
    (``start_abandoned``): every fused track and HPDA track is the clean run's, the IMM's after the forged one."""
    sonar = sonar_stream()
    clean, _ = paper_run(tmp_path / "clean")

    def forge(bus: Bus, k: int) -> None:
        if k == 0:
            for m in (MEASUREMENTS[SENSORS[0]][0], sonar[0]):
                bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, seq=m.seq + 50)))

    attacked, services = paper_run(tmp_path / "attacked", forge)
    same_tracks(fused(attacked), fused(clean))
    assert len(fused(attacked)) == 34
    for name in (f"local-{SENSORS[0]}", "imm", "hpda"):
        assert services[name].counters.get("start_abandoned") == 1, name
    same_tracks(tracker_tracks(attacked, "hpda"), tracker_tracks(clean, "hpda"))
    assert len(tracker_tracks(clean, "hpda")) > 0
    imm = tracker_tracks(attacked, "imm")
    assert imm[0].seq == 50 and len(imm) == 35
    same_tracks(imm[1:], tracker_tracks(clean, "imm"))


@pytest.mark.parametrize("algorithm", ["ekf", "ekf-ie"])
def test_the_radar_local_filter_abandons_a_first_scan_numbered_far_ahead(algorithm: str) -> None:
    """The radar local filter's first message of all a genuine scan numbered 50 ahead: taken as it came, every
    honest scan after it was ``late`` (0 estimates of 39; redteam63). Now the next two abandon it
    (``start_abandoned``, :class:`LoneStart` as at the 2-D local filter) and every estimate is the clean run's."""
    lines = list(radar_scans(RadarConfig(), seed=3))[:40]
    scans = [Measurement(sensor="r1", seq=k, t=line["t"], kind="radar", z=np.array(line["z"]), R=np.array(line["R"]),
                         sensor_position=np.array(line["sensor_position"]), stamp_ns=1) for k, line in enumerate(lines)]
    runs = []
    for forged in ([], [replace(scans[0], seq=50)]):
        svc = RadarLocalFilterService("r1", make_radar_filter(algorithm), service_id="r1", options=OPTIONS,
                                      deployment=KEYS.deployment)
        bus = Bus([svc])
        for m in [*forged, *scans]:
            bus.put(KEYS.sensor_meas("r1"), encode(m))
        runs.append((svc, [(e.seq, e.t, e.x.tobytes(), e.P.tobytes()) for e in bus.of(LocalEstimate)]))
    (_, clean), (svc, attacked) = runs
    assert len(clean) == len(scans) - 1 and attacked == clean
    assert svc.counters.get("start_abandoned") == 1 and svc.counters.get("rejected_late") == 1


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
@pytest.mark.parametrize("dt", [1e9, -1e12])
def test_mtt_local_abandons_a_first_scan_stamped_far_off(tmp_path: Path, algorithm: str, dt: float) -> None:
    """The first message of all at s1's ``mtt-local``, its first scan stamped 10^9 s ahead (or 10^12 s before):
    taken as it came, every honest scan of s1 was refused (``late``; ``time_jump``; federated, queued behind the
    forged report, whose answer never came) and s1 was missing from every picture. Now s1's next two scans abandon it
    (``start_abandoned``), its first honest scan is tracked when its second arrives, and every picture is that of
    the clean data delivered in that order (s1's first scan just before its second)."""
    msgs = mtt_lines(tmp_path)
    s1 = [i for i, m in enumerate(msgs) if m.sensor == "s1"]
    late_first = [m for i, m in enumerate(msgs) if i != s1[0]]
    late_first.insert(late_first.index(msgs[s1[1]]), msgs[s1[0]])
    runs = []
    for name, forged, order in (("clean", False, late_first), ("forged", True, msgs)):
        services = mtt_services(tmp_path / name, algorithm)
        bus = Bus(list(services.values()))
        if forged:
            bus.put(KEYS.sensor_meas("s1"), encode(replace(msgs[s1[0]], seq=500, t=msgs[s1[0]].t + dt)))
        for m in order:
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
        services["centre"].on_stop()
        runs.append((pictures(bus), services["s1"]))
    (clean, _), (attacked, local) = runs
    assert attacked == clean and len(clean) > 5
    assert all("s1" in p[5] for p in clean[:3])
    assert local.counters.get("start_abandoned") == 1 and local.counters.get("reports") == 1 + len(s1)


def admitted_numbers(guard: NumberedLeadGuard, seqs: list[int]) -> list[list[int]]:
    """Each scan number's arrival, as a one-sensor tracker handles it: ``[-1]`` when it abandons the start, ``[]``
    when it contradicts it (refused), else what the guard gives (taken)."""
    out: list[list[int]] = []
    for seq in seqs:
        m = replace(MEASUREMENTS[SENSORS[0]][0], seq=seq, t=float(seq))
        again = guard.contradicted(m)
        if again or guard.contradicts(m):
            out.append([-1] if again else [])
            continue
        given = guard.admit(m.sensor, m.t, m)
        for g in given:
            guard.took(g.sensor, g.t, g.seq)
        out.append([g.seq for g in given])
    return out


def test_an_honest_start_is_never_abandoned() -> None:
    """Honest scans reordered at the start (at most two periods late: three numbers behind) never abandon the first
    one, nor do scans after a second one was taken; a forged first 50 ahead is abandoned by the next two."""
    assert admitted_numbers(NumberedLeadGuard.one_sensor(), [3, 0, 1, 2, 4, 5]) == [[3], [0], [1], [2], [4], [5]]
    assert admitted_numbers(NumberedLeadGuard.one_sensor(), [20, 21, 0, 1, 2]) == [[20], [21], [0], [1], [2]]
    assert admitted_numbers(NumberedLeadGuard.one_sensor(), [50, 0, 1]) == [[50], [], [-1]]
    # 9 - 0 > gap: not 0 and 9
    assert admitted_numbers(NumberedLeadGuard.one_sensor(), [50, 0, 9, 10]) == [[50], [], [], [-1]]
