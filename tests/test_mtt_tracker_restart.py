"""A local multi-target tracker restarted mid-run (a crash the launcher restarts): the new process
starts afresh (tracks and ids new), so the centre drops the former process's local tracks and the
recording lists the restart; its replay starts that tracker afresh there too, and equals the live
pictures. Before, the replay ran the sensor's tracker on through the restart: `fedtrack launch` with
s2's tracker and sensor SIGKILLed and restarted had `verify_run` report ``max_replay_diff`` inf (the
tracks of s2 differing from the restart on), and a restart the centre took before the lost liveliness
(no departure) fused the new process's ids 0, 1, ... into the central tracks of the old one's.
In process (:class:`test_hostile_messages.Bus`), about 1 s each."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import zenoh
from support import assert_same_pictures
from test_hostile_messages import KEYS, MTT_SENSORS, OPTIONS, Bus, mtt_lines, mtt_services

from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import SensorTracker, could_be_first, report_to_wire
from fedtrack.local_filters.mtt.scan import scan_from_measurement
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.wire import encode

RESTART_T = 6.0  # s2's tracker restarts then (the scenario is 12 s)


def lose_token(centre: Any, sensor: str) -> None:
    """The centre sees ``sensor``'s tracker's liveliness token go."""
    centre._on_alive(SimpleNamespace(key_expr=KEYS.alive("mtt-local", sensor), kind=zenoh.SampleKind.DELETE))


def lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# (federated after the departure: the centre's resets made the old replay's pictures equal on this scenario)
@pytest.mark.parametrize(("algorithm", "departed"), [("mtt-decentralized", True), ("mtt-federated", False)],
                         ids=["decentralized-after-its-departure", "federated-before-its-departure"])
def test_a_restarted_tracker_starts_afresh_in_the_replay_too(tmp_path: Path, algorithm: str, departed: bool) -> None:
    services = mtt_services(tmp_path, algorithm)
    centre, recorder = services["centre"], services["recorder"]
    bus = Bus(list(services.values()))
    restarted = False
    for msg in mtt_lines(tmp_path):
        if msg.t >= RESTART_T and not restarted:
            restarted = True
            if departed:  # its liveliness token went with the process
                lose_token(centre, "s2")
                centre.on_tick()
            cfg = MttConfig(sensors=MTT_SENSORS, max_lag=3.0, clutter_density=2.0 / 5000.0**2)
            services["s2"] = MttLocalService("s2", algorithm == "mtt-federated", cfg, 5.0, service_id="s2",
                                             options=OPTIONS, deployment=KEYS.deployment)
            published = bus.published
            bus = Bus(list(services.values()))
            bus.published = published
        bus.put(KEYS.sensor_meas(msg.sensor), encode(msg))
    centre.on_stop()
    bus.drain()
    assert centre.counters["trackers_restarted"] == 1
    assert centre.counters.get("sensors_left", 0) == int(departed)  # a restart is no departure
    assert "rejected_handler_error" not in centre.counters

    measurements, live = tmp_path / "m.jsonl", tmp_path / "live.jsonl"
    recorder.recording.export(measurements, live)  # type: ignore[attr-defined]
    marks = [obj for obj in lines(measurements) if "detections" not in obj]
    assert [(m["sensor"], "left" in m) for m in marks] == [("s2", True)] * departed + [("s2", False)]
    config = tmp_path / "c.toml"
    config.write_text('[mtt]\nsensors = ["s1", "s2", "s3"]\nmax_lag = 3.0\nclutter_density = 8e-8\n')
    again = tmp_path / "again.jsonl"
    replay_mtt(algorithm, measurements, config, again)
    assert_same_pictures(lines(live), lines(again))



def test_a_restarted_tracker_of_a_region_run_starts_afresh_in_its_replay_too(tmp_path: Path) -> None:
    """The same with a centre per region (each lists the restart; the replay restarts the shared
    tracker once, with the scan the lines name); decentralized, whose pictures the old replay missed."""
    from test_mtt_regions_live import CONFIG, services

    config = tmp_path / "config.toml"
    config.write_text(CONFIG)
    cfg = MttConfig(sensors=MTT_SENSORS, max_lag=3.0, clutter_density=1.2e-7)
    common = {"options": OPTIONS, "deployment": KEYS.deployment}
    centres, local, merger, recorder = services(tmp_path, "mtt-decentralized", config, cfg, common)
    recorder.on_start()
    bus = Bus([*centres, *local, merger, recorder])
    restarted = False
    for m in mtt_lines(tmp_path):
        if m.t >= RESTART_T and not restarted:
            restarted = True
            for c in centres:  # s2's liveliness token went with its process
                lose_token(c, "s2")
                c.on_tick()
            local[1] = MttLocalService("s2", False, cfg, 5.0, regions=merger.regions, service_id="s2", **common)
            published = bus.published
            bus = Bus([*centres, *local, merger, recorder])
            bus.published = published
        bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    for svc in [*local, *centres, merger]:
        svc.on_stop()
        bus.drain()
    recorder.on_stop()
    assert [c.counters.get("trackers_restarted") for c in centres] == [1, 1]
    marks = [obj for obj in lines(tmp_path / "out" / "measurements.jsonl") if obj.get("restarted")]
    assert sorted(m["region"] for m in marks) == ["x0y0", "x1y0"] and all(m["sensor"] == "s2" for m in marks)
    again = tmp_path / "again.jsonl"
    replay_mtt("mtt-decentralized", tmp_path / "out" / "measurements.jsonl", config, again, regions="config")
    assert_same_pictures(lines(tmp_path / "out" / "tracks.jsonl"), lines(again))



@pytest.mark.parametrize("associator", ["gnn", "jipda", "mht"])
def test_only_a_fresh_trackers_report_could_be_first(tmp_path: Path, associator: str) -> None:
    """A tracker's first report (tracks in it) is one a fresh tracker could send (every track started
    by its scan, none retired), so the centre takes it as a restart; none of its later reports is (a
    report marked ``first`` then: ``restarts_ignored``, docs/multitarget-formats.md)."""
    cfg = MttConfig(sensors=MTT_SENSORS, max_lag=3.0, clutter_density=2.0 / 5000.0**2, associator=associator)
    scans = [scan_from_measurement(m) for m in mtt_lines(tmp_path) if m.sensor == "s2"]
    tracker = SensorTracker(scans[0], cfg, False)
    reports = [report_to_wire(tracker.track(scan)[0], seq, 1) for seq, scan in enumerate(scans)]
    assert reports[0].ids and [could_be_first(r) for r in reports] == [True] + [False] * (len(reports) - 1)
