"""Sequences of valid messages that a peer the access control admits can send (marker ``security``):
a picture sent twice for one time, a clock that runs ahead of the others'. Each test shows the
harm on the code before its fix and that the service now refuses the message, counted, with the
honest output unchanged. The services run in-process through their own dispatch
(:class:`test_hostile_messages.Bus`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_hostile_messages import KEYS, OPTIONS, Bus
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.local_filters.regions import load_regions
from fedtrack.wire import TrackPicture, encode

pytestmark = pytest.mark.security


def region_picture(t: float, ids: tuple[int, ...], x: float = 0.0) -> TrackPicture:
    n = len(ids)
    return TrackPicture(seq=int(t), t=t, ids=ids, x=np.full((n, 4), x), P=np.tile(np.eye(4), (n, 1)),
                        confirmed=(True,) * n, sensors=(("s1",),) * n, fused_sensors=("s1",), fused_seqs=(int(t),),
                        left=(), stamp_ns=1, closing=False)


def test_a_region_picture_sent_twice_for_one_time_neither_stalls_nor_repeats_the_merge(tmp_path: Path) -> None:
    """A region centre publishing a second picture of a time it had published (two primaries during a
    split brain, a re-send, or a forgery by a ``fusion`` identity) put two pictures of one time in the
    region's queue: the merge of that time then looked up its first sighting, already forgotten
    (``KeyError``), the merger's state was put back after it had published, and every tick (20 Hz)
    published the same merged picture again (same ``seq``) and failed: ``serve picture`` never
    merged another time. Now the second picture is refused (``conflict``; an identical one is a
    ``duplicate``), the next merged picture is ``contested``, and every time is merged once."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None and len(regions.ids) == 2
    svc = PictureMergeService(regions, 4, 2.0, service_id="picture", options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    a, b = (KEYS.region_picture(rid) for rid in regions.ids)
    bus.put(a, encode(region_picture(0.0, (0, 2))))
    bus.put(a, encode(region_picture(0.0, (0, 2))))  # re-sent: the same picture
    bus.put(a, encode(region_picture(0.0, (0, 2), x=5.0)))  # a second, different one of the same time
    bus.put(b, encode(region_picture(0.0, (1, 3))))
    for _ in range(3):  # the service's ticks, as its loop runs them
        with svc.guarded("on_tick", svc.tick_state_attrs):
            svc.on_tick()
    for k in range(1, 4):
        bus.put(a, encode(region_picture(float(k), (0, 2))))
        bus.put(b, encode(region_picture(float(k), (1, 3))))
    merged = bus.of(TrackPicture)
    assert "rejected_handler_error" not in svc.counters
    assert [(p.seq, p.t) for p in merged] == [(0, 0.0), (1, 1.0), (2, 2.0), (3, 3.0)]
    assert svc.counters["duplicate"] == 1 and svc.counters["rejected_conflict"] == 1 and svc.counters["contested"] == 1
    assert [p.contested for p in merged] == [True, False, False, False]
    assert merged[0].ids == (0, 1, 2, 3) and not merged[0].x.any()  # the first picture of region a stays
    assert merged[0].fused_seqs == (0, 0)  # each region's entries once
