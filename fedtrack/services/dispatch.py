"""A service's transactional dispatch (:class:`Dispatch`, a part of
:class:`fedtrack.services.base.Service`): each queued sample or query decoded, its sender checked,
a message in parts joined, and handled as one transaction (:meth:`Dispatch.guarded`: the state
put back if the handler raises); what is refused is counted ``rejected_<reason>`` and logged at
most every ``REJECT_LOG_INTERVAL_S``, and the scans a handler finds contested, repeated, restarted
or stamped far ahead are counted."""

from __future__ import annotations

import logging
import pickle
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import zenoh

from fedtrack.services.admission import MAX_CONTESTED, ReceivedScans, ScanOrder, check_sender
from fedtrack.services.lead import LEAD_INTERVALS, LeadGuard, NumberedLeadGuard
from fedtrack.services.publishing import ENCODING
from fedtrack.services.rejections import Conflict, Rejected, clip, reason_of, text_of
from fedtrack.wire import LocalEstimate, Measurement, WireError, decode, encode

REJECT_LOG_INTERVAL_S = 5.0


def held_bytes(msg: Any) -> int:
    """About how many bytes holding message ``msg`` takes: its arrays' (the lead guards' HELD_BYTES bound)."""
    return sum(getattr(msg, f.name).nbytes for f in fields(msg) if isinstance(getattr(msg, f.name), np.ndarray))


class ServiceFault(Exception):
    """Raised by a handler when the service itself cannot go on, whatever the message (its storage
    failed): never a rejection; the service stops with exit code 1, its message logged in one line."""



@dataclass
class Attempt:
    """What :meth:`Service.guarded` yields: ``failed`` once the block raised (and was undone)."""

    failed: bool = False



class Dispatch:
    """The dispatch of :class:`fedtrack.services.base.Service`. It relies on that class's ``keys``,
    ``log``, ``counters``, ``status``, ``contested_scans``, ``state_attrs``, ``_subscriptions``,
    ``_queryables``, ``_reassembly``, the rejection log's ``_last_log`` and ``_suppressed``, and its
    method ``count``."""

    def _dispatch(self, item: tuple[Any, ...]) -> None:
        """Handle one queued sample or query; whatever escapes the handler's own transaction (its
        checkpoint: a state that cannot be pickled) is a rejection too, never the service's end."""
        try:
            self._handle(item)
        except ServiceFault:
            raise
        except Exception as exc:  # noqa: BLE001 - no message may kill a service
            self._reject(str(item[2]), 0, exc)

    def _answer(self, index: int, key: str, query: zenoh.Query) -> None:
        """Reply to ``query`` on its queryable's ``key`` (whatever the selector: never on a wildcard, which
        the access control refuses)."""
        with query, self.guarded(f"query on {key}"):
            reply = self._queryables[index].handler()
            if reply is not None:
                query.reply(key, encode(reply), encoding=ENCODING)

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind, index, key, payload = item
        if kind == "query":  # a query, or the size of one that _on_query refused (on the same stream)
            if isinstance(payload, int):
                self._reject(key, payload, Rejected("query", "a query with a payload, parameters or an attachment "
                                                             "(this queryable takes none): dropped unanswered"))
            else:
                self._answer(index, key, payload)
            return
        sub = self._subscriptions[index]
        size = len(payload)
        try:
            msg = decode(payload, sub.msg_type)
            check_sender(self.keys, key, msg)
            if getattr(msg, "parts", 1) > 1 and not sub.raw:  # a raw handler (the recorder) takes each part
                try:
                    whole = self._reassembly.add(key, msg, payload, time.monotonic())
                except WireError as exc:  # parts that are not one message's
                    raise Rejected("parts", str(exc)) from None
                if whole is None:
                    return
                msg, size = whole
        except WireError as exc:
            self.counters["rejected"] += 1
            self._log_rejected(key, size, str(exc))
            return
        except Rejected as exc:
            self._reject(key, size, exc)
            return
        self.counters["received"] += 1
        with self.guarded(f"a message on {key}", key=key, size=size):
            sub.handler(*((msg, payload) if sub.raw else (msg,)))

    @contextmanager
    def guarded(self, what: str, attrs: tuple[str, ...] | None = None, key: str | None = None,
                size: int = 0) -> Iterator[Attempt]:
        """Run the block as one transaction: if it raises anything, the attributes ``attrs``
        (default ``state_attrs``), the counters and the status are put back as they were when
        it began, the failure is counted as a rejection (:func:`reason_of`) and logged (bounded),
        and the service goes on (the :class:`Attempt` yielded says ``failed``). A handler that
        publishes does so last (compute, then commit), so that nothing it failed on was sent."""
        names = self.state_attrs if attrs is None else attrs
        saved = (pickle.dumps({name: getattr(self, name) for name in names}, protocol=pickle.HIGHEST_PROTOCOL),
                 dict(self.counters), self.status)
        attempt = Attempt()
        try:
            yield attempt
        except ServiceFault:
            raise
        except Exception as exc:  # noqa: BLE001 - a handler must not end the service (module docstring)
            state, counters, status = saved
            for name, value in pickle.loads(state).items():
                setattr(self, name, value)
            self.counters, self.status = counters, status
            attempt.failed = True
            self._reject(key or what, size, exc)

    def contest(self, key: str, exc: Conflict) -> None:
        """A second, different message on ``key`` for scan ``exc.seq`` (the first stays, maybe
        already used): rejected without undoing anything, counted ``contested`` once per scan,
        and the scan named by this service's next output (:meth:`take_contested`; docs/wire.md,
        "Contested scans")."""
        if exc.seq not in self.contested_scans and len(self.contested_scans) < MAX_CONTESTED:
            self.count("contested")
            self.contested_scans.append(exc.seq)
        self.note_rejected(key, exc)

    def admitted(self, order: ScanOrder | ReceivedScans, msg: Measurement) -> bool:
        """Whether a sensor's scan ``msg`` is new to ``order``: an identical repeat is counted
        ``duplicate``, a second, different message for a scan already taken is contested
        (:meth:`contest`); both are False, and the handler drops the message."""
        try:
            if order.check(msg):
                return True
            self.count("duplicate")
        except Conflict as exc:  # the first may be the forgery: the next output names the scan
            self.contest(self.keys.sensor_meas(msg.sensor), exc)
        return False

    def restarted(self, msg: Measurement | LocalEstimate, why: str = "after a pause beyond max_time_jump_s") -> None:
        """Count and log that a tracker starts again at scan ``msg``, ``why``
        (:class:`fedtrack.services.clock.ClockJump`)."""
        self.count("restarted")
        self.log.warning("scan %d of %s at t=%g: the tracker starts again %s", msg.seq, msg.sensor, msg.t, why)

    def abandons(self, again: list[Any], msg: Measurement) -> bool:
        """Whether the tracker abandons its only scan for ``again`` (:meth:`LoneStart.contradicted`, on ``msg``'s
        arrival): counted ``start_abandoned`` and ``restarted``; the caller starts again from ``again``."""
        if again:
            self.count("start_abandoned")
            self.restarted(msg, "from two scans that contradict its only one (lead.LoneStart)")
        return bool(again)

    def contradicting(self, guard: NumberedLeadGuard[Measurement], msg: Measurement, fresh: Callable[[], None],
                      handle: Callable[[Measurement], None]) -> bool:
        """Whether scan ``msg`` contradicts a one-sensor tracker's only scan (:class:`LoneStart`, on scan numbers):
        refused ``late`` without raising (a raising handler would put ``guard`` back), or, with the scan that
        contradicted it before, abandoning it (:meth:`abandons`): ``fresh()`` starts the tracker afresh, then
        ``handle`` takes the two. True: the handler is done with ``msg``."""
        again = guard.contradicted(msg)
        if self.abandons(again, msg):
            fresh()
            for scan in again:
                handle(scan)
            return True
        if guard.contradicts(msg):
            self.note_rejected(self.keys.sensor_meas(msg.sensor), Rejected(
                "late", f"scan {msg.seq}, more than {LEAD_INTERVALS} behind the only scan taken (lead.LoneStart)"))
            return True
        return False

    def after_last(self, last_t: float | None, scan: Measurement) -> bool:
        """Whether ``scan`` is after the time ``last_t`` of the last scan a single-sensor tracker took;
        one at that time, under a new number, is rejected (``time_jump``) without raising: at ``hpda``
        the track manager pools the detections of scans at one time for its births (a sensor repeating
        its time with new scan numbers grew that pool without bound), and ``imm`` updated its track
        with the same measurement again (its variance halved, nothing counted)."""
        if last_t is None or scan.t != last_t:
            return True
        self.note_rejected(self.keys.sensor_meas(scan.sensor), Rejected(
            "time_jump", f"scan {scan.seq} at t={scan.t}, the time of the last scan taken"))
        return False

    def take_contested(self) -> tuple[int, ...]:
        """The scans contested since the last output (sorted), which the output about to be
        published names; the list starts again empty."""
        scans, self.contested_scans = tuple(sorted(self.contested_scans)), []
        return scans

    def note_rejected(self, key: str, exc: Rejected) -> None:
        """Count and log the rejection of a message on ``key`` without raising, for a handler that
        keeps what it changed (e.g. a scan marked contested)."""
        self._reject(key, 0, exc)

    def in_time(self, guard: LeadGuard[Any] | NumberedLeadGuard[Any], key: str, msg: Any, source: str | None = None,
                item: Any = None) -> list[Any]:
        """``msg`` (a scan or an estimate of ``msg.sensor``, or of ``source``, at ``msg.t``, published on
        ``key``; held as ``item`` if given) and those it witnesses, in order; none while it is held for
        being stamped (or numbered: :class:`NumberedLeadGuard`) far ahead of the data
        (:class:`LeadGuard`); the held messages it contradicts are counted ``rejected_time_lead``. The
        handler calls ``guard.took`` for each one it takes."""
        dropped, behind = guard.dropped, guard.behind
        released = guard.admit(msg.sensor if source is None else source, msg.t, msg if item is None else item,
                               held_bytes(msg))
        self.note_leads(key, guard.dropped - dropped)
        for _ in range(guard.behind - behind):
            self.note_rejected(key, Rejected("time_behind", "a first scan stamped more than max_time_jump_s before "
                                                            "the start two scans agreed on (a forged or broken "
                                                            "clock): not fused"))
        return released

    def note_leads(self, key: str, n: int) -> None:
        """Count ``n`` scans (or reports) on ``key`` that were stamped too far ahead of the data and
        that no witness confirmed (:mod:`fedtrack.services.lead`): ``rejected_time_lead``."""
        for _ in range(n):
            self.note_rejected(key, Rejected("time_lead", "stamped too far ahead of the data and never witnessed by "
                                                          "another scan (a forged or broken clock): not fused"))

    def _reject(self, key: str, size: int, exc: Exception) -> None:
        reason = reason_of(exc)
        self.counters["rejected"] += 1
        self.count(f"rejected_{reason}")
        if reason == "handler_error":  # a bug: say what and where, at error level
            frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
            where = f" at {frame.filename}:{frame.lineno} in {frame.name}" if frame else ""
            self._log_rejected(key, size, f"{type(exc).__name__}: {text_of(exc)}{where}", logging.ERROR)
        else:
            self._log_rejected(key, size, text_of(exc))

    def _log_rejected(self, key: str, size: int, reason: str, level: int = logging.WARNING) -> None:
        """Log a rejection (at most one per REJECT_LOG_INTERVAL_S and level): the key, the payload's
        size and the reason, each cut to LOG_CHARS, never the payload itself."""
        now = time.monotonic()
        if now - self._last_log.get(level, -float("inf")) < REJECT_LOG_INTERVAL_S:
            self._suppressed[level] = self._suppressed.get(level, 0) + 1
            return
        more = self._suppressed.pop(level, 0)
        self.log.log(level, "rejected a message on %s (%d bytes): %s%s", clip(key), size, clip(reason),
                     f" ({more} more rejected since the last report)" if more else "")
        self._last_log[level] = now

    def _count_part(self, name: str) -> None:
        """A counter of the reassembly of split messages (``rejected_parts`` is also a rejection)."""
        self.count(name)
        if name == "rejected_parts":
            self.counters["rejected"] += 1
