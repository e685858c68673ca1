"""The fusion centre's snapshot (--snapshot): saved atomically after a scan, as data only (no pickle),
resumed only when it fits; anything else refused field by field, counted, and the centre fresh."""

from __future__ import annotations

import functools
import logging
import pickle
from collections.abc import Iterable
from hashlib import blake2b
from pathlib import Path
from typing import Any
from unittest import mock

import msgpack
import numpy as np
import pytest

from fedtrack.config import ConfigError
from fedtrack.fusion_center.centre import DecentralizedCentre, FederatedCentre
from fedtrack.fusion_center.service import FusionCenterService
from fedtrack.fusion_center.snapshot import SNAPSHOT_MAGIC, snapshot_data
from fedtrack.keys import Keys
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import MAX_WINDOW, VdieParams
from fedtrack.services.snapshot import DIGEST_BYTES, unsealed, write_sealed
from fedtrack.wire import FusedTrack, LocalEstimate, encode
from fedtrack.zsession import SessionOptions

KEYS = Keys("d")


def centre(folder: Path | None, deployment: str = "d", sensors: tuple[str, ...] = ("1", "2"),
           kind: type[FederatedCentre | DecentralizedCentre] = FederatedCentre,
           config: FusionConfig | None = None) -> FusionCenterService:
    """A centre whose ``--snapshot`` is ``folder/fc.snapshot`` (the folder made if missing; None: no
    snapshot)."""
    if folder is not None:
        folder.mkdir(exist_ok=True)
    return FusionCenterService(list(sensors), kind(list(sensors), config or FusionConfig()), 0.5,
                               snapshot=folder and folder / "fc.snapshot", service_id="fusion",
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
    (tmp_path / "fc.snapshot").write_bytes(b"not a snapshot")
    broken = centre(tmp_path)
    broken._restore()
    assert not broken.restored and broken.last_track is None and broken.counters["snapshot_refused"] == 1


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


@functools.cache
def stream() -> tuple[tuple[LocalEstimate, ...], tuple[bytes, ...]]:
    """The local estimates of ``test_fuzz_handlers``' federated pipeline (paper 004 scenario 1, two
    sensors, 34 scans, a maneuver onset fused at scan 32) and its centre's tracks (wire bytes)."""
    from test_fuzz_handlers import run

    pipe = run()
    return (tuple(m for _, m in pipe.published if isinstance(m, LocalEstimate)),
            tuple(encode(t) for t in pipe.tracks()))


def fed(svc: FusionCenterService, estimates: Iterable[LocalEstimate]) -> list[bytes]:
    """The tracks (wire bytes) ``svc`` publishes when it takes ``estimates`` through its own dispatch."""
    tracks: list[bytes] = []
    svc._subscriptions = svc.subscriptions()

    def publish(key: str, msg: Any) -> None:
        if isinstance(msg, FusedTrack):
            tracks.append(encode(msg))

    svc.publish = publish  # type: ignore[method-assign]
    for e in estimates:
        svc._dispatch(("sample", 0, KEYS.local_estimate(e.sensor), encode(e)))
    return tracks


@pytest.mark.parametrize("kind", [FederatedCentre, DecentralizedCentre])
@pytest.mark.parametrize("k", [31, 32])  # the scan before the onset (a candidate filling), the onset (in CA)
def test_a_centre_resumed_from_its_snapshot_fuses_exactly_the_tracks_of_one_never_stopped(
        tmp_path: Path, kind: type[FederatedCentre | DecentralizedCentre], k: int) -> None:
    """A centre stopped after scan ``k`` and started again from its snapshot publishes, byte for byte,
    the tracks of a centre that never stopped (its state read back equals the one written)."""
    estimates, _ = stream()
    whole = fed(centre(None, kind=kind), estimates)
    first = centre(tmp_path / "run", kind=kind)
    assert fed(first, [e for e in estimates if e.seq <= k]) == whole[:k + 1]
    again = centre(tmp_path / "run", kind=kind)
    again._restore()
    assert again.restored and again.counters["restored"] == 1 and "snapshot_refused" not in again.counters
    assert snapshot_data("d", again.centre, again.last_track) == snapshot_data("d", first.centre, first.last_track)
    if kind is FederatedCentre:  # resumed in CV with a candidate filling (31), in CA (32)
        assert bool(again.centre.vdie.is_ca) == (k == 32)
    assert fed(again, [e for e in estimates if e.seq > k]) == whole[k + 1:]


class Payload:
    """Unpickled, it creates the file ``path`` (what a pickle in the output folder could do at a restart)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple[Any, ...]:
        return open, (str(self.path), "x")


@pytest.mark.parametrize("magic", [b"fedtrack-centre-1\n", SNAPSHOT_MAGIC])
def test_a_pickle_in_the_snapshot_is_refused_unread_and_creates_nothing(
        tmp_path: Path, magic: bytes, caplog: pytest.LogCaptureFixture) -> None:
    """A snapshot holding a pickle whose loading would create a file, behind a valid digest, of the
    format before 2026-11-27 (a pickle: it created the file at the restart) or of today's: refused in
    one log line, counted ``snapshot_refused``, nothing created; the centre starts fresh (rebuilt
    from the next scan's local estimates, as without a snapshot)."""
    marker = tmp_path / "created-by-the-snapshot"
    write_sealed(tmp_path / "fc.snapshot", magic, pickle.dumps({"deployment": "d", "centre": Payload(marker),
                                                                "track": b""}))
    svc = centre(tmp_path)
    with caplog.at_level(logging.WARNING, logger=svc.log.name):
        svc._restore()
    assert not marker.exists()
    assert not svc.restored and svc.last_track is None and svc.next_seq is None and svc.centre.vdie is None
    assert svc.counters["snapshot_refused"] == 1 and "restored" not in svc.counters
    lines = [r.getMessage() for r in caplog.records if r.name == svc.log.name]
    assert len(lines) == 1 and "refused" in lines[0] and "starting fresh" in lines[0] and "\n" not in lines[0]
    assert ("version '1' of the format" if magic != SNAPSHOT_MAGIC else "not valid msgpack") in lines[0], lines
    estimates, _ = stream()
    fresh = centre(None)
    later = [e for e in estimates if e.seq >= 20]
    assert fed(svc, later) == fed(fresh, later) and svc.counters["rebuilt"] == 1


def resealed(good: bytes, *keys: str, value: Any) -> bytes:
    """The snapshot file ``good`` with the entry at ``keys`` of its map set to ``value`` and its digest
    made again (as a writer of the folder could)."""
    obj = msgpack.unpackb(unsealed(good, SNAPSHOT_MAGIC), raw=False)
    functools.reduce(dict.__getitem__, keys[:-1], obj)[keys[-1]] = value
    data = msgpack.packb(obj, use_bin_type=True)
    return SNAPSHOT_MAGIC + blake2b(data, digest_size=DIGEST_BYTES).digest() + data


def test_a_cut_tampered_or_wrong_shape_snapshot_is_refused_and_the_centre_starts_fresh(tmp_path: Path) -> None:
    """A real snapshot (after scan 31) cut (inside its head, inside its data), a byte changed, its
    state's arrays changed and the digest made again (a NaN, an array of another shape, a boolean
    2, a field added, a track the wire refuses), or written with another ``[fusion.vdie] window`` (its
    candidate banks of another shape): each refused naming the field, counted, the centre fresh."""
    estimates, _ = stream()
    first = centre(tmp_path)
    fed(first, [e for e in estimates if e.seq <= 31])
    path = tmp_path / "fc.snapshot"
    good = path.read_bytes()
    wide = centre(tmp_path / "w", config=FusionConfig(vdie=VdieParams(window=8)))
    fed(wide, [e for e in estimates if e.seq <= 31])
    cases = [
        ("cut short", good[:30]), ("checksum mismatch", good[:-1]),
        ("checksum mismatch", good[:100] + bytes([good[100] ^ 0xFF]) + good[101:]),
        ("state.x: contains NaN", resealed(good, "state", "x", "data", value=np.full(6, np.nan).tobytes())),
        ("state.bank_cv.E.shape: expected [6, 4, 2], got [6, 2, 4]",
         resealed(good, "state", "bank_cv", "E", "shape", value=[6, 2, 4])),
        ("state.is_ca: a boolean other than 0 or 1", resealed(good, "state", "is_ca", "data", value=b"\x02")),
        ("snapshot: expected the fields", resealed(good, "code", value="import os")),
        ("track.payload: not valid msgpack", resealed(good, "track", value=b"\x80\x04garbage")),
        ("state.bank_cv.E.shape: expected [6, 4, 2], got [8, 4, 2]", (tmp_path / "w" / "fc.snapshot").read_bytes()),
    ]
    for reason, raw in cases:
        path.write_bytes(raw)
        svc = centre(tmp_path)
        with mock.patch.object(svc.log, "warning") as warn:
            svc._restore()
        assert not svc.restored and svc.last_track is None and svc.centre.vdie is None, reason
        assert svc.counters["snapshot_refused"] == 1, reason
        (message, *args), = [c.args for c in warn.call_args_list]
        assert reason in message % tuple(args), (reason, message % tuple(args))


def test_the_largest_detector_window_a_config_takes_still_resumes_from_its_snapshot(tmp_path: Path) -> None:
    """``[fusion.vdie] window`` and ``p`` are bounded (MAX_WINDOW): beyond, the snapshot's arrays outgrew
    the wire's size limits its reader applies, so every restart started fresh."""
    with pytest.raises(ConfigError, match=f"window: must be between 1 and {MAX_WINDOW}"):
        VdieParams(window=MAX_WINDOW + 1).validate()
    with pytest.raises(ConfigError, match=f"p: must be between 1 and {MAX_WINDOW}"):
        VdieParams(p=MAX_WINDOW + 1).validate()
    config = FusionConfig(vdie=VdieParams(window=MAX_WINDOW, p=MAX_WINDOW))
    estimates, _ = stream()
    first = centre(tmp_path, config=config)
    fed(first, [e for e in estimates if e.seq <= 31])
    again = centre(tmp_path, config=config)
    again._restore()
    assert again.restored and again.counters.get("snapshot_refused", 0) == 0
    assert again.last_track is not None and again.last_track.seq == 31
