"""Hostile but well-formed messages at the single-target services (the fusion centre, the local
filters, the ``imm`` and ``hpda`` trackers), from a peer allowed to publish on the key: each is
rejected and counted, and the honest output is the clean run's (docs/wire.md, "Rejections")."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_fuzz_handlers import MEASUREMENTS, SCANS, SENSORS
from test_fuzz_trackers import SERVICES, position_stream, sonar_stream
from test_hostile_messages import (
    KEYS,
    OPTIONS,
    Bus,
    CleanRuns,
    assert_one_time_jump_changes_nothing,
    canonical,
    clean_runs,
    fused,
    paper_run,
    paper_services,
    same_tracks,
)

from fedtrack.fusion_center import service as centre_service
from fedtrack.local_filters import service as local_service
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.service import IMMService
from fedtrack.local_filters.pda.config import load_config
from fedtrack.local_filters.pda.service import PDAService
from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.service import RadarLocalFilterService
from fedtrack.sensors.radar import RadarConfig, radar_scans
from fedtrack.wire import MAX_DETECTIONS, Detection, FusedTrack, LocalEstimate, Measurement, encode, parts

__all__ = ["clean_runs"]  # the fixture, shared with test_hostile_messages

SONAR = [replace(m, seq=10 * m.seq) for m in sonar_stream()]  # room for scan numbers between


def hpda_run(forge: dict[int, list[Measurement]]) -> tuple[PDAService, list[Any]]:
    """The ``hpda`` service on :data:`SONAR`, ``forge[k]`` published (in parts) after scan ``k``."""
    svc = PDAService("sonar1", "hpda", load_config(None), service_id="hpda", options=OPTIONS,
                     deployment=KEYS.deployment)
    bus = Bus([svc])
    for k, scan in enumerate(SONAR):
        for msg in [scan, *forge.get(k, [])]:
            for part in parts(msg):
                bus.put(KEYS.sensor_meas("sonar1"), encode(part))
    return svc, [canonical(m) for m in bus.of(FusedTrack)]


def clutter(scan: Measurement, seq: int, n: int) -> Measurement:
    """Scan ``seq`` at ``scan``'s time: ``n`` strong detections spread over its region."""
    rng = np.random.default_rng(seq)
    z = np.array([d.z for d in scan.detections])
    lo, hi = z.min(axis=0), z.max(axis=0)
    return replace(scan, seq=seq, detections=tuple(Detection(z=rng.uniform(lo, hi), amplitude=10.0) for _ in range(n)))


def test_hpda_scans_repeating_the_last_ones_time_are_refused() -> None:
    """Scans with new numbers at the time of the last scan taken: the track manager pooled their
    detections for its births, without bound (60 scans of 2,048 detections: 122,880 held, pickled
    with every message, and the next scan asked 3.75 GiB for its pairing and failed, as did every
    scan after it while the pool lasted). Now rejected (``time_jump``), the tracks the clean run's."""
    svc_clean, clean = hpda_run({})
    forged = {k: [clutter(SONAR[k], SONAR[k].seq + j, 50) for j in range(1, 6)] for k in (2, 3)}
    svc, tracks = hpda_run(forged)
    assert svc.counters.get("rejected_time_jump") == 10 and svc.counters["rejected"] == 10
    assert tracks == clean and len(clean) > 0
    assert canonical(svc.manager) == canonical(svc_clean.manager)


def test_imm_measurements_repeating_the_last_ones_time_are_refused() -> None:
    """Each measurement from scan 10 on published again at once under the next number (the later
    ones numbered after it): ``imm`` updated its track with it twice, nothing counted (40 estimates
    of 25 scans; the last x variance 76.1 -> 40.8 m^2). Now rejected (``time_jump``), as at ``hpda``;
    the estimates the clean run's."""
    def run(forge: bool) -> tuple[Any, list[Any]]:
        svc = IMMService("p1", "ao-vsimm", load_imm_config(None), service_id="imm", options=OPTIONS,
                         deployment=KEYS.deployment)
        bus, extra = Bus([svc]), 0
        for m in position_stream():
            bus.put(KEYS.sensor_meas("p1"), encode(replace(m, seq=m.seq + extra)))
            if forge and m.seq >= 10:
                extra += 1
                bus.put(KEYS.sensor_meas("p1"), encode(replace(m, seq=m.seq + extra, stamp_ns=1)))
        return svc, [(t.t, t.x.tobytes(), t.P.tobytes()) for t in bus.of(FusedTrack)]

    _, clean = run(False)
    svc, tracks = run(True)
    assert svc.counters.get("rejected_time_jump") == 15 and svc.counters["rejected"] == 15
    assert tracks == clean and len(clean) == 25


def test_a_hpda_scan_of_more_detections_than_one_message_is_refused() -> None:
    """A sonar scan sent in parts with more than ``MAX_DETECTIONS`` (2,048) detections: the
    track manager's births pair every free detection with every one of the previous scan (8,192
    on 8,192: 11 s and 3.2 GB a scan; the wire's 131,072 would need 137 GB). Rejected
    (``too_large``); the tracks are the clean run's."""
    _, clean = hpda_run({})
    big = clutter(SONAR[3], SONAR[3].seq + 1, MAX_DETECTIONS + 1)
    assert len(parts(big)) == 2
    svc, tracks = hpda_run({3: [replace(big, t=SONAR[3].t + 1.0)]})
    assert svc.counters.get("rejected_too_large") == 1 and svc.counters["rejected"] == 1
    assert tracks == clean and len(clean) > 0


def test_an_estimate_of_the_next_scan_stamped_before_this_one_changes_no_track(tmp_path: Path,
                                                                                clean_runs: CleanRuns) -> None:
    """One local filter's estimate of scan k + 1 stamped between scans k - 1 and k, arriving before
    scan k's: it set scan k + 1's time, the genuine estimates of k + 1 were refused (``time_jump``,
    contested) and it was fused alone after scan k, its track 315 m off and half a second before
    scan k's (with no deadline passing, the centre waited for the refused sensors, and every later
    scan with it). Now rejected once scan k is fused, as it would have been had it come then; every
    track is the clean run's."""
    clean, _ = clean_runs.paper()
    k = 12

    def forge(bus: Bus, scan: int) -> None:
        if scan == k:
            genuine = next(e for e in clean.of(LocalEstimate) if e.seq == k + 1 and e.sensor == SENSORS[0])
            bus.put(KEYS.local_estimate(SENSORS[0]), encode(replace(genuine, t=MEASUREMENTS[SENSORS[0]][k].t - 0.5)))

    attacked, services = paper_run(tmp_path, forge)
    assert services["centre"].counters.get("rejected_conflict", 0) == 0  # scan k + 1's genuine estimates taken
    assert_one_time_jump_changes_nothing(services["centre"], attacked, clean)


def test_a_measurement_stamped_before_the_last_one_changes_no_track(tmp_path: Path, clean_runs: CleanRuns) -> None:
    """A sensor's scan k + 1 stamped half a second before scan k (a broken clock), arriving first:
    the local filter predicted back in time and published an estimate the centre refuses, the
    genuine scan k + 1 was then a conflict, and the centre fused scans without the sensor until
    the filter caught up (2-3 m off; in-process, with no deadline passing, it waited for good).
    Now the local filter rejects it (``time_jump``) as if it never came: every track is the clean
    run's."""
    clean, _ = clean_runs.paper()
    k = 13

    def forge(bus: Bus, scan: int) -> None:
        if scan == k:
            genuine = MEASUREMENTS[SENSORS[0]][k]
            bus.put(KEYS.sensor_meas(SENSORS[0]), encode(replace(genuine, t=MEASUREMENTS[SENSORS[0]][k - 1].t - 0.5)))

    attacked, services = paper_run(tmp_path, forge)
    assert_one_time_jump_changes_nothing(services[f"local-{SENSORS[0]}"], attacked, clean)
    assert services["centre"].counters.get("rejected", 0) == 0


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_a_tracker_starts_again_after_a_pause_beyond_max_time_jump(name: str) -> None:
    """A sensor that pauses (or whose clock is set forward) for more than ``max_time_jump_s``
    (3,600 s): the ``imm`` and ``hpda`` services rejected every scan after it (``time_jump``), for
    good (measured: 15 of the IMM's 15 later scans). The first scan after the pause is still
    rejected (a lone forged one changes nothing: ``test_fuzz_trackers``); the next one starts
    the tracker again (``restarted``), whose tracks are then those of a fresh service fed the scans
    from that one on, exactly."""
    make, stream = SERVICES[name]
    n = len(stream) // 2
    later = [replace(m, t=m.t + 4000.0) for m in stream[n:]]

    def tracks(svc: Any, scans: list[Measurement]) -> list[Any]:
        bus = Bus([svc])
        for m in scans:
            bus.put(svc.keys.sensor_meas(m.sensor), encode(m))
        return [canonical(replace(t, stamp_ns=0)) for t in bus.of(FusedTrack)]

    paused, fresh = make(), make()
    before = tracks(paused, stream[:n])  # (hpda: none confirmed yet)
    after, expected = tracks(paused, later), tracks(fresh, later[1:])
    assert paused.counters.get("rejected_time_jump") == 1 and paused.counters["rejected"] == 1
    assert paused.counters.get("restarted") == 1
    assert after == expected
    if name == "imm":  # (the inactive modes' rows of its state are left uninitialized: compared by the tracks)
        assert before and expected and paused.tracker.t == fresh.tracker.t
    else:  # no confirmed track within the scans: its whole state
        assert len(paused.manager.tracks) and canonical(paused.manager) == canonical(fresh.manager)


def test_the_federated_pipeline_starts_again_after_a_pause_beyond_max_time_jump(
        tmp_path: Path, clean_runs: CleanRuns, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both sensors pause for 4,000 s (beyond ``max_time_jump_s``) after scan 15: the local filters
    rejected every later measurement (``time_jump``, 18 of 18 each) and the centre fused nothing
    more, for good. Now each local filter rejects the first scan after the pause and starts again
    from the next (``restarted``); the centre rejects the first estimates after the pause, starts
    again from the next scan's (scan 18), and from then fuses every scan; its track converges to
    the clean run's (within a tenth of its own position standard deviation by the last scan)."""
    pause, gap = 16, 4000.0

    class Clock:  # the deadlines pass between scans: each scan comes a second after the last
        now = 0.0

        @staticmethod
        def monotonic() -> float:
            return Clock.now

    monkeypatch.setattr(centre_service, "time", Clock)
    monkeypatch.setattr(local_service, "time", Clock)
    services = paper_services(tmp_path)
    bus = Bus(list(services.values()))
    for k in range(SCANS):
        Clock.now += 1.0
        for svc in (services["centre"], *(services[f"local-{s}"] for s in SENSORS)):
            svc.on_tick()
        bus.drain()
        for s in SENSORS:
            m = MEASUREMENTS[s][k]
            bus.put(KEYS.sensor_meas(s), encode(replace(m, t=m.t + gap) if k >= pause else m))
    tracks = fused(bus)
    assert [t.seq for t in tracks] == [*range(pause), *range(pause + 2, SCANS)]
    for s in SENSORS:
        assert services[f"local-{s}"].counters.get("restarted") == 1
        assert services[f"local-{s}"].counters.get("rejected_time_jump") == 1
    assert services["centre"].counters.get("restarted") == 1 and services["centre"].counters["rejected_time_jump"] == 2
    clean = fused(clean_runs.paper()[0])
    same_tracks(tracks[:pause], clean[:pause])
    last, reference = tracks[-1], clean[-1]
    std = np.sqrt(last.P[0, 0] + last.P[last.x.shape[0] // 2, last.x.shape[0] // 2])
    assert last.model == reference.model and np.linalg.norm(last.x - reference.x) < 0.1 * std


@pytest.mark.parametrize("gap", [3000.0, 4000.0])
def test_the_radar_local_filter_starts_again_after_a_pause(gap: float) -> None:
    """A radar paused for 3,000 s (within ``max_time_jump_s``) or 4,000 s (beyond): the EKF local
    filter predicted over the pause and failed on every later scan (``numerical``: 31 of 40),
    for good. Now it starts again (``restarted``) on the second scan in a row it cannot process,
    or after a pause beyond ``max_time_jump_s`` (the first scan after it rejected ``time_jump``);
    its estimates are then those of a fresh filter fed the scans from that one on, exactly."""
    lines, pause = list(radar_scans(RadarConfig(), seed=3))[:80], 40
    base = Measurement(sensor="r1", seq=0, t=0.0, kind="radar", z=np.ones(3), R=np.eye(3),
                       sensor_position=np.zeros(3), stamp_ns=1)
    scans = [replace(base, seq=k, t=line["t"] + (gap if k >= pause else 0.0), z=np.array(line["z"]),
                     R=np.array(line["R"])) for k, line in enumerate(lines)]

    def estimates(scans: list[Measurement]) -> tuple[RadarLocalFilterService, list[Any]]:
        svc = RadarLocalFilterService("r1", make_radar_filter("ekf"), service_id="r1", options=OPTIONS,
                                      deployment=KEYS.deployment)
        bus = Bus([svc])
        for m in scans:
            bus.put(KEYS.sensor_meas("r1"), encode(m))
        return svc, [canonical(e) for e in bus.of(LocalEstimate)]

    paused, after = estimates(scans)
    _, fresh = estimates(scans[pause + 1:])
    reason = "time_jump" if gap > 3600.0 else "numerical"
    assert paused.counters.get(f"rejected_{reason}") == 1 and paused.counters["rejected"] == 1
    assert paused.counters.get("restarted") == 1
    assert len(after) == pause - 1 + len(fresh) and after[pause - 1:] == fresh


def test_one_local_filters_estimates_beyond_max_time_jump_do_not_restart_the_centre(
        tmp_path: Path, clean_runs: CleanRuns) -> None:
    """The centre starts again after a pause only when every live sensor's estimates follow it: one
    local filter sending estimates of scans 13 and 14 4,000 s ahead, before the genuine ones, has
    both rejected (``time_jump``) and changes no track."""
    clean, _ = clean_runs.paper()
    k = 13

    def forge(bus: Bus, scan: int) -> None:
        if scan == k:
            for seq in (k, k + 1):
                genuine = next(e for e in clean.of(LocalEstimate) if e.seq == seq and e.sensor == SENSORS[0])
                bus.put(KEYS.local_estimate(SENSORS[0]), encode(replace(genuine, t=genuine.t + 4000.0)))

    attacked, services = paper_run(tmp_path, forge)
    centre = services["centre"]
    assert centre.counters.get("rejected_time_jump") == 2 and centre.counters["rejected"] == 2
    assert centre.counters.get("restarted", 0) == 0
    same_tracks(fused(attacked), fused(clean))


def test_a_burst_of_scans_milliseconds_apart_does_not_stall_a_lone_sensors_tracker() -> None:
    """A lone sensor sends scans 11-18 10 ms apart right after scan 10 (a buggy sensor flushing
    its queue), then goes on at its one-second cadence: its usual interval (the median of its
    last 8) became 10 ms, so scan 19 led (held), and so did each later scan, never within 40 ms
    of a held one: the ``imm`` tracker took nothing more, for good, with nothing counted. A lone
    sensor's later scan now witnesses its held scans however far apart: every scan is tracked."""
    make, stream = SERVICES["imm"]
    burst = [replace(stream[10], seq=10 + j, t=stream[10].t + 0.01 * j) for j in range(1, 9)]
    svc = make()
    bus = Bus([svc])
    for m in [*stream[:11], *burst, *stream[19:]]:
        bus.put(svc.keys.sensor_meas(m.sensor), encode(m))
    assert [t.seq for t in bus.of(FusedTrack)] == list(range(len(stream)))
    assert svc.lead.time.held == [] and svc.counters["rejected"] == 0
