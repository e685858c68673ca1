"""``Service``: the base class of every ``fedtrack serve <role>`` process.

A subclass sets ``role``, overrides the hooks it needs and calls ``publish``::

    class Echo(Service):
        role = "echo"

        def subscriptions(self) -> list[Subscription]:
            return [Subscription(self.keys.sensor_meas(), Measurement, self.on_measurement)]

        def on_measurement(self, msg: Measurement) -> None:
            self.publish(self.keys.fusion_event(), ...)

    def main(argv: list[str]) -> int:
        parser = service_parser("echo", "echo measurements")
        args = parser.parse_args(argv)
        return Echo(**service_kwargs(parser, args)).run()

Threading model: Zenoh callbacks only copy the payload into one bounded inbox
(:mod:`fedtrack.services.inbox`: at most QUEUE_SIZE messages and 128 MiB, blocking when full, so
nothing is dropped while running; each key's messages in order, the keys served in turn); a single worker
thread (the one calling ``run``) decodes, validates and calls the handlers, the
queryable handlers, ``on_tick`` and the health publisher, so subclasses need no
locks. Every payload is decoded with :func:`fedtrack.wire.decode` (bounded: depth, sizes); a bad
one is counted in ``counters["rejected"]`` and logged (rate-limited, a bounded summary: key, size,
reason), never fatal. A payload whose sender id is not the id in its key, and a decoded message a
handler refuses by raising :class:`Rejected`, are counted in ``rejected`` and in
``rejected_<reason>`` (docs/wire.md, "Rejections").

Handlers cannot kill a service: each message handler, query handler and ``on_tick`` runs as one
transaction (:meth:`Service.guarded`). The attributes a subclass names in ``state_attrs`` (the
state its handlers change) are checkpointed (pickled) before it runs and restored if it raises
anything; the message is then rejected (``rejected_numerical`` for a linear-algebra or
floating-point failure or :class:`Numerical`, ``rejected_handler_error`` for anything else, a
bug: logged with its exception and place) and the service goes on as if it had never come.
A handler that cannot do its job for any message, through no fault of the message (the
recorder's database cannot take a row: the disk full, the file unwritable), raises
:class:`ServiceFault` instead: ``run`` logs it in one line and returns 1, and the supervisor
restarts the service (before 2026-11-27 the recorder rejected every later message as a
``handler_error`` and exited 0: a silent loss). A ``MemoryError`` stays a rejection of its message: a
message may ask for a bounded but large allocation (docs/wire.md, "Bounds chosen here") that a
small host refuses, and a stop would let that message, sent again, restart the service again and
again.

Every publisher is a ``zenoh.ext`` advanced publisher that keeps its last
messages per key (``cache_depth``: about ``CACHE_BYTES`` of them, between ``MIN_CACHE_SAMPLES`` and
``CACHE_SAMPLES``) and sends a heartbeat every ``HEARTBEAT_S``: a
subscriber declared with ``Subscription(..., history=True)`` (the recorder) gets, when
it (re)starts, what was published while it was away, and recovers samples lost in
transit; samples it could not recover are counted in ``counters["missed"]``. The keys a
service names in :meth:`Service.plain_outputs` (read by plain subscribers only) have a
plain publisher instead: no cache, whose messages would only fill the process's memory; those in
:meth:`Service.windowed_outputs` keep only their last N messages (their parts).
``HISTORY_RECHECK_S`` after start, such a service queries the publishers' caches once
more (``<key>/@adv/**``, the advanced publishers' own queryable): in zenoh-ext 1.x a
live sample that overtakes the per-publisher history reply makes the advanced
subscriber drop that reply as old (measured here: a restarted recorder missed 8 of 202
measurements in 2 of 6 runs); the recheck delivers them (the handler sees copies).

Lifecycle of ``run()``: open the session -> declare subscribers, queryables and token watches ->
``on_start()`` -> declare the liveliness token ``alive/<role>/<id>`` -> loop until
SIGTERM/SIGINT or ``stop()`` -> undeclare subscribers, process what is already
queued -> ``on_stop()`` -> final Health (status "stopped", or "failed" after an
error) -> close the session
within a deadline. Returns 0 on a clean stop, 1 if ``on_start`` raised (logged with its
traceback) or a handler raised :class:`ServiceFault` (logged in one line), 2 for
a user error there (OSError, ConfigError, InputError) and 1 if the session could not be opened.

The class's parts by job: this module holds the lifecycle, the inputs, Health and the router's
watch; :mod:`fedtrack.services.dispatch` the transactional dispatch and the rejections;
:mod:`fedtrack.services.publishing` the publishers and their caches.
"""

from __future__ import annotations

import argparse
import logging
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import zenoh
import zenoh.ext

from fedtrack.config import ConfigError, finite_number
from fedtrack.deployment import deployment_of, endpoints_of
from fedtrack.jsonl import InputError
from fedtrack.keys import DEFAULT_DEPLOYMENT, InvalidName, Keys, check_id
from fedtrack.services.dispatch import Dispatch, ServiceFault
from fedtrack.services.inbox import Inbox
from fedtrack.services.publishing import Publishing
from fedtrack.services.reassembly import Reassembly
from fedtrack.services.rejections import clip
from fedtrack.wire import MAX_MAP_ITEMS, Health, M, Message, WireError, decode
from fedtrack.zsession import (
    Link,
    SessionError,
    SessionOptions,
    add_endpoint_args,
    close_session,
    open_session_unless,
    options_from_args,
)

QUEUE_SIZE = 10_000
CLOSE_DEADLINE_S = 2.0
DRAIN_DEADLINE_S = 2.0
_POLL_S = 0.05
HISTORY_RECHECK_S = 1.0


@dataclass(frozen=True)
class Subscription:
    """Deliver messages of ``msg_type`` published on ``key`` (wildcards allowed) to ``handler``.

    ``history``: a ``zenoh.ext`` advanced subscriber that also fetches what the publishers
    still hold in their caches when it starts (or when a publisher appears) and recovers
    samples it missed (publisher heartbeats); the handler may then see a message twice.
    ``recover`` (implied by ``history``): only the recovery of samples lost in transit (e.g.
    while the router restarts), delivered late but in order.
    ``raw``: the handler also gets the payload bytes (``handler(msg, payload)``).
    ``wanted``: samples are taken only while it returns True (asked on the Zenoh thread, before the
    payload is copied or decoded); None: always.
    ``remote``: only other sessions' publications (not this service's own).
    """

    key: str
    msg_type: type
    handler: Callable[..., None]
    history: bool = False
    recover: bool = False
    raw: bool = False
    wanted: Callable[[], bool] | None = None
    remote: bool = False


@dataclass(frozen=True)
class QueryHandler:
    """Answer ``get`` on ``key`` with the message ``handler()`` returns (no reply when it returns None)."""

    key: str
    handler: Callable[[], Message | None]


@dataclass(frozen=True)
class TokenWatch:
    """Follow the liveliness tokens on ``key`` (wildcards allowed): ``handler(key, alive)`` is called on a
    Zenoh thread as each appears (those already there too: history) or goes."""

    key: str
    handler: Callable[[str, bool], None]


BASE_COUNTERS = ("received", "rejected", "published", "dropped")  # every service's, in every Health


def health_counters(counters: dict[str, int]) -> dict[str, int]:
    """What a ``Health`` carries of a service's counters: all of them when they fit its
    ``MAX_MAP_ITEMS`` (32) entries; else the base counters and every ``rejected_<reason>`` first
    (about 20 reasons exist), then the others that are not zero in the order they were first
    counted, as many as fit beside ``counters_omitted`` (how many are left out). A region standby
    counts 25 from its first picture, and a Health of 33 could not be made: the worker loop
    raised, and a sensor's identity sending 8 kinds of message each rejected otherwise ended it."""
    if len(counters) <= MAX_MAP_ITEMS:
        return dict(counters)
    first = [k for k in BASE_COUNTERS if k in counters] + sorted(k for k in counters if k.startswith("rejected_"))
    names = first + [k for k, v in counters.items() if v and k not in first]
    if len(names) <= MAX_MAP_ITEMS:
        return {k: counters[k] for k in names}
    kept = names[:MAX_MAP_ITEMS - 1]
    return {**{k: counters[k] for k in kept}, "counters_omitted": len(names) - len(kept)}


class Service(Dispatch, Publishing):
    """Base class of a service process (see the module docstring)."""

    role: ClassVar[str] = "service"
    tick_period_s: ClassVar[float | None] = None  # call on_tick() this often (None: never)
    # the attributes the handlers, queries and on_tick change: checkpointed before each and
    # restored if it raises (:meth:`guarded`); attributes a handler only sets after everything
    # that can fail (compute, then commit) need not be listed
    state_attrs: ClassVar[tuple[str, ...]] = ()
    # those on_tick changes (None: ``state_attrs``); a service whose tick is frequent and whose
    # state is large names fewer and guards the rest itself
    tick_state_attrs: ClassVar[tuple[str, ...] | None] = None
    # on a stop, handle what is already queued for at most this long; the rest is counted in ``dropped``
    drain_deadline_s: ClassVar[float] = DRAIN_DEADLINE_S

    def __init__(self, service_id: str, options: SessionOptions, deployment: str = DEFAULT_DEPLOYMENT,
                 health_period_s: float = 1.0) -> None:
        self.id = check_id(service_id, "service id")
        check_id(self.role, "role")
        if health_period_s <= 0:
            raise ValueError(f"health period must be > 0, got {health_period_s}")
        self.options = options
        self.keys = Keys(deployment)
        self.health_period_s = health_period_s
        self.counters: dict[str, int] = dict.fromkeys(BASE_COUNTERS, 0)
        self.contested_scans: list[int] = []  # scans contested since the last output (:meth:`contest`)
        self.status = "ok"
        self.log = logging.getLogger(f"fedtrack.{self.role}.{self.id}")
        self.session: zenoh.Session | None = None
        self._queue = Inbox(QUEUE_SIZE)  # bounded in messages and bytes, its streams served in turn
        self._stop_requested = False
        self._closing = False
        # key -> its publisher and cache depth (0: a plain publisher)
        self._publishers: dict[str, tuple[zenoh.Publisher | zenoh.ext.AdvancedPublisher, int]] = {}
        self._inputs: list[Any] = []
        self._subscriptions: list[Subscription] = []
        self._queryables: list[QueryHandler] = []
        self._health_seq = 0
        self._last_log: dict[int, float] = {}  # log level -> monotonic time of the last rejection logged
        self._suppressed: dict[int, int] = {}  # log level -> rejections not logged since
        self._missed = 0
        self._inbox_full = 0  # samples and queries whose callback waited for room (a Zenoh thread's)
        self._router_outages = 0
        self._router_lost_at: float | None = None
        self._router_back_at: float | None = None
        self._routers: set[str] = set()  # the router tokens alive (a Zenoh thread's)
        self._miss_lock = threading.Lock()
        self._reassembly = Reassembly(self._count_part)

    # ------------------------------------------------------------ hooks
    def subscriptions(self) -> list[Subscription]:
        """Messages this service consumes (called once, before ``on_start``)."""
        return []

    def queryables(self) -> list[QueryHandler]:
        """Queries this service answers (called once, before ``on_start``)."""
        return []

    def token_watches(self) -> list[TokenWatch]:
        """Liveliness tokens this service follows (called once, with ``subscriptions``)."""
        return []

    def on_start(self) -> None:
        """Called once the session and subscribers exist, before the liveliness token."""

    def on_tick(self) -> None:
        """Called every ``tick_period_s`` seconds in the worker thread."""

    def on_stopping(self) -> None:
        """Called once at a clean stop, before the inputs close: the liveliness subscribers still up (a
        liveliness query once they are undeclared can miss tokens that stand)."""

    def on_stop(self) -> None:
        """Called once after the last message was handled (flush files here)."""

    def held(self) -> bool:
        """Whether the service holds input that messages still to come release (a federated tracker's scans
        waiting for the centre's resets): at a clean stop it keeps handling messages while so (:meth:`_settle`)."""
        return False

    # ------------------------------------------------------------ API for subclasses
    def query(self, key: str, msg_type: type[M], timeout_s: float = 1.0) -> list[M]:
        """``get`` on ``key``: the valid replies decoded as ``msg_type`` (invalid ones are counted in ``rejected``).

        Call it from the hooks (e.g. ``on_start``); it blocks until the replies are in or ``timeout_s``.
        """
        assert self.session is not None
        out: list[M] = []
        for reply in self.session.get(key, timeout=timeout_s):
            if reply.ok is None:
                continue
            payload = reply.ok.payload.to_bytes()
            try:
                out.append(decode(payload, msg_type))
            except WireError as exc:
                self.counters["rejected"] += 1
                self._log_rejected(key, len(payload), str(exc))
        return out

    def count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to counter ``name`` (reported in Health, which allows 32 counters in all)."""
        self.counters[name] = self.counters.get(name, 0) + n

    def stop(self) -> None:
        """Ask ``run`` to return; safe from signal handlers and other threads."""
        self._stop_requested = True

    # ------------------------------------------------------------ run
    def run(self) -> int:
        """Run until stopped; returns the process exit code."""
        logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                            format="%(asctime)s %(name)s %(levelname)s: %(message)s")
        sys.setswitchinterval(0.0005)  # measured: callback latency ~5 ms -> ~1 ms under CPU load
        restore = self._install_signal_handlers()
        try:
            self.session = open_session_unless(self.options, lambda: self._stop_requested)
        except SessionError as exc:
            self.log.error("%s", exc)
            restore()
            return 1
        if self.session is None:  # SIGTERM or Ctrl-C while it connected: nothing opened, nothing to say
            self.log.info("stopped while connecting (exit code 0)")
            restore()
            return 0
        code = 0
        try:
            self._declare_inputs()
            self.on_start()
            token = self.session.liveliness().declare_token(self.keys.alive(self.role, self.id))
            self._inputs.append(token)
            if self.options.mode == "client":
                self._inputs.append(self.session.liveliness().declare_subscriber(
                    self.keys.alive("router"), self._on_router, history=True))
            self.log.info("ready (%s)", self.keys.alive(self.role, self.id))
            self._loop(lambda: self._stop_requested)
            self._settle()
            self.on_stopping()
            self._close_inputs()
            self._drain()
        except ServiceFault as exc:
            self.log.error("%s: stopping", exc)
            code = 1
        except (OSError, ConfigError, InputError) as exc:
            self.log.error("%s", exc)
            code = 2
        except Exception as exc:  # a bug in on_start: report it clearly and exit non-zero
            self.log.critical("fatal: %s", exc, exc_info=True)
            code = 1
        finally:
            self._close_inputs()
            code = self._shutdown(code)
            restore()
        return code

    def _install_signal_handlers(self) -> Callable[[], None]:
        if threading.current_thread() is not threading.main_thread():
            return lambda: None
        previous = {sig: signal.signal(sig, lambda *_: self.stop()) for sig in (signal.SIGTERM, signal.SIGINT)}

        def restore() -> None:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return restore

    def _declare_inputs(self) -> None:
        assert self.session is not None
        self._subscriptions = self.subscriptions()
        self._queryables = self.queryables()
        for index, sub in enumerate(self._subscriptions):
            def on_sample(sample: zenoh.Sample, index: int = index, wanted: Callable[[], bool] | None = sub.wanted
                          ) -> None:
                if sample.kind == zenoh.SampleKind.PUT and (wanted is None or wanted()):
                    self._enqueue(("sample", index, str(sample.key_expr), sample.payload.to_bytes()))
            if sub.history or sub.recover:
                history = zenoh.ext.HistoryConfig(detect_late_publishers=True) if sub.history else None
                adv = zenoh.ext.declare_advanced_subscriber(
                    self.session, sub.key, on_sample, history=history,
                    recovery=zenoh.ext.RecoveryConfig(heartbeat=True), subscriber_detection=True)
                self._inputs.append(adv)
                self._inputs.append(adv.sample_miss_listener(self._on_miss))
            else:
                origin = zenoh.Locality.REMOTE if sub.remote else zenoh.Locality.ANY
                self._inputs.append(self.session.declare_subscriber(sub.key, on_sample, allowed_origin=origin))
        for index, qh in enumerate(self._queryables):
            self._inputs.append(self.session.declare_queryable(qh.key, lambda q, index=index: self._on_query(index, q)))
        for watch in self.token_watches():
            def on_token(sample: zenoh.Sample, handler: Callable[[str, bool], None] = watch.handler) -> None:
                handler(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            self._inputs.append(self.session.liveliness().declare_subscriber(watch.key, on_token, history=True))

    def _on_query(self, index: int, query: zenoh.Query) -> None:
        """Zenoh thread: queue a query for the worker, on its queryable's stream (a querier's selectors
        are no streams of their own: 100 of them won 100 turns of the inbox for each of a sender's).
        The queryables take no payload, parameters or attachment: such a query is dropped here, its
        payload held nowhere (the inbox's byte bound counts no query), and the worker counts it
        ``rejected_query``."""
        key = self._queryables[index].key
        if query.payload is None and query.attachment is None and not str(query.parameters):
            self._enqueue(("query", index, key, query))
            return
        size = sum(len(part) for part in (query.payload, query.attachment) if part is not None)
        query.drop()
        self._enqueue(("query", index, key, size))

    def _on_router(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: log the router's loss and its return, with the outage's length. The loss is the
        last router token going (the link to this client's router closed, which takes every token with
        it): a token that another session declared and withdrew, or another host's router stopping, is
        none (each was an outage at every service)."""
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind == zenoh.SampleKind.DELETE:
            self._routers.discard(name)
            if self._routers or self._router_lost_at is not None:
                return
            self._router_lost_at = time.monotonic()
            with self._miss_lock:
                self._router_outages += 1
            self.log.warning("router %s is gone: reconnecting", clip(name))
            return
        self._routers.add(name)
        if self._router_lost_at is not None:
            self._router_back_at = time.monotonic()
            self.log.warning("router %s is back after %.2f s", clip(name), self._router_back_at - self._router_lost_at)
            self._router_lost_at = None

    def link(self) -> Link:
        """This client's link to its router, for :meth:`fedtrack.zsession.Peers.gone` (a Zenoh
        thread rebinds what it reads: the time it came back before the cut ends)."""
        return Link(cut=self._router_lost_at is not None, back_at=self._router_back_at)

    def _on_miss(self, miss: zenoh.ext.Miss) -> None:
        """Zenoh thread: samples an advanced subscriber lost for good (gone from the publisher's cache)."""
        with self._miss_lock:
            self._missed += miss.nb
        self.log.warning("missed %d sample(s) from %s (no longer in its cache)", miss.nb, miss.source)

    def _enqueue(self, item: tuple[Any, ...]) -> None:
        """Zenoh callback side: block while the inbox is full (counted ``inbox_full``: the session
        receives nothing else meanwhile), give up only when closing."""
        if self._queue.put(item, timeout=0.0):
            return
        with self._miss_lock:
            self._inbox_full += 1
        while not self._queue.put(item, timeout=0.1):
            if self._closing:
                self.counters["dropped"] += 1
                return

    def _loop(self, done: Callable[[], bool]) -> None:
        """Handle messages, ticks and Health until ``done()``."""
        now = time.monotonic()
        next_health = now
        next_tick = now + self.tick_period_s if self.tick_period_s else float("inf")
        recheck = now + HISTORY_RECHECK_S if any(sub.history for sub in self._subscriptions) else float("inf")
        while not done():
            wait = min(next_health, next_tick) - time.monotonic()
            try:
                self._dispatch(self._queue.get(timeout=min(max(wait, 0.0), _POLL_S)))
            except queue.Empty:
                pass
            now = time.monotonic()
            if now >= next_tick:
                try:
                    with self.guarded("on_tick", self.tick_state_attrs):
                        self.on_tick()
                except ServiceFault:
                    raise
                except Exception as exc:  # noqa: BLE001 - outside its transaction (see _dispatch)
                    self._reject("on_tick", 0, exc)
                next_tick = max(next_tick + self.tick_period_s, now)  # type: ignore[operator]
            if now >= next_health:
                self._reassembly.expire(now)
                self._put(self.keys.health(self.role, self.id), self._health())
                next_health = now + self.health_period_s
            if now >= recheck:
                self._query_caches()
                recheck = float("inf")

    def _settle(self) -> None:
        """At a clean stop, before the inputs close: while the service holds input that messages still to come
        release (:meth:`held`), go on as before for at most ``drain_deadline_s``."""
        deadline = time.monotonic() + self.drain_deadline_s
        if self.held():
            self._loop(lambda: not self.held() or time.monotonic() >= deadline)

    def _query_caches(self) -> None:
        """Ask the advanced publishers' caches again for every history subscription (see the module doc)."""
        assert self.session is not None
        for index, sub in enumerate(self._subscriptions):
            if not sub.history:
                continue

            def on_reply(reply: zenoh.Reply, index: int = index) -> None:
                if reply.ok is not None and reply.ok.kind == zenoh.SampleKind.PUT:
                    self._enqueue(("sample", index, str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
            self.session.get(f"{sub.key}/@adv/**", on_reply, consolidation=zenoh.ConsolidationMode.NONE,
                             accept_replies=zenoh.ReplyKeyExpr.ANY,
                             timeout=5.0)

    def _drain(self) -> None:
        """Handle what was queued before the subscribers were undeclared."""
        deadline = time.monotonic() + self.drain_deadline_s
        while time.monotonic() < deadline:
            try:
                self._dispatch(self._queue.get_nowait())
            except queue.Empty:
                return
        left = self._queue.qsize()
        self.counters["dropped"] += left
        self.log.warning("stopped with %d queued message(s) unhandled after %.1f s", left, self.drain_deadline_s)

    def _health(self) -> Health:
        self._health_seq += 1
        with self._miss_lock:
            if self._missed:
                self.counters["missed"] = self._missed
            if self._router_outages:
                self.counters["router_outages"] = self._router_outages
            if self._inbox_full:
                self.counters["inbox_full"] = self._inbox_full
        return Health(role=self.role, id=self.id, seq=self._health_seq, counters=health_counters(self.counters),
                      status=self.status)


    def _close_inputs(self) -> None:
        self._closing = True
        for item in reversed(self._inputs):
            try:
                item.undeclare()
            except zenoh.ZError as exc:
                self.log.warning("undeclare failed: %s", exc)
        self._inputs.clear()

    def _shutdown(self, code: int) -> int:
        try:
            self.on_stop()
        except Exception as exc:
            self.log.critical("on_stop failed: %s", exc, exc_info=True)
            code = code or 1
        try:
            self.status = "stopped" if code == 0 else "failed"
            self._put(self.keys.health(self.role, self.id), self._health())
            for pub, _ in self._publishers.values():
                pub.undeclare()
        except (zenoh.ZError, WireError) as exc:
            self.log.warning("final health not sent: %s", exc)
        self._publishers.clear()
        assert self.session is not None
        if not close_session(self.session, CLOSE_DEADLINE_S):
            self.log.warning("session close did not finish within %.1f s", CLOSE_DEADLINE_S)
        self.log.info("stopped (exit code %d)", code)
        return code


def service_parser(role: str, description: str, listen_default: tuple[str, ...] = (),
                   per_sensor: bool = False) -> argparse.ArgumentParser:
    """An argument parser for ``fedtrack serve <role>`` with ``--id``, ``--health-period`` and the Zenoh options;
    ``per_sensor``: a role run once per sensor (``--sensor``), whose ``--id`` defaults to the sensor's
    (:func:`service_kwargs`; a multi-target centre follows a tracker's token ``alive/mtt-local/<id>`` as its
    sensor's). Before the tour58 session every ``serve mtt-local`` started by hand had the id ``mtt-local``."""
    parser = argparse.ArgumentParser(prog=f"fedtrack serve {role}", description=description)
    parser.add_argument("--id", default=None if per_sensor else role,
                        help="service id, unique per role (default: " + ("the --sensor id" if per_sensor else role)
                        + ")")
    parser.add_argument("--health-period", type=finite_number, default=1.0, metavar="SECONDS",
                        help="publish Health this often (default: %(default)s)")
    add_endpoint_args(parser, listen_default)
    return parser


def service_kwargs(parser: argparse.ArgumentParser, args: argparse.Namespace, mode: str = "client") -> dict[str, Any]:
    """``Service.__init__`` keyword arguments from parsed arguments (bad values end in ``parser.error``).

    A ``[deployment]`` table in ``--config`` gives the defaults of ``--deployment`` (its ``name``),
    for clients ``--connect`` (its ``connect``, else ``router_listen``) and for a router
    ``--listen`` (its ``router_listen``).
    """
    config = getattr(args, "config", None)
    dep = deployment_of(config)
    if dep is not None:
        args.deployment = args.deployment or dep.name
        if mode == "client" and not args.connect:
            args.connect = list(endpoints_of(config, dep))
        if mode == "router" and not args.listen and dep.router_listen:
            args.listen = [dep.router_listen]
    args.deployment = args.deployment or DEFAULT_DEPLOYMENT
    if args.id is None:  # a per-sensor role (service_parser)
        args.id = args.sensor
    try:
        check_id(args.id, "--id")
        if args.health_period <= 0:
            raise ValueError(f"--health-period must be > 0, got {args.health_period}")
        options = options_from_args(args, mode)
    except (InvalidName, ValueError) as exc:
        parser.error(str(exc))
    return {"service_id": args.id, "options": options, "deployment": args.deployment,
            "health_period_s": args.health_period}
