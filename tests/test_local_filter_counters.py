"""The 2-D local filter's counters say what they count (in process): a scan refused when its turn
came is no gap in its sensor's numbers."""

from __future__ import annotations

from dataclasses import replace

from test_fuzz_trackers import position_stream
from test_hostile_messages import KEYS, OPTIONS, Bus

from fedtrack.local_filters.service import LocalFilterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.local import VdieLocalFilter
from fedtrack.wire import LocalEstimate, encode


def test_a_scan_refused_at_its_turn_is_no_gap() -> None:
    """Scan 10 at the time of scan 9 is rejected (``time_jump``, as at every live filter); the 2-D local
    filter then also counted scan 11 as following a gap (``gaps`` 1, 'measurements 10..10 never arrived')
    for the number it had itself refused. Now ``gaps`` stays 0 and the estimates are those of every
    other scan."""
    svc = LocalFilterService("p1", "decentralized", VdieLocalFilter(1, FusionConfig()), 0.5, service_id="p1",
                             options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    stream = position_stream()
    stream[10] = replace(stream[10], t=stream[9].t)
    for m in stream:
        bus.put(KEYS.sensor_meas("p1"), encode(m))
    assert [e.seq for e in bus.of(LocalEstimate)] == [k for k in range(25) if k != 10]
    assert svc.counters["rejected_time_jump"] == 1 and svc.counters["rejected"] == 1
    assert svc.counters.get("gaps", 0) == 0  # before: 1
