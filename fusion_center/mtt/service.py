"""``fedtrack serve mtt-centre --algorithm mtt-federated|mtt-decentralized|mtt-centralized
[--dim 4|6] [--config TOML]``: the multi-target fusion centre.

Track-to-track (``mtt-federated``, ``mtt-decentralized``): consumes the local trackers'
``TrackReport`` s (``local/*/tracks``) and runs :meth:`TrackToTrackCentre.answer` on each, in
arrival order; federated, it answers each report with the sensor's ``TrackResets``
(``fusion/mtt-resets/<id>``). Measurement level (``mtt-centralized``): consumes the sensors'
scans (``sensor/*/meas``) and runs the centralized tracker (roll-back for out-of-sequence
scans). Every ``period`` seconds of data it publishes a ``TrackPicture`` (``fusion/picture``)
by the replay's rule (:class:`fedtrack.fusion_center.mtt.replay.PictureClock`), carrying the
scans it processed since the previous picture in its processing order; on a clean stop it
publishes the pictures still due. ``fedtrack replay`` of the recorded scans in that order
gives the same pictures.

Sensors join by publishing (any sensor ``[mtt] sensors`` allows, at any time). A sensor
leaves when its tracker's liveliness token (``alive/mtt-local/<id>``; for ``mtt-centralized``
the sensor's own, ``alive/sensor/<id>``) disappears, or when nothing of it arrived for
``[mtt] leave_after_s`` seconds of wall-clock time: within one tick (50 ms) the centre drops it
(:meth:`TrackToTrackCentre.drop_sensor`: no longer live, so the others' sharing factors are
renormalized; its local tracks leave their central tracks) and lists the departure in the next
picture, so that the replay drops it at the same point.

``--dim``: the central state size, 6 when any sensor is a radar (the replay's rule on the
recorded scans). Rejected (docs/wire.md#rejections): a sensor the config does not allow
(``unknown_sensor``), a report of another state size or a scan of another kind
(``wrong_model``), a second, different message for a (sensor, scan) already taken
(``conflict``; an identical one is a ``duplicate``) and a scan number more than
``[deployment] max_seq_jump`` ahead of the sensor's last (``seq_jump``).
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Any, Callable

import numpy as np
import zenoh

from fedtrack.config import ConfigError, load_tables
from fedtrack.fusion_center.mtt.engines import CentralizedEngine, TrackToTrackEngine, no_tracks
from fedtrack.fusion_center.mtt.replay import PictureClock
from fedtrack.geodetic import Frame, geodetic_of_states
from fedtrack.local_filters.mtt.config import MttConfig, MttServiceSettings
from fedtrack.local_filters.mtt.local import report_from_wire, resets_to_wire
from fedtrack.local_filters.mtt.scan import scan_from_measurement
from fedtrack.services.base import (
    Conflict,
    ReceivedScans,
    Rejected,
    Service,
    Subscription,
    require_finite,
    service_kwargs,
    service_parser,
)
from fedtrack.wire import Measurement, TrackPicture, TrackReport

ALGORITHMS = ("mtt-federated", "mtt-decentralized", "mtt-centralized")


class MttCentreService(Service):
    """The multi-target fusion centre."""

    role = "mtt-centre"
    tick_period_s = 0.05
    # restored after a failed handler (the engine changes in place: pickled before each message;
    # ``received`` is only changed once a message was handled); on_tick guards its departures itself
    state_attrs = ("engine", "clock", "order", "left_at", "pictures", "last_heard", "contested")
    tick_state_attrs = ()

    def __init__(self, algorithm: str, cfg: MttConfig, dim: int = 4, max_seq_jump: int = 1000,
                 frame: Frame | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.frame = frame  # [frame]: each picture track's WGS-84 position too
        if algorithm not in ALGORITHMS:
            raise ConfigError(f"algorithm: expected one of {', '.join(ALGORITHMS)}, got {algorithm!r}")
        self.algorithm = algorithm
        self.cfg = cfg
        self.dim = dim
        self.received = ReceivedScans(max_seq_jump)
        self.engine: CentralizedEngine | TrackToTrackEngine = (
            CentralizedEngine(cfg, dim) if algorithm == "mtt-centralized"
            else TrackToTrackEngine(cfg, dim, feedback=algorithm == "mtt-federated"))
        self.clock = PictureClock(cfg.period, cfg.picture_delay)
        self.order: list[tuple[str, int]] = []  # scans processed since the last picture
        self.left_at: list[int] = []  # positions in ``order`` that are departures
        self.pictures = 0
        self.last_heard: dict[str, float] = {}  # sensor -> monotonic time of its last message
        self.gone: deque[str] = deque()  # liveliness lost (filled by a Zenoh thread)
        self.contested = False  # a conflicting message since the last picture (docs/wire.md)

    def on_start(self) -> None:
        assert self.session is not None
        role = "sensor" if self.algorithm == "mtt-centralized" else "mtt-local"
        self._inputs.append(self.session.liveliness().declare_subscriber(self.keys.alive(role), self._on_alive))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: a tracker's (or sensor's) token went away; the worker drops it (on_tick)."""
        if sample.kind == zenoh.SampleKind.DELETE:
            self.gone.append(str(sample.key_expr).rsplit("/", 1)[-1])

    def on_tick(self) -> None:
        now = time.monotonic()
        silent = [s for s, heard in self.last_heard.items() if now - heard > self.cfg.leave_after_s]
        while self.gone:
            silent.append(self.gone.popleft())
        for sensor in dict.fromkeys(silent):
            if sensor not in self.last_heard:
                continue
            with self.guarded(f"the departure of {sensor}"):
                del self.last_heard[sensor]
                self.engine.leave(sensor)
                self.clock.left()
                self.left_at.append(len(self.order))
                self.order.append((sensor, 0))
                self.count("sensors_left")
                self.log.info("sensor %s left: dropped from fusion", sensor)

    def subscriptions(self) -> list[Subscription]:
        if self.algorithm == "mtt-centralized":
            return [Subscription(self.keys.sensor_meas(), Measurement, self.on_scan)]
        return [Subscription(self.keys.mtt_report(), TrackReport, self.on_report)]

    def _admit(self, msg: Measurement | TrackReport) -> bool:
        """True for a new (sensor, scan). False for an identical repeat (counted ``duplicate``) and
        for a second, different one: rejected, and the next picture is marked ``contested`` (the
        first was fused)."""
        if not self.cfg.allows(msg.sensor):
            raise Rejected("unknown_sensor", f"sensor {msg.sensor!r} is not in mtt.sensors")
        try:
            if self.received.check(msg):
                return True
            self.count("duplicate")
            return False
        except Conflict as exc:
            conflict = exc
        if not self.contested:
            self.count("contested")
        self.contested = True
        self.note_rejected(self.keys.mtt_report(msg.sensor) if isinstance(msg, TrackReport)
                           else self.keys.sensor_meas(msg.sensor), conflict)
        return False

    def _process(self, msg: Measurement | TrackReport, work: Callable[[], None]) -> None:
        """Make the pictures due before data at ``msg.t``, do ``work``, then publish them (compute,
        then commit: a failed ``work`` undoes both) and note the scan."""
        pictures = [self._picture(T) for T in self.clock.due(msg.t)]
        work()
        for picture in pictures:
            self.publish(self.keys.mtt_picture(), picture)
        self.order.append((msg.sensor, msg.seq))
        self.last_heard[msg.sensor] = time.monotonic()
        self.received.take(msg)

    def on_scan(self, msg: Measurement) -> None:
        try:
            scan = scan_from_measurement(msg)
        except ValueError as exc:
            raise Rejected("wrong_model", str(exc)) from None
        if scan.sensor_position is not None and self.dim != 6:
            raise Rejected("wrong_model", "a radar scan at a 2-D centre (--dim 4)")
        if not self._admit(msg):
            return
        self._process(msg, lambda: self.engine.ingest(scan))

    def on_report(self, msg: TrackReport) -> None:
        d = msg.x.shape[1] if msg.ids else None
        if d is not None and (d not in (4, 6) or d > self.dim):
            raise Rejected("wrong_model", f"local state of size {d} at a centre of size {self.dim}")
        m = msg.obs_z.shape[1]
        if msg.obs_z.shape[0] and not (m in (2, 3) and m <= d // 2):  # a position, or a radar's 3
            raise Rejected("wrong_model", f"observations of size {m} from a local state of size {d}")
        if not self._admit(msg):
            return
        if msg.contested:  # its local tracker took a conflicting scan or resets (docs/wire.md)
            self.log.warning("report %d of %s names contested scans %s", msg.seq, msg.sensor, list(msg.contested))
        report = report_from_wire(msg)
        engine = self.engine
        assert isinstance(engine, TrackToTrackEngine)

        def fuse() -> None:
            resets, q_scale = engine.fuse(report)
            if engine.feedback:
                self.publish(self.keys.mtt_resets(msg.sensor),
                             resets_to_wire(msg.seq, resets, q_scale))
        self._process(msg, fuse)
        self.contested = self.contested or bool(msg.contested)  # the next picture includes this report

    def _picture(self, T: float, closing: bool = False) -> TrackPicture:
        """The next picture, at ``T`` (it lists the scans since the previous one)."""
        tracks = no_tracks(self.dim) if closing else self.engine.picture(T)
        require_finite(f"the picture at t={T}", tracks.x, tracks.P)
        d = tracks.x.shape[1]
        ca = tuple(model == "ca" for model in tracks.models)
        maneuvering = tracks.maneuver_rows()
        picture = TrackPicture.unchecked(
            seq=self.pictures, t=T, ids=tuple(tracks.ids), x=tracks.x, P=tracks.P.reshape(-1, d),
            confirmed=tuple(tracks.confirmed), sensors=tuple(tuple(s) for s in tracks.sensors),
            fused_sensors=tuple(s for s, _ in self.order), fused_seqs=tuple(q for _, q in self.order),
            stamp_ns=time.time_ns(), closing=closing, left=tuple(self.left_at), ca=ca if any(ca) else (),
            maneuvering=tuple(maneuvering), maneuver=None if tracks.maneuver is None else tracks.maneuver[maneuvering],
            contested=self.contested, existence=None if tracks.existence is None else np.array(tracks.existence),
            lla=None if self.frame is None else geodetic_of_states(self.frame, tracks.x))
        self.pictures += 1
        self.order, self.left_at, self.contested = [], [], False
        self.counters["pictures"] = self.pictures
        for name, value in self.engine.counters().items():
            self.counters[name] = value
        return picture

    def _publish_picture(self, T: float, closing: bool = False) -> None:
        self.publish(self.keys.mtt_picture(), self._picture(T, closing))

    def on_stop(self) -> None:
        """The pictures still due at the end of the data (as the replay writes them), then the
        closing record of the scans processed after the last picture."""
        for T in self.clock.final():
            self._publish_picture(T)
        if self.order:
            self._publish_picture(self.clock.high, closing=True)


def service_from_args(argv: list[str]) -> MttCentreService:
    """The centre that ``serve mtt-centre ARGV`` runs (a ConfigError is the CLI's one-line error)."""
    parser = service_parser("mtt-centre", "the multi-target fusion centre")
    parser.add_argument("--algorithm", choices=ALGORITHMS, default="mtt-federated", help="the fusion of the local trackers' tracks (default: %(default)s)")
    parser.add_argument("--dim", type=int, choices=(4, 6), default=4,
                        help="central state size: 6 when any sensor is a radar (default: %(default)s)")
    parser.add_argument("--config", help="configuration file; reads [mtt], [deployment] and [frame] (docs/multitarget.md)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args)
    path = Path(args.config) if args.config else None
    settings = load_tables(path, MttServiceSettings)
    frame = None if settings.frame is None else settings.frame.frame
    return MttCentreService(args.algorithm, settings.mtt, args.dim, settings.deployment.max_seq_jump, frame, **kwargs)


def main(argv: list[str]) -> int:
    return service_from_args(argv).run()
