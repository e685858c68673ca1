"""The launcher's monitor: its Zenoh session's subscriptions (fused tracks, pictures, measurements,
Health, primary and router tokens, region pictures), what they add to the run's
:class:`fedtrack.deploy.report.LaunchReport` (a message that is malformed or names another sender
than its key is rejected and counted: ``monitor_rejected``), the failover watch's clock and the
progress line."""

from __future__ import annotations

import collections
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from fedtrack.deploy.failovers import FailoverWatch
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import Settings
from fedtrack.keys import Keys
from fedtrack.services.rejections import clip
from fedtrack.wire import FusedTrack, Health, M, Measurement, TrackPicture, WireError, decode
from fedtrack.zsession import SessionError, SessionOptions, open_session

FINAL_STATUSES = ("stopped", "failed")  # a service's last Health status (fedtrack.services.base)
RATE_WINDOW_S = 5.0  # the progress line's per-sensor rates: scans a second over the last 5 s (over the whole
# run before 2026-11-27, so a sensor killed at 60 s still showed 1/s at 90 s and one joining at 30 s 0/s)


class LaunchError(RuntimeError):
    """A service failed to start or an essential service died."""


class Monitor:
    """The launcher's own Zenoh session: it subscribes to the deployment's tracks, pictures,
    measurements, Health and tokens and keeps what it sees in a :class:`LaunchReport`."""

    def __init__(self, settings: Settings, max_scans: int | None = None, zenoh_config: str | None = None,
                 title: str = "fedtrack launch", scopes: frozenset[str] = frozenset()) -> None:
        self.settings = settings
        self.title = title  # the command the launcher's own lines name (``fedtrack demo`` runs one too)
        self.zenoh_config = zenoh_config
        self.max_scans = max_scans
        self._enough = threading.Event()
        self.keys = Keys(settings.deployment.name)
        self.report = LaunchReport()
        self._lock = threading.Lock()
        self._session: zenoh.Session | None = None
        self._subs: list[Any] = []
        self.watch = FailoverWatch(scopes)  # failovers and router outages, from the tokens and pictures
        self._wall0_ns, self._mono0_ns = time.time_ns(), time.monotonic_ns()  # the watch's clock (_watch_ns)
        self._arrivals: dict[str, collections.deque[float]] = {}  # sensor -> its scans of the last RATE_WINDOW_S
        # the newest fused track's scan number: a measurement's publish stamp is kept only up to max_seq_jump beyond
        # it (the services reject one further ahead), one per sensor and scan: a sensor numbering its scans
        # afresh on its own key grew the launcher by 212 B each (21 MB per 100,000), for good
        self._newest_track = -1
        self._router_status: dict[str, str] = {}  # router role/id -> the Health status last said

    def _say(self, text: str) -> None:
        sys.stderr.write(f"\n{self.title}: {text}\n")
        sys.stderr.flush()

    def _open_monitor(self) -> None:
        opts = SessionOptions(mode="client", connect=self.settings.deployment.connect_endpoints,
                              connect_timeout_s=self.settings.deployment.ready_timeout_s,
                              config_file=self.zenoh_config)
        try:
            self._session = open_session(opts)
        except SessionError as exc:  # a host without a router, whose router is not up (was a traceback)
            raise LaunchError(f"no router reached within ready_timeout_s = {opts.connect_timeout_s:g} s: "
                              f"{exc}") from None
        self._subs = [
            self._session.declare_subscriber(self.keys.fusion_track(), self._on_track),
            self._session.declare_subscriber(self.keys.sensor_meas(), self._on_meas),
            self._session.declare_subscriber(self.keys.health(), self._on_health),
            self._session.declare_subscriber(self.keys.mtt_picture(), self._on_picture),
            self._session.liveliness().declare_subscriber(self.keys.primary(), self._on_primary_token),
            self._session.liveliness().declare_subscriber(self.keys.alive("router"), self._on_router_token,
                                                          history=True),
            self._session.declare_subscriber(self.keys.region_picture(), self._on_region_picture),
        ]

    def _monitored(self, sample: zenoh.Sample, msg_type: type[M], key_of: Callable[[M], str] | None = None) -> M | None:
        """The message of ``sample`` decoded as ``msg_type`` or None when it is rejected: malformed, or
        (``key_of``) published on another key than the one its payload names as its sender's (a Health's
        role and id, a measurement's sensor). The access control admits an identity on its own keys
        only, not its payloads: before 2026-11-27 sensor 1's identity could publish the fusion centre's
        Health, with its counters, on ``health/sensor/1``, and the summary showed them. Counted in
        ``LaunchReport.monitor_rejected`` (in the summary's rejected total), the first one logged."""
        key = str(sample.key_expr)
        try:
            msg = decode(sample.payload.to_bytes(), msg_type)
        except WireError as exc:
            return self._monitor_rejects(key, str(exc))
        if key_of is not None and key_of(msg) != key:
            return self._monitor_rejects(key, f"sender: its payload is of {key_of(msg)}")
        return msg

    def _monitor_rejects(self, key: str, reason: str) -> None:
        with self._lock:
            self.report.monitor_rejected += 1
            first = self.report.monitor_rejected == 1
        if first:
            self._say(f"rejected a message on {clip(key)}: {clip(reason)} (every one is counted in summary.json's "
                      "monitor_rejected)")

    def _on_track(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        track = self._monitored(sample, FusedTrack)
        if track is None:
            return
        with self._lock:
            self.report.scans_fused += 1
            self.report.latencies_ms.append((now - track.stamp_ns) / 1e6)
            self.report.track_arrivals_ns[track.seq] = now
            self._newest_track = max(self._newest_track, track.seq)
            if self.max_scans is not None and self.report.scans_fused >= self.max_scans:
                self._enough.set()

    def _on_picture(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        pic = self._monitored(sample, TrackPicture)
        if pic is None:
            return
        if pic.closing or pic.part != pic.parts - 1:  # a picture in parts arrived with its last (docs/wire.md)
            return
        with self._lock:
            self.report.pictures += 1
            self.report.picture_arrivals.append((pic.t, now))
            self.report.picture_seqs.add(pic.seq)
            self.watch.covered("all", self._watch_ns())

    def _watch_ns(self) -> int:
        """The failover watch's clock: the wall clock as it read at the launcher's start, advanced by the
        monotonic clock, so that a step of the host's clock moves no failover or outage figure (stepped
        back 30 s before a frozen primary's take-over, its region's pictures seemed silent for -25 s and
        the take-over was no failover, before 2026-11-27)."""
        return self._wall0_ns + time.monotonic_ns() - self._mono0_ns

    def _on_region_picture(self, sample: zenoh.Sample) -> None:
        """A region centre's picture (``region/<rid>/picture``): covers its region after a failover."""
        with self._lock:
            self.watch.covered(str(sample.key_expr).split("/")[-2], self._watch_ns())

    def _on_primary_token(self, sample: zenoh.Sample) -> None:
        """A centre's primary token went or was claimed (:meth:`FailoverWatch.primary_token`)."""
        now, (scope, instance) = self._watch_ns(), str(sample.key_expr).rsplit("/", 2)[-2:]
        with self._lock:
            line = self.watch.primary_token(scope, instance, sample.kind == zenoh.SampleKind.DELETE, now)
        if line:
            self._say(line)

    def _on_router_token(self, sample: zenoh.Sample) -> None:
        """A router token went or came (:meth:`FailoverWatch.router_token`)."""
        now, name = self._watch_ns(), str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            line = self.watch.router_token(name, sample.kind == zenoh.SampleKind.DELETE, now)
        if line:
            self._say(line)

    def _on_meas(self, sample: zenoh.Sample) -> None:
        m = self._monitored(sample, Measurement, lambda m: self.keys.sensor_meas(m.sensor))
        if m is None:
            return
        if m.part != m.parts - 1:  # a scan in parts counts once, with its last part
            return
        with self._lock:
            self.report.measurements[m.sensor] = self.report.measurements.get(m.sensor, 0) + 1
            arrivals, now = self._arrivals.setdefault(m.sensor, collections.deque()), time.monotonic()
            arrivals.append(now)
            while arrivals[0] < now - RATE_WINDOW_S:  # held for the rates only (quiet: never shown)
                arrivals.popleft()
            if m.kind == "scan":
                mt = self.settings.multitarget
                self.report.note_scan(m.t, m.stamp_ns, self.settings.mtt.period, self.settings.mtt.picture_delay,
                                      mt.duration if mt is not None else 0.0)
            elif m.seq <= self._newest_track + self.settings.deployment.max_seq_jump:
                self.report.publish_stamps_ns.setdefault(m.seq, {}).setdefault(m.sensor, m.stamp_ns)

    def _on_health(self, sample: zenoh.Sample) -> None:
        """A service's Health: its counters kept for the summary; a router's status said when it changes
        (out of file descriptors: :mod:`fedtrack.services.router`), but for its last (the launcher says
        a process's end itself)."""
        h = self._monitored(sample, Health, lambda h: self.keys.health(h.role, h.id))
        if h is None:
            return
        name = f"{h.role}/{h.id}"
        with self._lock:
            self.report.health[name] = dict(h.counters)
            self.report.statuses[name] = h.status
            said = self._router_status.get(name, "ok")
            if h.role == "router":
                self._router_status[name] = h.status
        if h.role == "router" and h.status != said and h.status not in FINAL_STATUSES:
            self._say(f"{name}: {clip(h.status)}")

    def _status_line(self, start: float) -> str:
        with self._lock:
            now = time.monotonic()
            window = min(max(now - start, 1e-9), RATE_WINDOW_S)
            for times in self._arrivals.values():
                while times and times[0] < now - window:
                    times.popleft()
            rates = " ".join(f"{s}:{len(self._arrivals[s]) / window:.1f}/s" for s in sorted(self._arrivals))
            lat = self.report.latencies_ms[-50:]
            last = f"{np.median(lat):.1f} ms" if lat else "-"
            if self.settings.multitarget is not None:
                return f"pictures {self.report.pictures}  sensors {rates or '-'}"
            return f"scans fused {self.report.scans_fused}  sensors {rates or '-'}  latency(p50 last 50) {last}"
