"""Open and close Zenoh sessions the same way in every fedtrack process.

Always: multicast scouting off (no LAN discovery; endpoints are explicit), shared
memory off (no ``/dev/shm/*.zenoh`` leftovers), fast reconnection (retry every
0.1 s growing to 1 s), and ``connect/timeout_ms`` so a client started before its
router waits for it instead of failing. ``close_session`` never blocks longer
than its deadline (``close()`` can take ~12 s against a frozen peer).

``--zenoh-config FILE`` (``SessionOptions.config_file``): a Zenoh JSON5 configuration
file loaded first (TLS certificates, access control, authentication, ...); the
settings above and the endpoints are then applied on top of it.

Liveliness across a router outage (:class:`Peers`, :class:`Link`): a peer whose token went with this
client's own link to its router is not dead; it has ``LINK_GRACE_S`` after the link is back to return,
and a wait for other services' messages runs neither while the link is cut nor in that time.
"""

from __future__ import annotations

import argparse
import json
import re
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import zenoh

from fedtrack.config import ConfigError, finite_number
from fedtrack.deployment import listen_address, on_loopback
from fedtrack.keys import DEFAULT_DEPLOYMENT, InvalidName, check_id

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
RETRY_PERIOD_MAX_S = 1.0  # a client retries its connection every 0.1 s, doubling up to this
OPEN_POLL_S = 0.05  # s: how often a service opening its session checks for a stop (open_session_unless)
MODES = ("client", "peer", "router")
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?")
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")


class SessionError(RuntimeError):
    """The Zenoh session could not be opened (bad endpoint, no router within the timeout, ...)."""


@dataclass(frozen=True)
class SessionOptions:
    """How to open a session.

    ``connect_timeout_s``: how long ``open`` waits for a ``connect`` endpoint (a
    negative value waits forever). ``lease_ms``: link lease, i.e. how fast a frozen
    peer is declared dead (None keeps Zenoh's 10 s).
    """

    mode: str = "client"
    connect: tuple[str, ...] = (DEFAULT_ROUTER,)
    listen: tuple[str, ...] = ()
    connect_timeout_s: float = 10.0
    lease_ms: int | None = None
    config_file: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for ep in (*self.connect, *self.listen):
            check_endpoint(ep)
        if self.mode == "client" and not self.connect:
            raise ValueError("a client needs at least one --connect endpoint")
        if self.lease_ms is not None and self.lease_ms < 100:
            raise ValueError(f"lease_ms must be >= 100, got {self.lease_ms}")
        if self.config_file is not None:
            load_config_file(self.config_file)


def check_endpoint(endpoint: str) -> str:
    """Return ``endpoint`` if it looks like ``proto/address`` (e.g. ``tcp/127.0.0.1:7447``)."""
    if not _ENDPOINT.match(endpoint):
        raise ValueError(f"invalid endpoint {endpoint!r} (expected e.g. tcp/127.0.0.1:7447)")
    return endpoint


def load_config_file(path: str) -> zenoh.Config:
    """A ``zenoh.Config`` from a JSON5 file; ValueError naming the file if it cannot be used."""
    try:
        return zenoh.Config.from_file(path)
    except (zenoh.ZError, OSError, ValueError) as exc:
        text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip()) or type(exc).__name__
        raise ValueError(f"zenoh config {path}: {_RUST_LOCATION.sub('', text)}") from None


def make_config(opts: SessionOptions) -> zenoh.Config:
    """The ``zenoh.Config`` for ``opts`` (see the module docstring for the fixed settings)."""
    settings: dict[str, Any] = {
        "mode": opts.mode,
        "connect/endpoints": list(opts.connect),
        "listen/endpoints": list(opts.listen),
        "connect/timeout_ms": -1 if opts.connect_timeout_s < 0 else int(opts.connect_timeout_s * 1000),
        "connect/retry": {"period_init_ms": 100, "period_max_ms": int(RETRY_PERIOD_MAX_S * 1000),
                          "period_increase_factor": 2},
        "scouting/multicast/enabled": False,
        "transport/shared_memory/enabled": False,
    }
    if opts.mode == "router":
        settings["scouting/delay"] = 0
    if opts.lease_ms is not None:
        settings["transport/link/tx/lease"] = opts.lease_ms
    config = load_config_file(opts.config_file) if opts.config_file is not None else zenoh.Config()
    for key, value in settings.items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(opts: SessionOptions) -> zenoh.Session:
    """Open a session; a failure (e.g. no router within the timeout) raises SessionError."""
    try:
        return zenoh.open(make_config(opts))
    except zenoh.ZError as exc:
        where = f"connect {', '.join(opts.connect)}" if opts.connect else f"listen {', '.join(opts.listen)}"
        reason = _RUST_LOCATION.sub("", str(exc))
        raise SessionError(f"cannot open a zenoh {opts.mode} session ({where}): {reason}") from None


def open_session_unless(opts: SessionOptions, stopped: Callable[[], bool]) -> zenoh.Session | None:
    """:func:`open_session` in a thread of its own while the calling thread checks ``stopped`` every
    ``OPEN_POLL_S``; None once ``stopped`` says so before the session is open (one that opens later is closed).
    ``zenoh.open`` waits in native code, where no Python signal handler runs: a service connecting for ever
    (``--connect-timeout -1``) to a router that was not there ignored SIGTERM and Ctrl-C, and only SIGKILL ended it
    (before the tour61 session); with the default 10 s it answered them 10 s late."""
    lock = threading.Lock()
    outcome: list[zenoh.Session | Exception] = []  # the session, or the error to raise in the calling thread
    given_up = False

    def connect() -> None:
        try:
            result: zenoh.Session | Exception = open_session(opts)
        except Exception as exc:
            result = exc
        with lock:
            if not given_up:
                outcome.append(result)
                return
        if isinstance(result, zenoh.Session):
            close_session(result)

    thread = threading.Thread(target=connect, name="zenoh-open", daemon=True)
    thread.start()
    while True:
        thread.join(OPEN_POLL_S)
        with lock:
            if outcome:
                if isinstance(outcome[0], Exception):
                    raise outcome[0]
                return outcome[0]
            if stopped():
                given_up = True
                return None


def close_session(session: zenoh.Session, deadline_s: float = 2.0) -> bool:
    """Close ``session`` within ``deadline_s``; False if it did not finish (the process may exit anyway)."""
    def close() -> None:
        try:
            session.close()
        except zenoh.ZError:
            pass

    thread = threading.Thread(target=close, name="zenoh-close", daemon=True)
    thread.start()
    thread.join(deadline_s)
    return not thread.is_alive()


def alive_keys(session: zenoh.Session, key: str, timeout_s: float = 0.5) -> set[str]:
    """Keys of the liveliness tokens currently matching ``key`` (e.g. ``Keys.alive()``)."""
    return {str(r.ok.key_expr) for r in session.liveliness().get(key, timeout=timeout_s) if r.ok is not None}


def wait_alive(session: zenoh.Session, keys: list[str], timeout_s: float) -> set[str]:
    """Wait until a liveliness token exists for every key in ``keys``; returns those still missing."""
    deadline = time.monotonic() + timeout_s
    missing = set(keys)
    while True:
        missing = {k for k in missing if not alive_keys(session, k, 0.5)}
        if not missing or time.monotonic() >= deadline:
            return missing
        time.sleep(0.05)


# After this client's link to its router is back, how long its peers have to be back too: each lost its
# link when the router died and retries on the same schedule, so a live peer reconnects at most one retry
# period after this one; what it published before this client's subscribers were known at the router again
# arrives with the recovery its publisher's next heartbeat sets off (fedtrack.services.publishing's
# HEARTBEAT_S, 0.5 s; live, 0.34 s after the link's return); the rest is room for a loaded machine.
LINK_GRACE_S = 2 * RETRY_PERIOD_MAX_S
LOST_KEPT = 64  # tokens gone kept (the oldest forgotten): a flood of forged tokens declared and withdrawn


class Link(NamedTuple):
    """This client's link to its router, as the router's liveliness token shows it."""

    cut: bool = False  # the last router token went (the link closed): every other token went with it
    back_at: float | None = None  # monotonic time the link last came back after a cut (None: never cut)

    def waited(self, since: float, now: float) -> float:
        """How long a wait for other sessions' messages begun at ``since`` has run at ``now``, counted
        while the link held and its peers had time to be back: nothing can arrive while it is cut, so a
        deadline does not run then, and after a cut it runs from ``LINK_GRACE_S`` after the link's return.
        Before 2026-11-27 it ran throughout: the fusion centre fused a scan without the estimate the outage
        held up, and a local filter went on alone for want of the reset the outage held up, both during a
        router restart of 3.6 s; the filter then ran ahead through its backlog alone, and once it was more
        than the deadline ahead the centre fused scans 45-80 from its estimates alone; and after a 1.5 s
        restart every filter gave up waiting for one reset and went on alone through its backlog, the
        centre rebuilding 16 scans from their estimates (``tests/test_faults.py::test_kill_and_restart_router``
        under load: 38.7 and 39.9 m RMS against 7.1 m)."""
        if self.cut:
            return 0.0
        return now - (since if self.back_at is None else max(since, self.back_at + LINK_GRACE_S))

    def settled(self, now: float) -> bool:
        """Whether the link holds and has for ``LINK_GRACE_S`` since it last came back: what this
        session knows of the other sessions (their tokens, their subscribers) is whole again."""
        return not self.cut and (self.back_at is None or now >= self.back_at + LINK_GRACE_S)


class Peers:
    """The liveliness tokens of some peers (their keys), as they come and go (a Zenoh thread's
    callbacks rebind the sets, which another thread reads whole), and which peers a service stops
    waiting for (:meth:`gone`).

    A peer's token ``alive/<role>/<id>`` going away says the peer died (its link closed within
    milliseconds of the process ending), and a service waiting on it (the fusion centre on a local
    filter's estimate, a federated local filter on the centre's reset) goes on without it at once. But
    a client's link to its router closing takes every token with it: after a router outage the peers
    come back one by one, each session reconnecting on its own retry schedule, and the first estimates
    recovered from the publishers' caches arrive while the others' tokens are still missing. Taken as
    deaths (before 2026-11-27), they had the centre fuse a scan with the one estimate there (the
    others, a few milliseconds later, were late) and a local filter go on alone with its backlog, and
    after a 2.5 s router restart two of three filters went on alone for 33 scans of the maneuver
    (``tests/test_faults.py::test_kill_and_restart_router`` under load: 14.2 m RMS against 7.1 m).

    So a token that went while this service's own link was up is gone at once; one that went before
    the link came back (with it) is gone only if it is not back ``LINK_GRACE_S`` after the link is:
    a live peer's is back by then (see ``LINK_GRACE_S``). Meanwhile such a peer costs what a frozen one
    does: the wait's deadline, which after a cut runs from then (:meth:`Link.waited`)."""

    def __init__(self, kept: int | None = None) -> None:
        self.present: frozenset[str] = frozenset()
        self.lost: dict[str, float] = {}  # tokens that went and have not come back, with when they went
        self.kept = kept  # at most this many tokens followed (None: all)
        self.ignored = 0  # tokens not followed, beyond ``kept``

    def token(self, key: str, alive: bool, now: float) -> None:
        """Token ``key`` appeared (``alive``) or went at ``now``. With ``kept``, a token that would be one
        more than ``kept`` present is not followed (counted in ``ignored``), nor is its going: each token
        rebinds the set, a copy of those present, so that following N costs N^2 / 2 copies: 40,000 tokens of a
        region cost ``serve picture`` 77 s of CPU, 23 s when it follows 64 (``tests/test_picture_centres.py``)."""
        if self.kept is not None and key not in self.present:
            if not alive:
                return
            if len(self.present) >= self.kept:
                self.ignored += 1
                return
        if alive:
            self.present = self.present | {key}
            self.lost = {k: t for k, t in self.lost.items() if k != key}
        else:
            self.present = self.present - {key}
            lost = {k: t for k, t in self.lost.items() if k != key} | {key: now}
            self.lost = dict(list(lost.items())[-LOST_KEPT:])

    def gone(self, link: Link, now: float) -> frozenset[str]:
        """The tokens that went and count as their peers' deaths at ``now`` (:meth:`went`)."""
        return frozenset(self.went(link, now))

    def went(self, link: Link, now: float) -> dict[str, float]:
        """The tokens that went and count as their peers' deaths at ``now`` (see the module), with when
        each went (a service acting once on each death tells them apart by it): none while the link is
        cut; one that went with the link only ``LINK_GRACE_S`` after the link is back."""
        lost = self.lost
        if link.cut:
            return {}
        if link.back_at is None or now - link.back_at >= LINK_GRACE_S:
            return dict(lost)
        return {key: when for key, when in lost.items() if when > link.back_at}


def _endpoint_arg(value: str) -> str:
    """``--connect`` / ``--listen``: an endpoint, an IP protocol's ``HOST:PORT`` with a port in 1-65535
    (``tcp/127.0.0.1:99999`` was called off loopback)."""
    try:
        check_endpoint(value)
        if not value.startswith("unixsock-stream/"):
            listen_address(value, "endpoint")
    except ConfigError:
        raise argparse.ArgumentTypeError(f"invalid endpoint {value!r}: not PROTO/HOST:PORT with a port in "
                                         "1-65535") from None
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def id_arg(what: str) -> Callable[[str], str]:
    """An argparse ``type`` accepting one key chunk (``check_id``), e.g. ``id_arg("sensor id")``."""
    def parse(value: str) -> str:
        try:
            return check_id(value, what)
        except InvalidName as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return parse


_deployment_arg = id_arg("deployment")


def _config_values(config_file: str, section: str, *keys: str) -> list[Any]:
    """The values of ``section/<key>`` for each of ``keys`` in the Zenoh configuration ``config_file``."""
    config = load_config_file(config_file)
    return [json.loads(config.get_json(f"{section}/{key}")) for key in keys]


def requires_client_certificates(config_file: str) -> bool:
    """True when the Zenoh configuration ``config_file`` makes its TLS links mutual: ``enable_mtls`` with
    a ``root_ca_certificate`` to check the peer's certificate against (TLS without it authenticates
    the listening side only: any client may connect)."""
    mtls, ca = _config_values(config_file, "transport/link/tls", "enable_mtls", "root_ca_certificate")
    return mtls is True and bool(ca)


def denies_by_default(config_file: str) -> bool:
    """True when the Zenoh configuration ``config_file`` enables access control with default deny (the
    router's file that ``launch`` writes: each identity on its own keys only)."""
    enabled, default = _config_values(config_file, "access_control", "enabled", "default_permission")
    return enabled is True and default == "deny"


def check_authenticated(endpoint: str, flag: str, config_file: str | None, router: bool = False) -> None:
    """Authenticated by default, as ``launch`` is (``fedtrack.deploy.security.check_transport``): an
    endpoint off loopback must be ``tls/`` with a Zenoh configuration (``--zenoh-config``) that makes
    it mutual TLS and, where a ``router`` listens, enables access control with default deny (without
    it every certificate of the CA, a sensor's, could publish on every key); a ValueError naming
    ``flag`` otherwise (``--insecure`` opts out)."""
    try:
        loopback = on_loopback(endpoint)
    except ConfigError:  # not PROTO/HOST:PORT: not known to be loopback (Zenoh names what is wrong with it)
        loopback = False
    if loopback:
        return
    if endpoint.startswith("tls/") and config_file is not None:
        if not requires_client_certificates(config_file):
            raise ValueError(f"{flag}: {endpoint} is off loopback and --zenoh-config {config_file} does not make its "
                             "TLS mutual (transport.link.tls: enable_mtls = true and root_ca_certificate), so a peer "
                             "without a certificate could connect: give --insecure to allow it (an explicit opt-out)")
        if router and flag == "--listen" and not denies_by_default(config_file):
            raise ValueError(f"{flag}: {endpoint} is off loopback and --zenoh-config {config_file} has no access "
                             "control with default deny (access_control: enabled = true, default_permission = "
                             "\"deny\"), so any certificate of its CA could publish on every key: give --insecure "
                             "to allow it (an explicit opt-out)")
        return
    raise ValueError(f"{flag}: {endpoint} is off loopback and not tls/ with --zenoh-config (mutual TLS); a plain link "
                     "there is unauthenticated: give --insecure to allow it (an explicit opt-out)")


def add_endpoint_args(parser: argparse.ArgumentParser, listen_default: tuple[str, ...] = ()) -> None:
    """Add ``--connect``, ``--listen``, ``--deployment``, ``--connect-timeout``, ``--lease-ms``, ``--zenoh-config``."""
    group = parser.add_argument_group("zenoh")
    group.add_argument("--connect", action="append", type=_endpoint_arg, metavar="ENDPOINT",
                       help="endpoint to connect to, repeatable (default: deployment.connect of --config, "
                            f"else {DEFAULT_ROUTER} for clients, none for a router)")
    group.add_argument("--listen", action="append", type=_endpoint_arg, metavar="ENDPOINT",
                       help=f"endpoint to listen on, repeatable (default: {', '.join(listen_default) or 'none'})")
    group.add_argument("--deployment", type=_deployment_arg,
                       help="key prefix fedtrack/<deployment>/... (default: deployment.name of --config, "
                            f"else {DEFAULT_DEPLOYMENT})")
    group.add_argument("--connect-timeout", type=finite_number, default=10.0, metavar="SECONDS",
                       help="wait this long for a connect endpoint; negative = forever (default: %(default)s)")
    group.add_argument("--lease-ms", type=int, default=None, metavar="MS",
                       help="link lease: a frozen peer is declared dead after this (default: zenoh's 10000)")
    group.add_argument("--zenoh-config", metavar="FILE",
                       help="Zenoh JSON5 configuration loaded first (TLS, access control); fedtrack's settings "
                            "and the endpoints are applied on top (default: none)")
    group.add_argument("--insecure", action="store_true",
                       help="allow plain (unauthenticated) endpoints off loopback: an explicit opt-out; without it an "
                            "endpoint off loopback must be tls/ with a --zenoh-config that makes TLS mutual "
                            "(a router's --listen: and enables access control, default deny; docs/deploy.md)")
    parser.set_defaults(_listen_default=tuple(listen_default))


def options_from_args(args: argparse.Namespace, mode: str = "client") -> SessionOptions:
    """SessionOptions from the arguments added by :func:`add_endpoint_args`."""
    connect = tuple(args.connect) if args.connect else ((DEFAULT_ROUTER,) if mode == "client" else ())
    listen = tuple(args.listen) if args.listen else args._listen_default
    for flag, endpoints in (("--connect", connect), ("--listen", listen)):
        for ep in endpoints:
            # TLS with no certificate to present (or CA to check the router's) waited out the connect timeout
            if ep.startswith("tls/") and args.zenoh_config is None and "#" not in ep:
                raise ValueError(f"{flag}: {ep} is TLS but no --zenoh-config gives the certificates (the file "
                                 "fedtrack launch writes to OUT/zenoh/<identity>.json5)")
            if not args.insecure:
                check_authenticated(ep, flag, args.zenoh_config, router=mode == "router")
    return SessionOptions(mode=mode, connect=connect, listen=listen,
                          connect_timeout_s=args.connect_timeout, lease_ms=args.lease_ms,
                          config_file=args.zenoh_config)
