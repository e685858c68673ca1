"""``fedtrack serve router``: the Zenoh router every other service connects to.

A Python session in router mode (no separate zenohd needed), listening on
``--listen``, else ``deployment.router_listen`` of ``--config``, else
``tcp/127.0.0.1:7447``, with multicast scouting off. It holds the liveliness token ``alive/router/<id>`` and publishes Health.

When it takes no new session, Zenoh says nothing to Python, so the router looks once a second
(``on_tick``) and says why: its Health status names the cause, it logs one line when new sessions
start being refused and one when they are taken again, and the launcher prints the status
(docs/deploy.md#machine-and-storage-faults, #slow-readers-and-unopened-links):

* out of file descriptors (its ``RLIMIT_NOFILE``; :func:`descriptors`, counted ``fd_exhausted``,
  seconds): Zenoh refuses every new link, retrying the accept every 100 ms, and says so only in its
  own Rust log (``Too many open files (os error 24) ... Hint: increase the system open file limit``,
  a WARN of ``zenoh_link_tcp``), which reaches nobody unless ``zenoh.init_log_from_env_or`` is
  called, then 10 lines a second on stdout;
* a ``--connect`` endpoint (another host's router, ``[deployment] router_connect``) without a link
  ``--connect-timeout`` after the start (:func:`unjoined`): Zenoh retries it for good and said nothing, so
  a host whose peer router was unreachable ran on alone, its data reaching no other host (tour59); the
  status names the endpoints (the launcher prints it) and a line says when a link comes;
* every session place taken (``transport/unicast/max_sessions`` of its Zenoh configuration;
  :func:`sessions_by_identity`, counted ``sessions_full``): the status names the identity holding
  the most (Zenoh bounds sessions for the router as a whole, not per identity, so one certificate can
  take every place the others do not hold).
"""

from __future__ import annotations

import errno
import json
import os
import resource
import socket
import time
from collections import Counter
from pathlib import Path

import zenoh

from fedtrack.deployment import listen_problem
from fedtrack.keys import DEFAULT_DEPLOYMENT
from fedtrack.services.base import Service, service_kwargs, service_parser
from fedtrack.zsession import DEFAULT_ROUTER, SessionOptions, load_config_file


def descriptors() -> tuple[int, int]:
    """``(open, limit)``: this process's open file descriptors (``/proc/self/fd``, less the one
    listing it; ``limit`` when no descriptor is left to list it) and its soft ``RLIMIT_NOFILE``."""
    limit = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    try:
        return len(os.listdir("/proc/self/fd")) - 1, limit
    except OSError as exc:
        if exc.errno not in (errno.EMFILE, errno.ENFILE):
            raise
        return limit, limit


def sessions_by_identity(session: zenoh.Session) -> Counter[str]:
    """The sessions open at the router of ``session`` by identity: its links (``session.info.links()``,
    one a session: ``max_links`` 1) by the certificate's common name (``auth_identifier``; ``""`` on a
    link without one). Before 2026-11-27 they were read from its admin space, which answers inside
    ``get`` into get's channel of 256 replies: with more than 256 sessions the router's tick blocked
    for good (no Health, no stop), and with 1,000 one call cost 0.7 s (0.5 s of CPU) against 1 ms now."""
    return Counter(link.auth_identifier or "" for link in session.info.links())


def _address(endpoint: str) -> tuple[str, str, str]:
    """``(protocol, host, port)`` of a Zenoh endpoint or locator (``tcp/[::1]:7447#...`` -> tcp, ::1, 7447)."""
    proto, _, rest = endpoint.split("#", 1)[0].split("?", 1)[0].partition("/")
    host, _, port = rest.rpartition(":")
    return proto, host.strip("[]"), port


def resolved(endpoint: str) -> frozenset[tuple[str, str, str]]:
    """The addresses ``endpoint`` names (its host name resolved; as written when it cannot be)."""
    proto, host, port = _address(endpoint)
    try:
        ips = {info[4][0] for info in socket.getaddrinfo(host, port, proto=socket.IPPROTO_TCP)}
    except (OSError, UnicodeError):
        ips = set()
    return frozenset((proto, ip, port) for ip in ips | {host})


def unjoined(endpoints: dict[str, frozenset[tuple[str, str, str]]], links: list[str]) -> list[str]:
    """The ``endpoints`` (each with its :func:`resolved` addresses) that none of ``links`` (the
    destinations of this router's links, ``session.info.links()``) goes to."""
    reached = {_address(dst) for dst in links}
    return [ep for ep, addresses in endpoints.items() if not addresses & reached]


class Router(Service):
    """Routes data between the client sessions; handles no messages itself; says when it takes no new
    session (module docstring)."""

    role = "router"
    tick_period_s = 1.0

    def __init__(self, service_id: str, options: SessionOptions, deployment: str = DEFAULT_DEPLOYMENT,
                 health_period_s: float = 1.0) -> None:
        super().__init__(service_id, options, deployment, health_period_s)
        config = load_config_file(options.config_file) if options.config_file is not None else zenoh.Config()
        self.max_sessions = int(json.loads(config.get_json("transport/unicast/max_sessions")))
        self.refusing: tuple[str, ...] = ()  # why new sessions are refused now (none: they are taken)
        self.peers = {ep: resolved(ep) for ep in options.connect}  # the other hosts' routers it joins
        self.peers_wait_s = max(options.connect_timeout_s, 0.0)  # negative (wait for good): said at once
        self.peers_due = time.monotonic() + self.peers_wait_s  # when a missing link is said
        self.missing: tuple[str, ...] = ()  # the peers without a link, said

    def on_tick(self) -> None:
        """Health status, ``fd_exhausted`` and ``sessions_full`` while new sessions are refused; a line
        and a status when the causes change (the counts in them are the episode's first)."""
        used, limit = descriptors()
        causes = []
        if used >= limit:
            causes.append(f"out of file descriptors ({used} open, RLIMIT_NOFILE {limit})")
            self.count("fd_exhausted")
        assert self.session is not None
        held = sessions_by_identity(self.session)
        if held.total() >= self.max_sessions:
            who, most = held.most_common(1)[0]
            causes.append(f"every session place taken ({held.total()} of max_sessions {self.max_sessions}; "
                          f"{who or 'a link without a certificate'} holds {most})")
            self.count("sessions_full")
        kinds = tuple(cause.split(" (", 1)[0] for cause in causes)
        missing = tuple(unjoined(self.peers, [str(link.dst) for link in self.session.info.links()])
                        if self.peers and time.monotonic() >= self.peers_due else ())
        if kinds == self.refusing and missing == self.missing:  # the same episode: its status said once
            return
        if kinds != self.refusing:
            if causes:
                self.log.error("%s: new sessions are refused", "; ".join(causes))
            else:
                self.log.warning("new sessions are taken again (%d open, %d file descriptors of RLIMIT_NOFILE %d)",
                                 held.total(), used, limit)
        joined = [ep for ep in self.missing if ep not in missing]
        if missing:
            self.log.error("no link to the router at %s after %g s (retrying): its host's router not up, or the "
                           "address or port wrong?", ", ".join(missing), self.peers_wait_s)
        if joined:
            self.log.warning("joined the router at %s", ", ".join(joined))
        self.refusing, self.missing = kinds, missing
        said = ["; ".join(causes) + ": new sessions are refused"] if causes else []
        said += [f"no link to the router at {', '.join(missing)} (--connect; retrying)"] if missing else []
        self.status = "; ".join(said) or "ok"


def main(argv: list[str]) -> int:
    parser = service_parser("router", "run the Zenoh router of a deployment", listen_default=(DEFAULT_ROUTER,))
    parser.add_argument("--config", type=Path, help="configuration file; reads [deployment] (name, router_listen; "
                        "default: none)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args, mode="router")
    for endpoint in kwargs["options"].listen:  # as launch checks router_listen (was: exit 1 and a log line)
        problem = listen_problem(endpoint)
        if problem:
            parser.error(f"--listen: {problem}")
    return Router(**kwargs).run()
