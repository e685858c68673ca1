"""A service started again under the same identity numbers its pictures as the one before it did
(faults5 session). The recorder keys pictures by number and keeps the first of a number: before
2026-11-27 a restarted ``serve picture`` and a cold standby that took over numbered their pictures
from 0 again, and the recorder refused each of them whose number an earlier picture had had
(``conflict``): of a 40 s launch at 2x, 9 merged pictures (the merger SIGKILLed at t = 10 s) and 15
pictures (the unsharded centre's primary killed, then its standby) were missing from the recording.
In-process, on the bus of ``test_hostile_messages``."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_hostile_messages import KEYS, OPTIONS, Bus
from test_hostile_sequences import region_picture
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService, resumed
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


@pytest.mark.parametrize("snapshot", [True, False])
def test_a_restarted_merger_merges_the_pictures_of_its_outage_from_the_region_caches(tmp_path: Path,
                                                                                     snapshot: bool) -> None:
    """The merger SIGKILLed after t = 3, back when the regions are at t = 9: it subscribes to the region
    pictures with history, so the regions' caches replay their last pictures (region b's holds one more,
    t = 2, than a's), a's overtaken by its live t = 10, which comes among b's replies (held as leading
    them by 5 s and dropped by the next reply, it was missing from the merged t = 10); the base
    service's second query of the caches and a standby's cache deliver them again. It publishes t = 4-9
    in order, numbered 4-9, none contested, every re-delivery a duplicate. With the launcher's
    ``--snapshot`` it knows t = 3 was merged; without it merges t = 3 again (the recorder keeps the
    first: the same picture stamped anew, a duplicate; a conflict before the tour59 session) and not t = 2,
    which only b's cache holds (merged, it would lack region a).
    Before: the region pictures had no cache (nothing of t = 4-8 came: 5 of 10 merged pictures
    missing), and a picture older than its region's latest was refused."""
    config = tmp_path / "config.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    state = tmp_path / "picture.snapshot" if snapshot else None
    first, again = (PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS,
                                        deployment=KEYS.deployment, snapshot=state) for _ in range(2))
    assert all(sub.history for sub in again.subscriptions())
    recorder = Recorder(tmp_path / "rec.db", service_id="rec", options=OPTIONS, deployment=KEYS.deployment)
    recorder.on_start()
    before = merged_on([first, recorder], range(4))
    bus = Bus([again, recorder])
    again.on_start()  # settling: the caches' replies come in
    a, b = (KEYS.region_picture(rid) for rid in regions.ids)
    pictures = {(key, k): encode(region_picture(float(k), ids)) for key, ids in ((a, (0, 2)), (b, (1, 3)))
                for k in range(2, 11)}
    replies = ([(b, k) for k in range(2, 6)] + [(a, 10)]  # a's live t = 10 among b's replies: 5 s ahead of them
               + [(a, k) for k in range(3, 10)] + [(b, k) for k in range(6, 10)])
    for key, k in replies + replies[::-1]:  # the caches' replies, then the second query's (any order)
        bus.put(key, pictures[key, k])
    assert not bus.of(TrackPicture)  # nothing merged while the replies come in
    again.settle_until = time.monotonic()  # HISTORY_SETTLE_S later
    with again.guarded("on_tick", again.tick_state_attrs):
        again.on_tick()
    for key, k in [(b, 8), (b, 9), (b, 10)]:  # a standby's cache, then the live picture
        bus.put(key, pictures[key, k])
    after = bus.of(TrackPicture)
    resent = [] if snapshot else [3]
    assert [(p.seq, p.t) for p in before + after] == [(k, float(k)) for k in (0, 1, 2, 3, *resent, *range(4, 11))]
    assert [p.ids for p in after] == [(0, 1, 2, 3)] * len(after) and not any(p.contested for p in after)
    assert again.counters["duplicate"] == len(replies) + 2
    assert (again.counters.get("merged_before"), again.counters.get("cache_partial")) == ((3, None) if snapshot
                                                                                           else (None, 1))
    assert again.counters["rejected"] == 0 and "contested" not in again.counters
    recorder.on_stop()
    assert recorder.counters.get("pictures_recorded") == 11 and "conflict" not in recorder.counters
    assert recorder.counters.get("duplicate", 0) == len(resent)  # t = 3 again, equal but for its stamp
    if state is not None:
        assert resumed(state.read_bytes(), 2) == (10.0, {})


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


def test_a_merger_snapshot_cut_or_corrupted_on_disk_is_refused_and_every_cached_time_merged(tmp_path: Path) -> None:
    """``serve picture --snapshot``: a file whose time was changed on disk (12.0 to 92.0), cut, of the
    format before 2026-11-27 (the time alone, which such a change turned into a restart skipping every
    picture up to t = 92) or not finite is refused, as is a FIFO or a link to /dev/zero put in its place (unread):
    the restart merges every time the caches hold, as without a snapshot, and skips none."""
    from fedtrack.fusion_center.mtt.picture_merge import SHOWN_DTYPE, SNAPSHOT_MAGIC
    from fedtrack.services.snapshot import write_sealed

    config = tmp_path / "config.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    state = tmp_path / "picture.snapshot"

    def started() -> PictureMergeService:
        merger = PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS,
                                     deployment=KEYS.deployment, snapshot=state)
        merger.on_start()
        return merger
    started()._keep(12.0)
    good = state.read_bytes()
    assert started().resumed_t == 12.0
    sealed = []
    for magic, data in ((SNAPSHOT_MAGIC, b"inf"), (b"fedtrack-picture-1\n", b"12.0"),  # the time alone: version 1
                        (SNAPSHOT_MAGIC, b"12.0\n" + np.array([(5, 2)], SHOWN_DTYPE).tobytes()),  # region 2 of 2
                        (SNAPSHOT_MAGIC, b"12.0\n" + bytes(5))):  # no whole (id, region)
        write_sealed(state, magic, data)
        sealed.append(state.read_bytes())
    for bad in (good.replace(b"12.0", b"92.0"), good[:-1], b"92.0", *sealed):
        state.write_bytes(bad)
        assert started().resumed_t is None, bad
    state.unlink()
    state.symlink_to("/dev/zero")  # read whole: a MemoryError ended the start
    assert started().resumed_t is None
    state.unlink()
    os.mkfifo(state)  # opened to read: the start blocked until something wrote to it
    assert started().resumed_t is None
