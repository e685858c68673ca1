"""A service started again under the same identity numbers its pictures as the one before it did
(faults5 session). The recorder keys pictures by number and keeps the first of a number: before
2026-11-27 a restarted ``serve picture`` and a cold standby that took over numbered their pictures
from 0 again, and the recorder refused each of them whose number an earlier picture had had
(``conflict``): of a 40 s launch at 2x, 9 merged pictures (the merger SIGKILLed at t = 10 s) and 15
pictures (the unsharded centre's primary killed, then its standby) were missing from the recording.
In-process, on the bus of ``test_hostile_messages``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from test_hostile_messages import KEYS, OPTIONS, Bus
from test_hostile_sequences import region_picture
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.regions import load_regions
from fedtrack.services.recorder import Recorder
from fedtrack.wire import TrackPicture, encode


def merged_on(bus_services: list[Any], times: range) -> list[TrackPicture]:
    """The merged pictures ``bus_services``' merger publishes for the two regions' pictures at ``times``."""
    merger = bus_services[0]
    bus = Bus(bus_services)
    a, b = (KEYS.region_picture(rid) for rid in merger.regions.ids)
    for k in times:  # region_picture numbers a picture at t = k as k, as a region centre started at 0 does
        bus.put(a, encode(region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
    return bus.of(TrackPicture)


def test_a_restarted_merger_numbers_on_and_the_recorder_keeps_every_picture(tmp_path: Path) -> None:
    config = tmp_path / "config.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    recorder = Recorder(tmp_path / "rec.db", service_id="rec", options=OPTIONS, deployment=KEYS.deployment)
    recorder.on_start()
    first, again = (PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS,
                                        deployment=KEYS.deployment) for _ in range(2))
    before = merged_on([first, recorder], range(4))  # then SIGKILLed: t = 4, 5 merged by nobody
    after = merged_on([again, recorder], range(6, 9))  # the launcher's restart
    assert [(p.seq, p.t) for p in before + after] == [(k, float(k)) for k in (0, 1, 2, 3, 6, 7, 8)]
    recorder.on_stop()
    assert recorder.counters.get("pictures_recorded") == 7 and "conflict" not in recorder.counters, recorder.counters


def test_a_cold_standby_numbers_its_pictures_as_its_primary() -> None:
    """The restarted centre (a standby started after its primary's first picture) numbers its picture
    at t = 9 s, after a take-over, 9 (it was its own first: 0), whether it saw the primary's pictures
    (it takes their numbers) or not (a picture's number is its time over the period)."""
    standby = MttCentreService("mtt-federated", MttConfig(sensors=("s1",)), 4, standby=True, service_id="c",
                               options=OPTIONS, deployment=KEYS.deployment)
    Bus([standby]).put(KEYS.mtt_picture(), encode(TrackPicture(
        seq=5, t=5.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(), fused_sensors=(),
        fused_seqs=(), stamp_ns=1)))
    assert standby.standby.cold
    assert standby._picture(9.0).seq == 9
    unseen = MttCentreService("mtt-federated", MttConfig(sensors=("s1",)), 4, standby=True, service_id="d",
                              options=OPTIONS, deployment=KEYS.deployment)
    unseen.clock.due(8.3)  # its first scan, at 8.3 s: it saw no picture of the primary (up after it died)
    assert unseen._picture(9.0).seq == 9
