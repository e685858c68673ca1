"""``serve picture`` and the region centres' tokens (``alive/mtt-region/<rid>/<instance>``): a region
with no live centre (its centre and standby dead, or none started) is not waited for; a live one that
is late still is. In-process on the bus of ``test_hostile_messages`` (the tokens given by hand), and
over a loopback Zenoh router with a real region centre's token (about 3 s)."""

from __future__ import annotations

import threading
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

from support import free_port, wait_until
from test_hostile_messages import KEYS, OPTIONS, Bus
from test_hostile_sequences import region_picture
from test_mtt_regions_live import CONFIG as REGIONS_CONFIG

from fedtrack.fusion_center.mtt import picture_merge
from fedtrack.fusion_center.mtt.picture_merge import PictureMergeService
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.wire import TrackPicture, decode, encode
from fedtrack.zsession import SessionOptions, close_session, open_session


def regions_of(tmp_path: Path) -> Regions:
    config = tmp_path / "regions.toml"
    config.write_text(REGIONS_CONFIG)
    regions = load_regions(config)
    assert regions is not None and regions.ids == ("x0y0", "x1y0")
    return regions


def test_a_region_without_a_live_centre_is_not_waited_for(tmp_path: Path) -> None:
    """Region x1y0 has no centre: x0y0's picture of t = 0 is merged at once (before: after the whole
    ``--wait``, 60 s here), its merged picture naming x1y0 ``missing``, counted ``no_centre``, not
    contested (x1y0 never sent one). x1y0's centre starts: t = 1 waits for its picture. It dies: t = 2
    is merged at once again, contested (x1y0 had sent pictures). After this merger's own link to the
    router came back, a region whose token is not back yet is waited for (its token went with the link);
    so is a region that publishes while none of its tokens shows, until one does."""
    merger = PictureMergeService(regions_of(tmp_path), 4, 60.0, 1.0, service_id="picture", options=OPTIONS,
                                 deployment=KEYS.deployment)
    bus = Bus([merger])
    merger.token_watches()
    a, b = KEYS.region_picture("x0y0"), KEYS.region_picture("x1y0")
    token_a, token_b = KEYS.region_centre("x0y0", "a1"), KEYS.region_centre("x1y0", "b1")
    merger._on_centre(token_a, True)
    merger._on_centre(KEYS.region_centre("elsewhere", "c1"), True)  # no region of the config: changes nothing
    bus.put(a, encode(region_picture(0.0, (0,))))
    merged = bus.of(TrackPicture)
    assert [(p.t, p.ids, p.missing, p.contested) for p in merged] == [(0.0, (0,), ("x1y0",), False)]
    assert merger.counters["no_centre"] == 1 and merger.counters["missing_region"] == 1
    merger._on_centre(token_b, True)  # x1y0's centre is up: its picture is waited for
    bus.put(a, encode(region_picture(1.0, (0,))))
    merger.on_tick()
    assert len(bus.of(TrackPicture)) == 1
    bus.put(b, encode(region_picture(1.0, (1,))))
    assert [(p.t, p.ids, p.missing) for p in bus.of(TrackPicture)[1:]] == [(1.0, (0, 1), ())]
    merger._on_centre(token_b, False)  # x1y0's centre (and standby) died
    bus.put(a, encode(region_picture(2.0, (0,))))
    assert [(p.t, p.missing, p.contested) for p in bus.of(TrackPicture)[2:]] == [(2.0, ("x1y0",), True)]
    merger._router_back_at = time.monotonic()  # this merger's link just came back: x1y0's token may follow
    bus.put(a, encode(region_picture(3.0, (0,))))
    merger.on_tick()
    assert len(bus.of(TrackPicture)) == 3 and merger.counters["no_centre"] == 2
    merger._on_centre(token_a, False)
    merger._on_centre(token_a, True)  # x0y0's own token does not stand for x1y0's
    merger._router_back_at -= 60.0  # LINK_GRACE_S after the return: x1y0's token did not come back
    merger.on_tick()
    assert [(p.t, p.missing) for p in bus.of(TrackPicture)[3:]] == [(3.0, ("x1y0",))]
    # x1y0 publishes while none of its tokens shows (an access control that drops them): waited for again
    bus.put(a, encode(region_picture(4.0, (0,))))
    bus.put(b, encode(region_picture(4.0, (1,))))  # late: t = 4 was merged without it
    bus.put(a, encode(region_picture(5.0, (0,))))
    merger.on_tick()
    assert [p.t for p in bus.of(TrackPicture)] == [0.0, 1.0, 2.0, 3.0, 4.0]
    merger._on_centre(token_b, True)  # its token shows, then goes: judged by it again
    merger.on_tick()
    merger._on_centre(token_b, False)
    merger.on_tick()
    assert [(p.t, p.missing) for p in bus.of(TrackPicture)[5:]] == [(5.0, ("x1y0",))]
    assert merger.counters["rejected"] == 0 and merger.counters["late_picture"] == 1


def test_a_flood_of_centre_tokens_is_followed_a_bounded_number(tmp_path: Path) -> None:
    """A region's identity (``region-<rid>``) may declare any ``alive/mtt-region/<rid>/*``, and the merger
    followed every one in one set rebound, a copy, at each token: 40,000 tokens of x0y0 declared by one
    session on a loopback router cost a live ``serve picture`` 77 s of CPU (the router 80 s; the session's
    declarations took 273 s), now 23 s (18 s; 58 s), the rest Zenoh's own work per token; 10,000 here held
    1.5 MB. It now follows at most ``CENTRE_TOKENS_KEPT`` of each region's and counts the rest
    (``tokens_ignored``): x0y0 stays covered, x1y0 is judged by its own token as before."""
    merger = PictureMergeService(regions_of(tmp_path), 4, 60.0, 1.0, service_id="picture", options=OPTIONS,
                                 deployment=KEYS.deployment)
    merger.token_watches()
    token_a, token_b = KEYS.region_centre("x0y0", "a1"), KEYS.region_centre("x1y0", "b1")
    merger._on_centre(token_a, True)
    merger._on_centre(token_b, True)
    n = 10_000
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for i in range(n):
        merger._on_centre(KEYS.region_centre("x0y0", f"forged{i}"), True)
    held = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert held < 100_000, f"{held} bytes held for {n} tokens"
    kept = getattr(picture_merge, "CENTRE_TOKENS_KEPT", 0)
    merger.on_tick()
    assert merger.counters["tokens_ignored"] == n + 1 - kept and not merger._uncovered(time.monotonic())
    for i in range(n):
        merger._on_centre(KEYS.region_centre("x0y0", f"forged{i}"), False)
    merger._on_centre(token_b, False)  # x1y0's centre died: not waited for; x0y0's genuine token stands
    assert merger._uncovered(time.monotonic()) == {1} and merger.counters["rejected"] == 0


def test_a_merged_picture_is_not_held_for_a_region_whose_centre_stopped_over_zenoh(tmp_path: Path) -> None:
    """Live, on a loopback router: region x1y0's centre runs (its token is the real one) but gets no
    reports; a test session publishes x0y0's pictures. Its picture of t = 0 waits the whole ``--wait``
    (1 s) for x1y0's, whose centre lives; x1y0's centre stops, its token goes, and the picture of t = 1
    is merged within 0.5 s, x1y0 ``missing`` (before: 1 s again)."""
    regions = regions_of(tmp_path)
    port = free_port()
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    opts = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=5.0)
    deployment = "centretokens"
    centre = MttCentreService("mtt-federated", MttConfig(sensors=("s1",)), 4, region="x1y0", regions=regions,
                              service_id="x1y0", options=opts, deployment=deployment)
    merger = PictureMergeService(regions, 4, 1.0, 1.0, service_id="picture", options=opts, deployment=deployment)
    threads = [threading.Thread(target=svc.run, daemon=True) for svc in (centre, merger)]
    session = None
    got: list[tuple[float, TrackPicture]] = []
    try:
        for th in threads:
            th.start()
        session = open_session(opts)
        keys = type(KEYS)(deployment)
        session.declare_subscriber(keys.mtt_picture(), lambda s: got.append(
            (time.monotonic(), decode(s.payload.to_bytes(), TrackPicture))))
        assert wait_until(lambda: merger.settle_until is None and merger.centres is not None
                          and len(merger.centres["x1y0"].present) == 1, timeout=10.0)
        pub = session.declare_publisher(keys.region_picture("x0y0"))
        delays = []
        for k in range(2):
            if k == 1:
                centre.stop()
                threads[0].join(10.0)
            sent = time.monotonic()
            pub.put(encode(region_picture(float(k), (0,))))
            assert wait_until(lambda: len(got) > k, timeout=5.0), k
            delays.append(got[k][0] - sent)
        assert delays[0] >= 0.9 and delays[1] < 0.5, delays
        assert [(p.t, p.ids, p.missing) for _, p in got] == [(0.0, (0,), ("x1y0",)), (1.0, (0,), ("x1y0",))]
        assert merger.counters.get("no_centre") == 1 and merger.counters["rejected"] == 0
    finally:
        centre.stop()
        merger.stop()
        for th in threads:
            th.join(10.0)
        for z in (session, router):
            if z is not None:
                close_session(z)


def test_a_region_centre_started_again_is_merged_after_its_former_ones_last_entries(tmp_path: Path) -> None:
    """x0y0's centre stops (its closing record lists the report it fused last) and a new process of
    it starts: the merged picture lists the former's last entry, then the new one's start (``began``,
    its first track id and hand-over number) and its entries, so that the recording replays them in
    that order. Before, the closing record's entries came at the end of the run, and a region picture
    listed no start. A region picture listing a start that is not its own first entry, or naming
    another region or an id outside its sequence, is refused (``wrong_region``)."""
    merger = PictureMergeService(regions_of(tmp_path), 4, 60.0, 1.0, service_id="picture", options=OPTIONS,
                                 deployment=KEYS.deployment)
    bus = Bus([merger])
    a, b = KEYS.region_picture("x0y0"), KEYS.region_picture("x1y0")
    for k in range(2):
        bus.put(a, encode(region_picture(float(k), (0,))))
        bus.put(b, encode(region_picture(float(k), (1,))))
    closing = replace(region_picture(1.5, ()), closing=True, fused_seqs=(7,))
    bus.put(a, encode(closing))
    fresh = replace(region_picture(2.0, (4098,)), fused_sensors=("x0y0", "s1"), fused_seqs=(4098, 8), began=(0,),
                    began_serials=(2049,))
    bus.put(a, encode(fresh))
    bus.put(b, encode(region_picture(2.0, (1,))))
    last = bus.of(TrackPicture)[-1]
    assert last.t == 2.0 and list(zip(last.fused_sensors, last.fused_seqs, last.regions)) == [
        ("s1", 7, "x0y0"), ("x0y0", 4098, "x0y0"), ("s1", 8, "x0y0"), ("s1", 2, "x1y0")]
    assert (last.began, last.began_serials) == ((1,), (2049,))
    for bad in (replace(fresh, t=3.0, began=(1,)), replace(fresh, t=3.0, fused_sensors=("x1y0", "s1")),
                replace(fresh, t=3.0, fused_seqs=(4099, 8))):
        bus.put(a, encode(bad))
    assert merger.counters["rejected_wrong_region"] == 3
    assert len(bus.of(TrackPicture)) == 3


def test_a_run_that_ends_while_the_merger_settles_keeps_its_closing_records_last(tmp_path: Path) -> None:
    """Both regions' pictures of t = 0 and 1 and their closing records (each listing the report its
    centre fused last) arrive within the merger's first ``HISTORY_SETTLE_S`` (a short run, or a
    merger started late): the closing records' entries come after the pictures', in the merger's
    closing record, as when they arrive later. Before, a closing record was kept at once and the
    settled pictures then taken for a new process's (a centre started again after a clean stop): its
    entries were listed first, in the merged picture of t = 0, and the replay of the recording failed
    (a tracker's scan before its time: ``test_mtt_regions_live``'s run over Zenoh on a fast machine)."""
    merger = PictureMergeService(regions_of(tmp_path), 4, 60.0, 1.0, service_id="picture", options=OPTIONS,
                                 deployment=KEYS.deployment)
    bus = Bus([merger])
    merger.settle_until = time.monotonic() + 60.0  # on_start's: the caches' replies come in
    for key, seq in ((KEYS.region_picture("x0y0"), 7), (KEYS.region_picture("x1y0"), 9)):
        for k in range(2):
            bus.put(key, encode(replace(region_picture(float(k), (seq,)), fused_sensors=("s1",), fused_seqs=(k,))))
        bus.put(key, encode(replace(region_picture(1.5, ()), closing=True, fused_sensors=("s1",), fused_seqs=(seq,))))
    assert bus.of(TrackPicture) == []
    merger.settle_until = time.monotonic()  # HISTORY_SETTLE_S later
    merger.on_tick()
    merger.on_stop()
    merged = [(p.t, p.closing, list(zip(p.fused_seqs, p.regions))) for p in bus.of(TrackPicture)]
    assert merged == [(0.0, False, [(0, "x0y0"), (0, "x1y0")]), (1.0, False, [(1, "x0y0"), (1, "x1y0")]),
                      (1.5, True, [(7, "x0y0"), (9, "x1y0")])]
