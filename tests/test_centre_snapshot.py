"""The fusion centre's snapshot (--snapshot): saved atomically after a scan, resumed only when it fits."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fedtrack.fusion_center.centre import FederatedCentre
from fedtrack.fusion_center.service import FusionCenterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.wire import FusedTrack
from fedtrack.zsession import SessionOptions


def centre(tmp_path: Path, deployment: str = "d", sensors: tuple[str, ...] = ("1", "2")) -> FusionCenterService:
    return FusionCenterService(list(sensors), FederatedCentre(list(sensors), FusionConfig()), 0.5,
                               snapshot=tmp_path / "fc.snapshot", service_id="fusion",
                               options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment=deployment)


def test_snapshot_round_trip_and_refusals(tmp_path: Path) -> None:
    first = centre(tmp_path)
    first.centre.t = 7.0
    track = FusedTrack(seq=7, t=7.0, model="cv", x=np.ones(4), P=np.eye(4), maneuver=False, degraded=False,
                       sensors=("1", "2"), stamp_ns=1)
    first._save(track)
    assert [p.name for p in tmp_path.iterdir()] == ["fc.snapshot"]  # no temporary left
    again = centre(tmp_path)
    again._restore()
    assert again.restored and again.next_seq == 8 and again.last_track.seq == 7 and again.centre.t == 7.0
    assert again.counters["restored"] == 1
    for other in (centre(tmp_path, deployment="e"), centre(tmp_path, sensors=("1", "3"))):
        other._restore()
        assert not other.restored and other.next_seq is None
    (tmp_path / "fc.snapshot").write_bytes(b"not a pickle")
    broken = centre(tmp_path)
    broken._restore()
    assert not broken.restored and broken.last_track is None


def test_a_snapshot_that_cannot_be_written_leaves_every_scan_fused(tmp_path: Path) -> None:
    """A snapshot write that fails (here its folder is gone; live, a file size limit or a full disk)
    is counted and the scan stands: the tracks equal those of a centre without a snapshot. Before
    2026-11-27 the failure undid each scan after its track and resets were out (rejected as a
    ``handler_error``), so the centre's state stayed at the last scan it could save."""
    from test_fuzz_handlers import SCANS, run

    plain, failing = run(), run(snapshot=tmp_path / "gone" / "fc.snapshot")
    assert [(t.seq, t.x.tolist(), t.P.tolist()) for t in failing.tracks()] == \
        [(t.seq, t.x.tolist(), t.P.tolist()) for t in plain.tracks()]
    assert len(failing.tracks()) == SCANS
    assert failing.centre.counters["snapshot_failed"] == SCANS and failing.centre.counters["rejected"] == 0
    assert list(tmp_path.iterdir()) == []
