"""``fedtrack serve router``: the Zenoh router every other service connects to.

A Python session in router mode (no separate zenohd needed), listening on
``--listen``, else ``deployment.router_listen`` of ``--config``, else
``tcp/127.0.0.1:7447``, with multicast scouting off. It holds the liveliness token ``alive/router/<id>`` and publishes Health.
"""

from __future__ import annotations

from pathlib import Path

from fedtrack.deployment import listen_address, port_in_use
from fedtrack.services.base import Service, service_kwargs, service_parser
from fedtrack.zsession import DEFAULT_ROUTER


class Router(Service):
    """Routes data between the client sessions; handles no messages itself."""

    role = "router"


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
