"""Wait until services of a deployment are up: python -m fedtrack.deploy.wait_ready ROLE/ID ...

Opens a Zenoh client session to ``--connect`` (waiting for the router to appear) and
polls the liveliness tokens ``fedtrack/<deployment>/alive/<role>/<id>``. Use it on the
sensor hosts of a multi-host deployment before ``fedtrack launch``, so that no scan is
published before the fusion center and the recorder listen. Exit code 0 when every
service is up, 1 (naming the missing ones) after ``--timeout`` seconds, 2 for bad arguments.
``--tls-dir DIR`` connects to a mutual-TLS router (``tls/`` endpoint) as the identity ``launcher``
(``DIR/ca.pem``, ``DIR/launcher.pem``, ``.key``: the host's ``[zenoh] tls_dir``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from fedtrack.config import ConfigError
from fedtrack.deploy.access_control import LAUNCHER
from fedtrack.deploy.certificates import check_certificates
from fedtrack.deploy.security import tls_config
from fedtrack.keys import InvalidName, Keys
from fedtrack.zsession import (
    SessionError,
    SessionOptions,
    close_session,
    open_session,
    wait_alive,
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fedtrack.deploy.wait_ready", description=__doc__.splitlines()[0])
    parser.add_argument("services", nargs="+", metavar="ROLE/ID", help="e.g. fusion-center/fusion recorder/recorder")
    parser.add_argument("--connect", required=True, action="append", help="router endpoint, e.g. tcp/10.47.0.1:7447")
    parser.add_argument("--deployment", required=True, help="deployment name ([deployment] name)")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds (default: %(default)s)")
    parser.add_argument("--tls-dir", type=Path, metavar="DIR",
                        help="mutual TLS as the identity launcher with the certificates in DIR (this host's "
                             "[zenoh] tls_dir; default: none, plain links)")
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        parser.error("--timeout must be > 0")
    deadline = time.monotonic() + args.timeout
    with tempfile.TemporaryDirectory(prefix="fedtrack-wait-") as tmp:
        try:
            keys = Keys(args.deployment)
            wanted = [keys.alive(*s.split("/", 1)) for s in args.services if "/" in s]
            if len(wanted) != len(args.services):
                parser.error("services must be given as ROLE/ID")
            if args.tls_dir is None and any(ep.startswith("tls/") for ep in args.connect):
                parser.error("--connect: a tls/ endpoint needs --tls-dir (the certificates; it waited out --timeout)")
            config = None
            if args.tls_dir is not None:
                check_certificates(args.tls_dir.resolve(), [LAUNCHER])
                config = Path(tmp) / "launcher.json5"
                tls = tls_config(args.tls_dir.resolve(), LAUNCHER, router=False)
                config.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
            session = open_session(SessionOptions(mode="client", connect=tuple(args.connect),
                                                  connect_timeout_s=args.timeout,
                                                  config_file=None if config is None else str(config)))
        except ConfigError as exc:  # a certificate of --tls-dir
            parser.error(f"--tls-dir: {str(exc).removeprefix('zenoh.tls_dir: ')}")
        except (InvalidName, ValueError) as exc:
            parser.error(str(exc))
        except SessionError as exc:
            print(f"wait_ready: {exc}", file=sys.stderr)
            return 1
    try:
        missing = wait_alive(session, wanted, max(deadline - time.monotonic(), 0.0))
    finally:
        close_session(session)
    if missing:
        print(f"wait_ready: not up after {args.timeout:g} s: {', '.join(sorted(missing))}", file=sys.stderr)
        return 1
    print(f"wait_ready: up: {', '.join(args.services)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
