"""Messages valid on the wire but semantically hostile, against the services in-process (marker
``security``): what an attacker holding a valid identity on the bus, or a broken sensor, can send.

Each test first shows the harm the message did (a buffer that grew with every message, a track
the message wrecked) and then that the service now bounds or refuses it, counted. The services are
driven through their own dispatch (decode, sender check, guarded handler), the path a Zenoh sample
takes (:class:`test_hostile_messages.Bus`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_fuzz_trackers import position_stream
from test_hostile_messages import KEYS, OPTIONS, Bus, mtt_lines, mtt_services
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.fusion_center.mtt import service as centre_service_module
from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.service import HANDOVERS_KEPT, MttCentreService
from fedtrack.geodetic import Frame
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.service import IMMService
from fedtrack.local_filters.linear import gating
from fedtrack.local_filters.mtt import history as history_module
from fedtrack.local_filters.mtt import service as service_module
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.history import MAX_ENTRIES
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.regions import load_regions
from fedtrack.local_filters.service import LocalFilterService, RadarLocalFilterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.local import VdieLocalFilter
from fedtrack.services.recorder import Recorder
from fedtrack.wire import (
    MAX_LIST_ITEMS,
    MAX_PARTS,
    MAX_TRACKS,
    Detection,
    FusedTrack,
    HandOver,
    LocalEstimate,
    Measurement,
    TrackPicture,
    TrackReport,
    TrackResets,
    WireError,
    decode,
    encode,
    payloads,
)

pytestmark = pytest.mark.security


def scan(sensor: str, seq: int, t: float, z: np.ndarray, R: np.ndarray | None = None) -> Measurement:
    """A multi-target scan of ``sensor`` with detections ``z`` (k, 2)."""
    return Measurement(sensor=sensor, seq=seq, t=t, kind="scan", z=np.zeros(0),
                       R=np.eye(2) * 100.0 if R is None else R, detections=[(row, 0.0) for row in z], stamp_ns=1)


def mtt_local(federated: bool, **kwargs: Any) -> tuple[Bus, MttLocalService]:
    svc = MttLocalService("s1", federated, MttConfig(sensors=("s1",), max_lag=3.0, clutter_density=1e-7), 2.0,
                          service_id="s1", options=OPTIONS, deployment=KEYS.deployment, **kwargs)
    return Bus([svc]), svc


# ---------------------------------------------------------------- scans microseconds apart

def test_scans_microseconds_apart_keep_a_bounded_history(monkeypatch: Any) -> None:
    """A sensor sending scans 0.1 ms apart (all within ``max_lag``) made its tracker keep every one,
    with the state after it: memory grew with every scan and one late scan re-ran them all (2,000
    scans: 58 MB, 3.5 s). The history keeps at most MAX_ENTRIES (256; 16 here, for speed), the
    older folded into the checkpoint; a scan before the checkpoint is late."""
    assert MAX_ENTRIES == 256
    monkeypatch.setattr(history_module, "MAX_ENTRIES", 16)
    bus, svc = mtt_local(federated=False)
    rng = np.random.default_rng(3)
    n = 16 + 24
    for k in range(n):
        bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", k, 1e-4 * k, rng.uniform(-5e3, 5e3, (3, 2)))))
    history = svc.tracker.history  # type: ignore[union-attr]
    assert svc.counters["reports"] == n
    assert len(history.times) == 16 and history.base_t == pytest.approx(1e-4 * (n - 16 - 1))
    bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", n, 1e-4 * 10.5, rng.uniform(-5e3, 5e3, (3, 2)))))
    assert svc.counters["late"] == 1 and len(history.times) == 16


def test_scans_waiting_for_resets_are_bounded(monkeypatch: Any) -> None:
    """A federated tracker holds the scans that arrive while it waits for the centre's resets: with
    the centre slow or gone (one scan a ``--reset-timeout``) or a sensor flooding scans, that queue
    grew with every scan. It holds at most MAX_ENTRIES (16 here); beyond, the oldest waiting scan
    is dropped and counted ``queue_dropped``, and the tracker goes on with the newest."""
    monkeypatch.setattr(service_module, "MAX_ENTRIES", 16)
    bus, svc = mtt_local(federated=True)
    rng = np.random.default_rng(4)
    n = 40
    for k in range(n):
        bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", k, float(k), rng.uniform(-5e3, 5e3, (3, 2)))))
    assert svc.awaiting == 0 and len(svc.queue) == 16 and svc.counters["queue_dropped"] == n - 1 - 16
    assert [seq for seq, _, _ in svc.queue] == list(range(n - 16, n))
    svc.awaiting_since -= 10.0  # the reset timeout passed: the tracker goes on with the oldest kept
    svc.on_tick()
    assert svc.counters["reports"] == 2 and svc.awaiting == n - 16 and len(svc.queue) == 15


# ---------------------------------------------------------------- numbers no sensor can mean

def position_trackers() -> tuple[Bus, IMMService, LocalFilterService]:
    """The IMM tracker and a decentralized (DVDIE) local filter of the position sensor ``p1``."""
    common: dict[str, Any] = {"options": OPTIONS, "deployment": KEYS.deployment}
    imm = IMMService("p1", "ao-vsimm", load_imm_config(None), service_id="imm", **common)
    local = LocalFilterService("p1", "decentralized", VdieLocalFilter(1, FusionConfig()), 0.5, service_id="p1",
                               **common)
    return Bus([imm, local]), imm, local


def outputs_of(bus: Bus) -> dict[str, dict[int, np.ndarray]]:
    """Each tracker's position estimates by scan."""
    out: dict[str, dict[int, np.ndarray]] = {"imm": {}, "local": {}}
    for key, msg in bus.published:
        if isinstance(msg, (FusedTrack, LocalEstimate)):
            out["imm" if isinstance(msg, FusedTrack) else "local"][msg.seq] = np.asarray(msg.x)[[0, 2]]
    return out


def test_a_position_beyond_the_resolution_of_its_noise_is_refused() -> None:
    """One measurement at 1e100 m with a 1 m² noise (valid numbers each) wrecked the IMM tracker and
    the local filter for good: 23 scans later their estimates were still 1e95-1e98 m off and the IMM
    dropped every other scan as numerical. Its noise is below the float64 spacing of its own value
    (about 1e84 m there): such a measurement is refused at decoding, and the trackers go on as if it
    had been lost (within metres of the clean run's estimates 5 scans later)."""
    stream = position_stream()
    clean_bus, _, _ = position_trackers()
    for m in stream:
        clean_bus.put(KEYS.sensor_meas("p1"), encode(m))
    bus, imm, local = position_trackers()
    genuine = stream[10]
    payload = encode(Measurement.unchecked(sensor="p1", seq=10, t=genuine.t, kind="position",
                                           z=np.array([1e100, -1e100]), R=np.eye(2), stamp_ns=11))
    with pytest.raises(WireError, match=r"Measurement\.R: noise std 1 below the float64 resolution"):
        decode(payload, Measurement)
    for k, m in enumerate(stream):
        bus.put(KEYS.sensor_meas("p1"), payload if k == 10 else encode(m))
    assert imm.counters["rejected"] == local.counters["rejected"] == 1
    assert "rejected_numerical" not in imm.counters and "rejected_numerical" not in local.counters
    clean, got = outputs_of(clean_bus), outputs_of(bus)
    for name in ("imm", "local"):
        assert sorted(got[name]) == [k for k in sorted(clean[name]) if k != 10]
        assert max(np.linalg.norm(got[name][k] - clean[name][k]) for k in range(15, len(stream))) < 20.0


def test_a_scan_whose_tracks_no_receiver_takes_is_dropped_where_it_is_tracked(tmp_path: Path) -> None:
    """A scan with a noise of 1e-20 m² (resolvable at its 5 km positions) made the local tracker's
    updated tracks so ill-conditioned (position variance 1e-20 m² beside velocity variances of
    hundreds) that the centre refused the report as not positive definite: the federated tracker
    then waited for resets that never came, and held every later scan. Now the tracker checks its
    report as a receiver would before it publishes it: the scan is dropped there (``numerical``),
    its state as before it, and the reports go on."""
    services = mtt_services(tmp_path)
    bus = Bus(list(services.values()))
    lines = mtt_lines(tmp_path)
    target = next(i for i, m in enumerate(lines) if i >= 8 and m.sensor == "s1")
    for i, m in enumerate(lines):
        bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, R=np.eye(2) * 1e-20) if i == target else m))
    s1, centre = services["s1"], services["centre"]
    assert centre.counters["rejected"] == 0 and s1.counters["rejected_numerical"] == 1
    assert s1.awaiting is None and not s1.queue
    assert s1.counters["reports"] == sum(m.sensor == "s1" for m in lines) - 1


def test_a_detection_past_the_earths_limb_leaves_every_picture_readable(tmp_path: Path) -> None:
    """With ``[frame]`` a centre's pictures carry each track's latitude and longitude (``lla``). A sensor
    adding one detection 8,000 km out to its scans (its own key) started a track past the ellipsoid's limb,
    whose 2-D place on the Earth was NaN: every picture holding it (7 of 11) was refused by every receiver,
    the recorder here (``TrackPicture.lla: contains NaN or infinity``; the launcher and ``serve picture``
    alike). Such a track is now placed at the limb: every picture is recorded."""
    cfg = MttConfig(sensors=("s1", "s2", "s3"), max_lag=3.0, clutter_density=2.0 / 5000.0**2)
    common: dict[str, Any] = {"options": OPTIONS, "deployment": KEYS.deployment}
    centre = MttCentreService("mtt-centralized", cfg, 4, frame=Frame(48.0, 11.0, 0.0), service_id="centre", **common)
    recorder = Recorder(tmp_path / "r.db", service_id="rec", **common)
    recorder.on_start()
    bus = Bus([centre, recorder])
    far = Detection(np.array([8e6, 0.0]), 1.0)
    for m in mtt_lines(tmp_path):
        bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, detections=(*m.detections, far)) if m.sensor == "s1"
                                                    and m.t > 4.0 else m))
    pictures = bus.of(TrackPicture)
    assert len(pictures) > 5 and any(np.abs(p.x[:, 0]).max() > 7e6 for p in pictures)
    assert recorder.counters["rejected"] == 0
    assert all(decode(payload, TrackPicture) for p in pictures for payload in payloads(p))


# ---------------------------------------------------------------- many sensor ids

def one_track_report(sensor: str, seq: int) -> TrackReport:
    """A report of one confirmed local track at the same place for every sensor."""
    x = np.array([[100.0 + 10.0 * seq, 10.0, 200.0, 0.0]])
    return TrackReport(sensor=sensor, seq=seq, t=float(seq), ids=(1,), x=x, P=np.diag([100.0, 25.0, 100.0, 25.0]),
                       confirmed=(True,), detected=(True,), obs_H=np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]),
                       obs_R=np.eye(2) * 100.0, obs_z=x[:, [0, 2]], started=(seq == 0,), retired=(), stamp_ns=1)


def test_more_live_sensors_than_a_picture_can_list_are_refused() -> None:
    """With ``[mtt] sensors = "any"``, 70 sensor ids reporting one target made its central track list
    70 sensors, beyond the 64 (MAX_LIST_ITEMS) a picture's track may list: every receiver (the
    recorder, ``serve picture``, the launcher) refused every picture; and each id raised every
    tracker's sharing factor. A centre takes at most MAX_LIST_ITEMS live sensors: a report of
    another is rejected (``too_many_sensors``) until one of them leaves."""
    svc = MttCentreService("mtt-federated", MttConfig(sensors="any", max_lag=3.0), 4, service_id="centre",
                           options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    n = MAX_LIST_ITEMS + 6
    for k in range(3):
        for i in range(n):
            bus.put(KEYS.mtt_report(f"f{i}"), encode(one_track_report(f"f{i}", k)))
    pictures = bus.of(TrackPicture)
    assert len(pictures) == 2 and all(len(p.ids) == 1 and len(p.sensors[0]) == MAX_LIST_ITEMS for p in pictures)
    for p in pictures:
        for payload in payloads(p):
            decode(payload, TrackPicture)  # every receiver takes it
    assert svc.counters["rejected_too_many_sensors"] == 3 * 6
    assert {r.q_scale for _, r in bus.published if isinstance(r, TrackResets)} <= {float(s) for s in range(1, 65)}


def test_the_live_centre_does_not_fuse_a_copied_feed(caplog: pytest.LogCaptureFixture) -> None:
    """s1's reports published again as s9's (a feed copied under a second id) beside an honest s2 at
    the same times: the centre fused s9 as a third independent sensor (every sharing factor 3). Now s9
    is found at its third report: logged once, that report and the later ones counted
    ``centre_copies``, answered without resets and with a factor of 1, and s1 and s2 shares of 2 again."""
    svc = MttCentreService("mtt-federated", MttConfig(sensors="any", max_lag=3.0), 4, service_id="centre",
                           options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    with caplog.at_level("WARNING"):
        for k in range(6):
            report = one_track_report("s1", k)
            bus.put(KEYS.mtt_report("s1"), encode(report))
            bus.put(KEYS.mtt_report("s9"), encode(replace(report, sensor="s9")))
            bus.put(KEYS.mtt_report("s2"), encode(replace(report, sensor="s2", obs_z=report.obs_z + 3.0)))
    counts = svc.engine.counters()  # Health's, as of the latest picture (t = 5): s9's reports at 2, 3 and 4
    assert counts["centre_copies"] == 4 and counts["centre_copying_sensors"] == 1 and svc.counters["centre_copies"] == 3
    answers = [r for _, r in bus.published if isinstance(r, TrackResets)]
    resets = {s: [r for r in answers if r.sensor == s] for s in ("s1", "s2", "s9")}
    assert [(len(r.ids), r.q_scale) for r in resets["s9"][2:]] == [(0, 1.0)] * 4
    assert resets["s2"][-1].q_scale == 2.0 and len(resets["s2"][-1].ids) == 1
    assert [r.getMessage() for r in caplog.records if "feed" in r.getMessage()] == [
        "sensor s9 copies s1's feed at t=2.00 (the same observations at the same times): its reports are not fused"]


def test_a_tracker_restart_keeps_the_copied_feed_check() -> None:
    """A restart (``TrackReport.first``) is the tracker's; the sensor and its data are the same. It
    emptied the copied-feed check's evidence of the sensor (tour47 session): s9, copying s1 and marking
    every report ``first``, was never found (0 of its 12 reports left out, s2's factor 3: s1's data
    fused twice); and s1's one honest restart at t = 6 made s9 the sensor heard from longer, so that
    s1 was taken for the copy at t = 8 and its reports were not fused, s9's in their stead. A report
    marked ``first`` is a restart where a fresh tracker could have sent it (its track started by the
    scan): so s9's and s1's here."""
    for cheat in (True, False):
        svc = MttCentreService("mtt-federated", MttConfig(sensors="any", max_lag=3.0), 4, service_id="centre",
                               options=OPTIONS, deployment=KEYS.deployment)
        bus = Bus([svc])
        for k in range(12):
            report = one_track_report("s1", k)
            restart = replace(report, first=True, started=(True,))
            bus.put(KEYS.mtt_report("s1"), encode(restart if not cheat and k == 6 else report))
            bus.put(KEYS.mtt_report("s9"), encode(replace(restart if cheat else report, sensor="s9")))
            bus.put(KEYS.mtt_report("s2"), encode(replace(report, sensor="s2", obs_z=report.obs_z + 3.0)))
        assert svc.counters["trackers_restarted"] == (11 if cheat else 1)
        assert svc.engine.centre.copies.copy_of == {"s9": "s1"}
        answers = [(r.sensor, len(r.ids), r.q_scale) for _, r in bus.published if isinstance(r, TrackResets)]
        assert answers[-3:] == [("s1", 1, 2.0), ("s9", 0, 1.0), ("s2", 1, 2.0)]


# ---------------------------------------------------------------- serve picture

def region_picture(t: float, fused: int, tracks: int = 0) -> TrackPicture:
    """A region's picture at ``t`` listing ``fused`` scans of ``s1`` and ``tracks`` tracks."""
    x = np.zeros((tracks, 4))
    return TrackPicture(seq=0, t=t, ids=tuple(range(tracks)), x=x, P=np.tile(np.eye(4), (tracks, 1)),
                        confirmed=(True,) * tracks, sensors=(("s1",),) * tracks, fused_sensors=("s1",) * fused,
                        fused_seqs=tuple(range(fused)), left=(), stamp_ns=1, closing=False)


def test_the_merger_outlives_region_pictures_it_cannot_merge(tmp_path: Path) -> None:
    """Three late region pictures, each valid (49,152 fused entries in 24 parts), made every later
    merged picture carry more entries than one message in MAX_PARTS parts can: publishing failed,
    the merger's state was put back, and ``serve picture`` never published again. The entries of
    late pictures are now dropped (counted ``late_dropped``) when the merged picture would not fit,
    and a region picture holding more tracks or entries than its share of one merged picture
    (MAX_PARTS x MAX_TRACKS / regions) is rejected (``too_large``)."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None and len(regions.ids) == 2
    # the late times on its grid
    svc = PictureMergeService(regions, 4, 2.0, 0.25, service_id="picture", options=OPTIONS,
                              deployment=KEYS.deployment)
    svc._subscriptions = svc.subscriptions()
    merged: list[TrackPicture] = []
    svc.publish = lambda key, msg: (payloads(msg), merged.append(msg))  # type: ignore[method-assign]

    def send(r: int, msg: TrackPicture) -> None:
        for payload in payloads(msg):
            svc._dispatch(("sample", r, KEYS.region_picture(regions.ids[r]), payload))

    share = MAX_PARTS * MAX_TRACKS // 2
    send(0, region_picture(0.0, 1))
    send(1, region_picture(0.0, 1))
    svc.wait_s = 0.0  # t = 1 merged without region 1, which is behind
    send(0, region_picture(1.0, 1))
    svc.wait_s = 2.0
    late = share * 3 // 4
    for t in (0.25, 0.5, 1.0):  # region 1's next pictures, late: after t = 1 was merged
        send(1, region_picture(t, late))
    for k in range(2, 5):
        send(0, region_picture(float(k), 1))
        send(1, region_picture(float(k), 1))
    assert [p.t for p in merged] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert svc.counters["late_picture"] == 3 and svc.counters["late_dropped"] == 3 * late
    assert len(merged[2].fused_sensors) == 2 and "rejected_handler_error" not in svc.counters
    send(1, region_picture(5.0, share + 1))
    assert svc.counters["rejected_too_large"] == 1


# ---------------------------------------------------------------- hand-overs

def region_centre(tmp_path: Path) -> tuple[Bus, MttCentreService, MttConfig]:
    """The (decentralized) centre of region ``x0y0`` of two."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    cfg = MttConfig(sensors=("s1", "s2", "s3"), max_lag=3.0)
    svc = MttCentreService("mtt-decentralized", cfg, 4, region="x0y0", regions=load_regions(config),
                           service_id="x0y0", options=OPTIONS, deployment=KEYS.deployment)
    return Bus([svc]), svc, cfg


def hand_over(svc: MttCentreService, cfg: MttConfig, serial: int, x: list[float], P: np.ndarray) -> HandOver:
    """Region ``x1y0``'s hand-over ``serial`` of central track 1: one ring entry at t = 0."""
    tracks = svc.engine.region.centre.tracks  # type: ignore[union-attr]
    values = {"x": x, "P": P.ravel().tolist()}
    ring = [v for name in tracks._ring
            for v in values.get(name, [0.0] * int(np.prod(getattr(tracks, name).shape[2:], dtype=np.int64)))]
    return HandOver(source="x1y0", serial=serial, id=1, confirmed=True, ring=np.array([ring]), neg_inf=(), sensors=(),
                    support=(), streak=(), window=(True,) * cfg.confirm_window, last_support=0.0, member_sensors=(),
                    member_ids=(), strikes=())


def test_a_hand_over_with_an_indefinite_covariance_is_refused(tmp_path: Path) -> None:
    """A region centre took over a track whose ring held a negative variance (the wire checks a
    ring only as numbers): its next picture was refused by every receiver (not positive definite).
    Each covariance of a ring is now checked as the wire checks any covariance: the hand-over is
    rejected (``wrong_model``) and the pictures go on."""
    bus, svc, cfg = region_centre(tmp_path)
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(hand_over(svc, cfg, 0, [-2000.0, 10.0, 0.0, 0.0],
                                                          np.diag([-1.0, 1.0, 1.0, 1.0]))))
    assert svc.counters["rejected_wrong_model"] == 1 and "taken_over" not in svc.counters
    for k in range(1, 5):
        bus.put(KEYS.region_report("x0y0", "s1"), encode(replace(one_track_report("s1", k), x=np.array(
            [[-2000.0 + 10.0 * k, 10.0, 0.0, 0.0]]), obs_z=np.array([[-2000.0 + 10.0 * k, 0.0]]))))
    pictures = bus.of(TrackPicture)
    assert len(pictures) == 3 and "rejected_numerical" not in svc.counters
    for p in pictures:
        for payload in payloads(p):
            decode(payload, TrackPicture)


def test_a_second_different_hand_over_with_a_number_taken_is_contested(tmp_path: Path) -> None:
    """A hand-over is known by its sender and number: a second one with the same pair was counted a
    ``duplicate`` and dropped however it differed, so a forgery sent first made the genuine hand-over
    vanish without a trace. A different one is now a conflict: rejected, the next picture contested."""
    bus, svc, cfg = region_centre(tmp_path)
    P = np.diag([100.0, 25.0, 100.0, 25.0])
    first = hand_over(svc, cfg, 7, [-2000.0, 10.0, 0.0, 0.0], P)
    for msg in (first, first, hand_over(svc, cfg, 7, [-1500.0, 10.0, 0.0, 0.0], P)):
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(msg))
    assert svc.counters["taken_over"] == 1 and svc.counters["duplicate"] == 1
    assert svc.counters["rejected_conflict"] == 1 and svc.counters["contested"] == 1
    for k in (2, 3, 4):
        bus.put(KEYS.region_report("x0y0", "s1"), encode(one_track_report("s1", k)))
    assert [p.contested for p in bus.of(TrackPicture)] == [True, False]


# ---------------------------------------------------------------- the 3-D radar local filter

@pytest.mark.parametrize("algorithm", ["ekf", "ekf-ie"])
def test_the_radar_local_filter_survives_its_measurements(algorithm: str) -> None:
    """``serve local-filter --filter ekf|ekf-ie|ekf-tsfuzzy`` died (exit 1) on its first measurement,
    any measurement: its filter held lambdas, so the checkpoint every handler takes before it runs
    (a pickle of the state) raised outside the handler. Its functions are now named ones; a
    measurement it cannot use (zero or negative range) is rejected and the filter goes on."""
    svc = RadarLocalFilterService("r1", make_radar_filter(algorithm), service_id="r1", options=OPTIONS,
                                  deployment=KEYS.deployment)
    bus = Bus([svc])
    for k in range(8):
        z = np.array([5000.0 + 50.0 * k, 0.3 + 0.001 * k, 0.05])
        meas = Measurement(sensor="r1", seq=k, t=float(k), kind="radar", z=z, R=np.diag([100.0, 1e-6, 1e-6]),
                           sensor_position=np.zeros(3), stamp_ns=1)
        bus.put(KEYS.sensor_meas("r1"), encode(meas))
        if k == 4:  # a second message for scan 4 (late) and one at zero range for scan 5 (rejected)
            bus.put(KEYS.sensor_meas("r1"), encode(replace(meas, z=z * np.array([-1.0, 1.0, 1.0]))))
            bus.put(KEYS.sensor_meas("r1"), encode(replace(meas, seq=5, t=4.5, z=np.array([0.0, 0.3, 0.05]))))
    estimates = bus.of(LocalEstimate)
    assert [e.seq for e in estimates] == [1, 2, 3, 4, 5, 6, 7]
    assert svc.counters["late"] == 1 and svc.counters["rejected_input"] == 1
    assert svc.counters["rejected"] == 1  # counted as every rejection is (it was rejected_input alone)
    assert np.linalg.norm(estimates[-1].x[[0, 2]] - 5350.0 * np.array([np.cos(0.307), np.sin(0.307)])) < 50.0


def test_a_state_that_cannot_be_checkpointed_is_a_rejection_not_the_end() -> None:
    """The checkpoint a handler takes before it runs is outside the handler: what it raised went up
    through the worker loop and ended the service. Whatever escapes a handler's transaction is now
    a rejection (``handler_error``, logged with its place); the worker loop guards ``on_tick`` the
    same way (not exercised here: it needs a session)."""
    svc = IMMService("p1", "ao-vsimm", load_imm_config(None), service_id="imm", options=OPTIONS,
                     deployment=KEYS.deployment)
    bus = Bus([svc])
    svc.spoilt = lambda: None  # type: ignore[attr-defined]  # a lambda: pickle refuses it
    svc.state_attrs = (*svc.state_attrs, "spoilt")  # type: ignore[misc]
    for m in position_stream()[:3]:
        bus.put(KEYS.sensor_meas("p1"), encode(m))
    assert svc.counters["rejected_handler_error"] == 3 and not bus.published


def test_the_hand_overs_a_centre_remembers_are_bounded(tmp_path: Path) -> None:
    """A region centre kept every hand-over's (source, number) it ever took, and pickled them with
    every message it handled (100,000 of them: 56 ms a message); any source name was taken. It keeps
    the last HANDOVERS_KEPT of each region of ``[regions]``: an older one is late; a source that is
    not another region is rejected (``unknown_region``)."""
    bus, svc, cfg = region_centre(tmp_path)
    P = np.diag([100.0, 25.0, 100.0, 25.0])
    n = HANDOVERS_KEPT + 6
    for serial in range(n):
        msg = replace(hand_over(svc, cfg, serial, [-4000.0 + 40.0 * serial, 10.0, 0.0, 0.0], P), id=2 * serial + 1)
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(msg))
    assert svc.counters["taken_over"] == n and sorted(svc.taken["x1y0"]) == list(range(6, n))
    bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(replace(hand_over(svc, cfg, 2, [0.0] * 4, P), id=999)))
    assert svc.counters["late"] == 1 and svc.counters["taken_over"] == n
    for source in ("x0y0", "elsewhere"):
        msg = replace(hand_over(svc, cfg, n, [0.0] * 4, P), source=source)
        bus.put(KEYS.region_handover("x0y0", source), encode(msg))
    assert svc.counters["rejected_unknown_region"] == 2


def test_a_hand_over_naming_more_sensors_than_a_picture_lists_is_refused(tmp_path: Path) -> None:
    """A hand-over may name up to 2048 sensors: one naming 70 made the track list 71 sensors in
    every later picture of the region, which every receiver refused (at most 64, MAX_LIST_ITEMS).
    A hand-over naming more than 64 sensors, or one ``[mtt] sensors`` does not allow, is rejected
    (``wrong_model``)."""
    bus, svc, cfg = region_centre(tmp_path)
    P = np.diag([100.0, 25.0, 100.0, 25.0])
    named = tuple(f"z{i}" for i in range(MAX_LIST_ITEMS + 6))
    many = replace(hand_over(svc, cfg, 0, [-2000.0, 10.0, 0.0, 0.0], P), sensors=named, support=(1,) * len(named),
                   streak=(0,) * len(named), member_sensors=named, member_ids=tuple(range(len(named))),
                   strikes=(0,) * len(named))
    stranger = replace(hand_over(svc, cfg, 1, [-2000.0, 10.0, 0.0, 0.0], P), sensors=("z1",), support=(1,),
                       streak=(0,))
    for msg in (many, stranger):
        bus.put(KEYS.region_handover("x0y0", "x1y0"), encode(msg))
    assert svc.counters["rejected_wrong_model"] == 2 and "taken_over" not in svc.counters


def empty_report(sensor: str, seq: int, t: float) -> TrackReport:
    return TrackReport(sensor=sensor, seq=seq, t=t, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(),
                       detected=(), obs_H=np.zeros((0, 4)), obs_R=np.zeros((0, 2)), obs_z=np.zeros((0, 2)),
                       started=(), retired=(), stamp_ns=1)


def test_reports_microseconds_apart_cannot_overfill_a_picture(monkeypatch: Any) -> None:
    """A picture lists every report taken since the previous one: 131,073 reports within one picture
    period (a tracker numbering them microseconds apart) made it unpublishable (more than MAX_PARTS
    messages), and every report after them was rejected with it, for good. A centre takes at most
    PICTURE_ITEMS - MAX_LIST_ITEMS entries between two pictures (164 - 64 here, for speed): more are
    rejected (``too_large``) and the pictures go on."""
    monkeypatch.setattr(centre_service_module, "PICTURE_ITEMS", 164)
    svc = MttCentreService("mtt-decentralized", MttConfig(sensors=("s1",), max_lag=3.0), 4, service_id="centre",
                           options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    for k in range(130):
        bus.put(KEYS.mtt_report("s1"), encode(empty_report("s1", k, 0.5 + 1e-6 * k)))
    assert svc.counters["rejected_too_large"] == 30
    for k in range(130, 133):
        bus.put(KEYS.mtt_report("s1"), encode(empty_report("s1", k, float(k - 129))))
    assert [len(p.fused_seqs) for p in bus.of(TrackPicture)] == [100, 1]  # at t = 1 and 2


# ---------------------------------------------------------------- round 3: values at the wire's edge

def huge_track_report(sensor: str, seq: int, scale: float) -> TrackReport:
    """A report of one confirmed track whose state and covariance are at ``scale``: each value
    within the wire's +-1e100, resolvable (a position of ``scale`` with a std of sqrt(1e100))."""
    x = np.array([[scale, scale, scale, scale]])
    return replace(one_track_report(sensor, seq), t=seq + 0.5, ids=(2,), x=x, P=np.eye(4) * 1e100,
                   obs_z=x[:, [0, 2]], obs_R=np.eye(2) * 1e100, started=(seq == 0,))


def test_a_report_at_the_wires_edge_cannot_make_pictures_nobody_takes() -> None:
    """A sensor's report of a track at 1e50 m with a covariance of 1e100 (each value valid on the
    wire) made the centre's pictures, predicted from it, carry variances beyond 1e100: every
    receiver (the recorder, ``serve picture``, the launcher) refused every picture while the track
    lived (a sensor sending it with every scan silenced the picture stream; the federated centre
    failed on its resets instead, ``numerical``). A report whose states or covariances could leave
    the wire's range when predicted over the centre's horizon is now rejected (``scale``) and the
    pictures go on."""
    svc = MttCentreService("mtt-decentralized", MttConfig(sensors=("s1", "s2"), max_lag=3.0), 4, service_id="centre",
                           options=OPTIONS, deployment=KEYS.deployment)
    bus = Bus([svc])
    for k in range(6):
        bus.put(KEYS.mtt_report("s1"), encode(one_track_report("s1", k)))
        bus.put(KEYS.mtt_report("s2"), encode(huge_track_report("s2", k, 1e50) if k >= 2 else one_track_report("s2", k)))
    pictures = bus.of(TrackPicture)
    assert [p.t for p in pictures] == [0.0, 1.0, 2.0, 3.0, 4.0]
    for p in pictures:
        for payload in payloads(p):
            decode(payload, TrackPicture)  # every receiver takes it
    assert svc.counters["rejected_scale"] == 4


def test_the_merger_refuses_a_region_picture_of_another_state_size(tmp_path: Path) -> None:
    """A region picture of 6-D tracks at a 2-D merger (or with an existence column the other regions'
    pictures lack) waited for the other region's picture of its time, whose merge then failed: the
    genuine picture was rejected as a ``handler_error`` (a region sending such pictures every period
    had every other region's pictures dropped). The state size is now checked on arrival
    (``wrong_model``) and a region picture without existence merges beside one with it."""
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None
    svc = PictureMergeService(regions, 4, 2.0, 1.0, service_id="picture", options=OPTIONS,
                              deployment=KEYS.deployment)
    bus = Bus([svc])

    def picture(t: float, ids: tuple[int, ...], d: int = 4, existence: bool = False) -> TrackPicture:
        n = len(ids)
        return TrackPicture(seq=0, t=t, ids=ids, x=np.zeros((n, d)), P=np.tile(np.eye(d), (n, 1)),
                            confirmed=(True,) * n, sensors=(("s1",),) * n, fused_sensors=("s1",), fused_seqs=(0,),
                            left=(), stamp_ns=1, closing=False, existence=np.full(n, 0.5) if existence else None)

    bus.put(KEYS.region_picture("x0y0"), encode(picture(0.0, (0, 2), d=6)))
    bus.put(KEYS.region_picture("x0y0"), encode(picture(0.0, (0, 2), existence=True)))
    bus.put(KEYS.region_picture("x1y0"), encode(picture(0.0, (1, 3))))
    merged = bus.of(TrackPicture)
    assert svc.counters["rejected_wrong_model"] == 1 and "rejected_handler_error" not in svc.counters
    assert len(merged) == 1 and merged[0].ids == (0, 1, 2, 3)
    assert merged[0].existence is not None and merged[0].existence.tolist() == [0.5, 1.0, 0.5, 1.0]


# ---------------------------------------------------------------- round 3: one identity flooding

def test_a_flooding_stream_neither_starves_the_others_nor_fills_memory() -> None:
    """Every service took its input in one FIFO of 10,000 messages, whatever their size: one sensor
    identity sending valid 2,048-track reports (about 50 ms of work each at the centre) as fast as
    the wire takes them queued 10,000 of them (8 minutes of work, 5 GiB of payloads; 20 GiB of
    2 MiB ones) ahead of every other sensor's, whose reports then came minutes late. The inbox now
    serves its streams (key expressions) in turn and holds at most MAX_QUEUED_BYTES of payloads
    (the callback waits beyond, as it did beyond 10,000 messages): another stream's message is
    taken within one turn of the flood."""
    from fedtrack.services.inbox import MAX_QUEUED_BYTES, Inbox

    inbox = Inbox(10_000, MAX_QUEUED_BYTES)
    big = b"x" * (2 * 1024 * 1024)
    held = 0
    while inbox.put(("sample", 0, "fedtrack/d/local/s1/tracks", big), timeout=0.0):
        held += 1
    assert held == MAX_QUEUED_BYTES // len(big)  # then the Zenoh callback waits: 128 MiB, not 20 GiB
    assert inbox.put(("sample", 0, "fedtrack/d/local/s2/tracks", b"genuine"), timeout=0.0) is False
    inbox.get(timeout=0.0)  # the worker takes one flood message: room for one more
    assert inbox.put(("sample", 0, "fedtrack/d/local/s2/tracks", b"genuine"), timeout=0.0)
    taken = [inbox.get(timeout=0.0)[2] for _ in range(2)]
    assert "fedtrack/d/local/s2/tracks" in taken  # served within one turn, not after the 63 queued floods
    order = []
    small = Inbox(100, MAX_QUEUED_BYTES)
    for k in range(3):
        small.put(("sample", 0, "a", bytes([k])), timeout=0.0)
    small.put(("sample", 0, "b", b"b"), timeout=0.0)
    while small.qsize():
        order.append(small.get(timeout=0.0)[3])
    assert order == [b"\x00", b"b", b"\x01", b"\x02"]  # each stream in its own order, the streams in turn


def test_a_flood_that_fills_the_inbox_is_counted_in_health() -> None:
    """A flood that fills a service's inbox holds its Zenoh callback, and with it everything the
    session receives, until the worker makes room (and an authenticated router cuts a reader that
    long behind: docs/deploy.md): nothing in Health said so. Each sample or query whose callback
    found the inbox full is counted ``inbox_full``; what waited is taken once there is room."""
    import threading

    from fedtrack.services.inbox import Inbox

    svc = MttCentreService("mtt-federated", MttConfig(sensors="any"), 4, service_id="centre", options=OPTIONS,
                           deployment=KEYS.deployment)
    svc._queue = Inbox(2)
    for k in range(2):
        svc._enqueue(("sample", 0, KEYS.mtt_report("s1"), bytes([k])))
    assert "inbox_full" not in svc._health().counters
    waiting = threading.Thread(target=svc._enqueue, args=(("sample", 0, KEYS.mtt_report("s2"), b"genuine"),))
    waiting.start()
    waiting.join(0.3)
    assert waiting.is_alive()  # the callback waits for room
    svc._queue.get(timeout=0.0)
    waiting.join(5.0)
    assert not waiting.is_alive() and svc._health().counters["inbox_full"] == 1
    assert sorted(svc._queue.get(timeout=0.0)[3] for _ in range(2)) == [b"\x01", b"genuine"]


# ---------------------------------------------------------------- crowds of detections

@pytest.mark.parametrize("radar", [False, True])
@pytest.mark.parametrize("role", ["mtt-local", "mtt-centralized"])
def test_a_crowd_of_detections_on_its_own_tracks_is_refused_before_its_pairs_are_made(
        monkeypatch: Any, role: str, radar: bool) -> None:
    """A sensor's scans of detections equal up to round-off (each distinct, so ``scan.distinct``
    keeps them), the second on the tracks the first started: every track gates every detection,
    n² pairs (2,048 in one message: 4.2 million, 1.5-2 s and 840 MB a scan; 4,096 in two parts:
    27 s and 4.7 GB for three scans; 131,072 would need terabytes). Beyond ``MAX_GATED_PAIRS``
    (2^20; 5,000 here, for speed), counted by the k-d tree before any pair is made, the scan is
    refused ``crowded`` and the tracker put back; the next honest scan is tracked. A radar's scan
    (range, azimuth, elevation) too: before attacks10 it kept every (track, detection) pair, its
    azimuth wrapping (2,048: 21 s and 880 MB a scan at ``mtt-local`` with gnn, 215 s and 1.7 GB
    with jipda, over 400 s with mht). 0.1 s each."""
    monkeypatch.setattr(gating, "MAX_GATED_PAIRS", 5000)
    if radar:  # ranges equal up to round-off, 30 km away; the honest scan's plot elsewhere
        crowd = np.array([30000.0, 0.3, 0.05]) + np.arange(100)[:, None] * [np.spacing(30000.0), 0.0, 0.0]
        honest, R, where = np.array([[20000.0, -1.0, 0.1]]), np.diag([100.0, 1e-4, 1e-4]), np.zeros(3)
    else:
        crowd = np.array([1000.0, 2000.0]) + np.arange(100)[:, None] * np.spacing(2000.0)
        honest, R, where = np.array([[5000.0, 0.0]]), None, None
    if role == "mtt-local":
        bus, svc = mtt_local(federated=False)
    else:
        svc = MttCentreService("mtt-centralized", MttConfig(sensors=("s1",), max_lag=3.0, clutter_density=1e-7),
                               6 if radar else 4, service_id="centre", options=OPTIONS, deployment=KEYS.deployment)
        bus = Bus([svc])
    for k, z in enumerate([crowd, crowd, honest]):
        bus.put(KEYS.sensor_meas("s1"), encode(replace(scan("s1", k, float(k), z, R), sensor_position=where)))
    assert svc.counters.get("rejected_crowded") == 1 and svc.counters["rejected"] == 1
    assert "rejected_handler_error" not in svc.counters
    if role == "mtt-local":  # scans 0 and 2 tracked
        assert svc.counters["reports"] == 2
        assert len(svc.tracker.tracker.state.tracks.ids) == 101  # type: ignore[union-attr]
