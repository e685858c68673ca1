"""``fedtrack serve hpda --sensor ID [--algorithm hpda|pda-ai] [--config TOML]``: the
cluttered-sensor tracker service (HPDA or IPDA-AI track initiation and tracking, paper 001).

Consumes sonar ``Measurement``s (kind ``sonar``, 2-D detections with amplitudes) on
``sensor/<ID>/meas``, runs the track manager of :mod:`fedtrack.local_filters.pda.tracks`, and
publishes one ``FusedTrack`` per *confirmed* track per scan on ``tracker/hpda/<ID>/track`` (the
convention of the IMM service): ``model`` is the algorithm, ``x`` the Singer state
``[x, vx, ax, y, vy, ay]``, ``sensors = [ID]``, ``maneuver`` false, and ``extra`` carries
``existence``, ``status`` (``confirmed``) and ``track`` (the track id). Measurements of
another kind or dimension, or older than the last one, are skipped and counted
(``unsupported``, ``out_of_order`` in Health); a scan at the time of the last one taken, or of
more than ``MAX_DETECTIONS`` detections, is rejected (``time_jump``, ``too_large``:
docs/wire.md); after a pause beyond ``max_time_jump_s`` the track manager starts again
(``restarted``: :class:`fedtrack.services.clock.ClockJump`). Health also counts
``confirmed_tracks`` published and ``live_tracks`` of the last scan. A second, different
measurement for the scan taken last is rejected (``conflict``), counted ``contested``, and the confirmed tracks of the
next scan that has any are flagged ``contested`` with the scan in ``extra["contested_scans"]``
(docs/wire.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fedtrack.config import load_tables
from fedtrack.deployment import DeploymentSettings
from fedtrack.keys import check_id
from fedtrack.local_filters.pda.association import ALGORITHMS
from fedtrack.local_filters.pda.config import PDAReplayConfig, load_config
from fedtrack.local_filters.pda.tracks import (
    ManagerState,
    TrackerSpec,
    initial_manager,
    manager_step,
    tracker_spec,
)
from fedtrack.services.admission import ScanOrder, contested_extra
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.clock import ClockJump
from fedtrack.services.lead import NumberedLeadGuard
from fedtrack.services.rejections import Rejected, require_covariances, require_finite
from fedtrack.wire import MAX_DETECTIONS, FusedTrack, Measurement
from fedtrack.zsession import id_arg


class PDAService(Service):
    """Runs the PDA-AI / HPDA track manager on one sonar's scans."""

    role = "hpda"
    state_attrs = ("manager", "order", "contested_scans", "lead")  # manager_step returns a new record: a pickle of it is the state

    def __init__(self, sensor: str, algorithm: str, cfg: PDAReplayConfig, max_time_jump_s: float = 3600.0,
                 **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.jump = ClockJump(max_time_jump_s)
        self.order = ScanOrder()
        self.lead: NumberedLeadGuard[Measurement] = NumberedLeadGuard.one_sensor()  # far ahead: waits for the next
        self.sensor = check_id(sensor, "--sensor")
        self.spec: TrackerSpec = tracker_spec(algorithm, cfg.tracker, cfg.existence)
        self.manager: ManagerState = initial_manager()

    def _fresh(self) -> None:
        """The tracker starts afresh (its only scan abandoned: :meth:`contradicting`)."""
        self.manager, self.lead, self.order = initial_manager(), NumberedLeadGuard.one_sensor(), ScanOrder()

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas(self.sensor), Measurement, self.on_measurement)]

    def on_measurement(self, msg: Measurement) -> None:
        if msg.kind != "sonar" or msg.R.shape != (2, 2):
            self.count("unsupported")
            return
        if self.contradicting(self.lead, msg, self._fresh, self.on_measurement):
            return
        if self.manager.t is not None and msg.t < self.manager.t:
            self.count("out_of_order")
            return
        restart = self.jump.restart(self.manager.t, msg.sensor, msg.seq, msg.t)
        if len(msg.detections) > MAX_DETECTIONS:
            # births pair every free detection with every one of the previous scan: M x U memory and time
            raise Rejected("too_large", f"scan {msg.seq}: {len(msg.detections)} detections, more than the "
                           f"{MAX_DETECTIONS} a scan of this tracker may hold")
        if not self.admitted(self.order, msg):
            return
        if restart:
            self.restarted(msg)
            self.manager, self.lead = initial_manager(), NumberedLeadGuard.one_sensor()
        for scan in self.in_time(self.lead, self.keys.sensor_meas(self.sensor), msg):
            # (a held scan may have been repeated meanwhile)
            if self.admitted(self.order, scan) and self.after_last(self.manager.t, scan):
                self._track(scan)

    def _track(self, msg: Measurement) -> None:
        """Run the track manager on ``msg`` (checked) and publish the confirmed tracks."""
        self.lead.took(msg.sensor, msg.t, msg.seq)
        z = np.array([d.z for d in msg.detections]).reshape(-1, 2)
        amp = np.array([d.amplitude for d in msg.detections])
        keep = amp >= self.spec.c.tau
        self.manager, rep = manager_step(self.spec, self.manager, msg.t, z[keep], amp[keep], msg.R)
        tracks = rep.tracks
        require_finite(f"scan {msg.seq}: the tracks", tracks.state.x, tracks.state.P, tracks.existence)
        require_covariances(f"scan {msg.seq}: the tracks", tracks.state.P)
        self.order.took(msg)
        self.counters["live_tracks"] = len(tracks)
        confirmed = np.flatnonzero(tracks.confirmed)
        contested = self.take_contested() if len(confirmed) else ()  # named by the next scan's tracks
        for i in confirmed:
            self.publish(self.keys.tracker_track("hpda", self.sensor), FusedTrack.unchecked(
                seq=msg.seq, t=msg.t, model=self.spec.algorithm, x=tracks.state.x[i], P=tracks.state.P[i],
                maneuver=False, degraded=False, sensors=(self.sensor,), stamp_ns=msg.stamp_ns,
                contested=bool(contested), extra={"existence": float(tracks.existence[i]), "status": "confirmed",
                                                  "track": float(tracks.ids[i]), **contested_extra(contested)}))
            self.count("confirmed_tracks")


def main(argv: list[str]) -> int:
    parser = service_parser("hpda", "cluttered-sensor tracker with track initiation (HPDA or IPDA-AI)", per_sensor=True)
    parser.add_argument("--sensor", required=True, type=id_arg("--sensor"), help="sonar sensor id whose scans to track")
    parser.add_argument("--algorithm", default="hpda", choices=ALGORITHMS, help="the track manager: PDA-AI or HPDA, paper 001 (default: %(default)s)")
    parser.add_argument("--config", help="configuration file; reads [pda.tracker] and [pda.existence] (see "
                        "docs/hpda.md; default: none, every key at its default)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args)
    path = Path(args.config) if args.config else None
    return PDAService(args.sensor, args.algorithm, load_config(path),  # ConfigError: the CLI's one-line error
                      load_tables(path, DeploymentSettings).deployment.max_time_jump_s, **kwargs).run()
