"""``fedtrack serve imm --sensor ID [--algorithm ao-vsimm] [--config TOML]``: a single-sensor
IMM tracker service (FSIMM, VSIMM or activation-only VSIMM of paper 000).

Consumes ``Measurement`` (kind ``position``, 2-D ``z``) on ``sensor/<ID>/meas`` and
publishes one ``FusedTrack`` per measurement on ``tracker/imm/<ID>/track``: ``model`` is the
algorithm, ``x = [x, vx, y, vy]``, ``sensors = [ID]``, ``maneuver`` is true when the most
probable mode has a non-zero acceleration, and ``extra`` carries ``mode_probabilities``
(model name -> probability), ``active_group`` and ``acceleration`` (``sum mu_i a_i``).
Measurements of another kind or dimension, or older than the last one, are skipped and
counted (``unsupported``, ``out_of_order`` in Health); after a pause beyond ``max_time_jump_s``
the tracker starts again (``restarted``: :class:`fedtrack.services.clock.ClockJump`). A second,
different measurement for the scan taken last is rejected (``conflict``), counted ``contested``, and the next track is
flagged ``contested`` with the scan in ``extra["contested_scans"]`` (docs/wire.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError, load_tables
from fedtrack.deployment import DeploymentSettings
from fedtrack.keys import check_id
from fedtrack.local_filters.imm.config import IMMConfig, load_imm_config
from fedtrack.local_filters.imm.filter import ALGORITHMS, AO_VSIMM
from fedtrack.local_filters.imm.tracker import IMMTracker
from fedtrack.services.admission import ScanOrder, contested_extra
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.clock import ClockJump
from fedtrack.services.lead import NumberedLeadGuard
from fedtrack.services.rejections import require_covariances, require_finite
from fedtrack.wire import MAX_MAP_ITEMS, FusedTrack, Measurement
from fedtrack.zsession import id_arg


class IMMService(Service):
    """Runs one :class:`IMMTracker` on one sensor's position measurements."""

    role = "imm"
    state_attrs = ("tracker", "order", "contested_scans", "lead")  # the tracker rebinds its records: a pickle of it is its state

    def __init__(self, sensor: str, algorithm: str, cfg: IMMConfig, max_time_jump_s: float = 3600.0,
                 **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.jump = ClockJump(max_time_jump_s)
        self.order = ScanOrder()
        self.lead: NumberedLeadGuard[Measurement] = NumberedLeadGuard.one_sensor()  # far ahead: waits for the next
        if len(cfg.models) > MAX_MAP_ITEMS:
            raise ConfigError(f"models: at most {MAX_MAP_ITEMS} models fit FusedTrack.extra, got {len(cfg.models)}")
        self.sensor = check_id(sensor, "--sensor")
        self.cfg = cfg
        self.tracker = IMMTracker(cfg, algorithm)
        self.moving = np.any(self.tracker.bank.acc != 0.0, axis=1)

    def _fresh(self) -> None:
        """The tracker starts afresh (its only scan abandoned: :meth:`contradicting`)."""
        self.tracker = IMMTracker(self.cfg, self.tracker.algorithm)
        self.lead, self.order = NumberedLeadGuard.one_sensor(), ScanOrder()

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas(self.sensor), Measurement, self.on_measurement)]

    def on_measurement(self, msg: Measurement) -> None:
        if msg.kind != "position" or msg.z.shape != (2,):
            self.count("unsupported")
            return
        if self.contradicting(self.lead, msg, self._fresh, self.on_measurement):
            return
        if self.tracker.t is not None and msg.t < self.tracker.t:
            self.count("out_of_order")
            return
        restart = self.jump.restart(self.tracker.t, msg.sensor, msg.seq, msg.t)
        if not self.admitted(self.order, msg):
            return
        if restart:
            self.restarted(msg)
            self.tracker, self.lead = IMMTracker(self.cfg, self.tracker.algorithm), NumberedLeadGuard.one_sensor()
        for scan in self.in_time(self.lead, self.keys.sensor_meas(self.sensor), msg):
            if self.admitted(self.order, scan) and self.after_last(self.tracker.t, scan):  # (a held scan may
                self._track(scan)  # have been repeated meanwhile)

    def _track(self, msg: Measurement) -> None:
        """Update the IMM with ``msg`` (checked) and publish its estimate."""
        self.lead.took(msg.sensor, msg.t, msg.seq)
        p = self.tracker.update(msg.t, msg.z, msg.R)
        require_finite(f"scan {msg.seq}: the IMM estimate", p.x, p.P, list(p.mode_probabilities.values()))
        require_covariances(f"scan {msg.seq}: the IMM estimate", p.P)
        self.order.took(msg)
        best = max(p.mode_probabilities, key=p.mode_probabilities.__getitem__)
        contested = self.take_contested()
        self.publish(self.keys.tracker_track("imm", self.sensor), FusedTrack.unchecked(
            seq=msg.seq, t=p.t, model=self.tracker.algorithm, x=p.x, P=p.P,
            maneuver=bool(self.moving[self.tracker.bank.names.index(best)]), degraded=False,
            sensors=(self.sensor,), stamp_ns=msg.stamp_ns, contested=bool(contested),
            extra={"mode_probabilities": p.mode_probabilities, "active_group": p.active_group,
                   "acceleration": tuple(p.acceleration.tolist()), **contested_extra(contested)}))


def main(argv: list[str]) -> int:
    parser = service_parser("imm", "single-sensor IMM tracker (FSIMM, VSIMM, activation-only VSIMM)", per_sensor=True)
    parser.add_argument("--sensor", required=True, type=id_arg("--sensor"), help="sensor id whose measurements to track")
    parser.add_argument("--algorithm", default=AO_VSIMM, choices=ALGORITHMS, help="the IMM variant, paper 000 (default: %(default)s)")
    parser.add_argument("--config", help="configuration file; reads [imm] (default: paper 000's model set)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args)
    path = Path(args.config) if args.config else None
    cfg = load_imm_config(path)  # ConfigError: the CLI exits 2
    jump = load_tables(path, DeploymentSettings).deployment.max_time_jump_s
    return IMMService(args.sensor, args.algorithm, cfg, jump, **kwargs).run()
