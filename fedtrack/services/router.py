"""``fedtrack serve router``: the Zenoh router every other service connects to.

A Python session in router mode (no separate zenohd needed), listening on
``--listen``, else ``deployment.router_listen`` of ``--config``, else
``tcp/127.0.0.1:7447``, with multicast scouting off. It holds the liveliness token ``alive/router/<id>`` and publishes Health.

Out of file descriptors (its ``RLIMIT_NOFILE``), Zenoh refuses every new link, retrying the accept
every 100 ms, and says so only in its own Rust log (``Too many open files (os error 24) ... Hint:
increase the system open file limit``, a WARN of ``zenoh_link_tcp``), which reaches nobody unless
``zenoh.init_log_from_env_or`` is called, then 10 lines a second on stdout; its Python API gives no
signal. So the router counts its own open descriptors each second (:func:`descriptors`): while none
is left its Health status says so and counts ``fd_exhausted`` (seconds), and it logs one line when
they run out and one when there is room again (docs/deploy.md#machine-and-storage-faults).
"""

from __future__ import annotations

import errno
import os
import resource
from pathlib import Path

from fedtrack.deployment import listen_address, port_in_use
from fedtrack.services.base import Service, service_kwargs, service_parser
from fedtrack.zsession import DEFAULT_ROUTER


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


class Router(Service):
    """Routes data between the client sessions; handles no messages itself; says when it runs out of
    file descriptors (module docstring)."""

    role = "router"
    tick_period_s = 1.0

    def on_tick(self) -> None:
        """Health status and ``fd_exhausted`` while no file descriptor is left, a line when that changes."""
        used, limit = descriptors()
        status = "ok" if used < limit else (f"out of file descriptors ({used} open, RLIMIT_NOFILE {limit}): "
                                             "new sessions are refused")
        if status != self.status:
            if status == "ok":
                self.log.warning("file descriptors free again (%d open, RLIMIT_NOFILE %d)", used, limit)
            else:
                self.log.error("%s", status)
        self.status = status
        if status != "ok":
            self.count("fd_exhausted")


def main(argv: list[str]) -> int:
    parser = service_parser("router", "run the Zenoh router of a deployment", listen_default=(DEFAULT_ROUTER,))
    parser.add_argument("--config", type=Path, help="configuration file; reads [deployment] (name, router_listen; "
                        "default: none)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args, mode="router")
    for endpoint in kwargs["options"].listen:  # as launch checks router_listen (was: exit 1 and a log line)
        if port_in_use(endpoint):
            parser.error(f"--listen: port {listen_address(endpoint, '--listen')[1]} is already in use ({endpoint})")
    return Router(**kwargs).run()
