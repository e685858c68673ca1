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
        if kinds == self.refusing:  # the same episode: its status (and counts) as when it began, said once
            return
        self.refusing = kinds
        self.status = "; ".join(causes) + ": new sessions are refused" if causes else "ok"
        if causes:
            self.log.error("%s", self.status)
        else:
            self.log.warning("new sessions are taken again (%d open, %d file descriptors of RLIMIT_NOFILE %d)",
                             held.total(), used, limit)


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
