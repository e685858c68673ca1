"""Authenticated transport for ``fedtrack launch``: mutual TLS and the router's access control.

A ``[zenoh]`` table with ``tls_dir`` makes the launcher give every service (and its own
monitor) a Zenoh configuration file (``--zenoh-config``) written to ``OUT/zenoh/``:

* every link is mutual TLS: the router listens with its certificate and asks every client
  for one signed by the deployment's CA (``TLS_DIR/ca.pem``); a client without a valid
  certificate cannot open a session;
* an identity is a certificate's common name, and the router's access control (default deny) lets
  each publish only on its own keys and subscribe to and query only what its roles read
  (:mod:`fedtrack.deploy.access_control`);
* the router cuts a reader that stops reading and a link that never opens its session
  (:func:`router_limits`).

Missing certificates are made on first use (:mod:`fedtrack.deploy.certificates`); ``python -m
fedtrack.deploy.security DIR IDENTITY...`` makes them by hand (for other hosts of a multi-host
deployment: each host needs ``ca.pem`` and its own identities' files, not the CA's key).

Without ``tls_dir``, ``launch`` refuses an endpoint off loopback unless ``[zenoh] insecure = true``
says so explicitly (:func:`check_transport`): a bus that other machines can reach is
authenticated unless the configuration opts out by name.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

from fedtrack.config import ConfigError
from fedtrack.deploy.access_control import LAUNCHER, ROUTER, access_control, known_identity
from fedtrack.deploy.certificates import CERT_DAYS, cert_days, ensure_certificates, make_certificates, subject_alt_names
from fedtrack.deployment import DeploymentConfig, on_loopback
from fedtrack.jsonl import InputError
from fedtrack.keys import Keys
from fedtrack.zsession import denies_by_default, load_config_file, requires_client_certificates

T = TypeVar("T")
STALL_SHARE = 4  # a reader that stops reading is cut within this share of the deployment's shortest wait
MIN_WAIT_BEFORE_CLOSE_S = 0.1  # a descheduled process on a loaded machine; below it honest readers could be cut
ACCEPT_TIMEOUT_S = 1.0  # Zenoh's open handshake after TLS: two round trips, each well under 0.5 s
SESSIONS_PER_IDENTITY = 4  # an identity's services, one restarted beside a frozen one's session, the tools


class RouterLimits(NamedTuple):
    """What the router gives a client before cutting it: ``wait_before_close_s``, how long a message may
    wait for room in a reader's full queue (Zenoh's ``wait_before_close``: the link is then closed; while it
    waits, the publisher's whole link waits, every other reader's messages from it too), and
    ``accept_timeout_s``, how long a link that passed TLS may take to open its session (one that never
    does held one of Zenoh's ``accept_pending`` 100 places for Zenoh's 10 s)."""

    wait_before_close_s: float
    accept_timeout_s: float = ACCEPT_TIMEOUT_S


def router_limits(*waits_s: float) -> RouterLimits:
    """The limits of a deployment whose services wait ``waits_s`` for another's message before they go on
    without it (``deadline_s``, the multi-target trackers' reset timeout): a slow reader is cut within a
    quarter (``STALL_SHARE``) of the shortest, at least ``MIN_WAIT_BEFORE_CLOSE_S``, so the messages it held
    up still arrive within that wait."""
    return RouterLimits(max(min(waits_s) / STALL_SHARE, MIN_WAIT_BEFORE_CLOSE_S))


def router_transport(limits: RouterLimits, tls: dict[str, Any], identities: int) -> dict[str, Any]:
    """The router's ``transport`` section: its ``tls``, ``limits`` (Zenoh counts ``wait_before_close`` in
    microseconds, ``accept_timeout`` in milliseconds) and at most ``SESSIONS_PER_IDENTITY`` sessions per
    identity of the deployment (``max_sessions``, Zenoh's 1,000: sessions of one identity, each reading the
    fused tracks, multiplied what the router sends; a sensor's and its local filter's are two, a centre's,
    its standby's and the merger's three)."""
    block = {"wait_before_close": round(limits.wait_before_close_s * 1e6)}
    return {"unicast": {"accept_timeout": round(limits.accept_timeout_s * 1e3),
                        "max_sessions": SESSIONS_PER_IDENTITY * identities},
            "link": {"tls": tls, "tx": {"queue": {"congestion_control": {"block": block}}}}}


DEFAULT_LIMITS = router_limits(DeploymentConfig.deadline_s)


@dataclass(frozen=True)
class ZenohSettings:
    """The ``[zenoh]`` table: ``config`` (a Zenoh JSON5 file every service of this host loads)
    or ``tls_dir`` (mutual TLS + access control, certificates in that directory); relative
    paths are relative to the configuration file. ``insecure = true``: plain links even off
    loopback (without it, ``launch`` refuses them: :func:`check_transport`)."""

    config: str | None = None
    tls_dir: str | None = None
    insecure: bool = False

    def validate(self) -> None:
        if self.config is not None and self.tls_dir is not None:
            raise ConfigError("tls_dir: give either config or tls_dir, not both")
        if self.insecure and self.tls_dir is not None:
            raise ConfigError("insecure: true contradicts tls_dir (mutual TLS); give one of them")


def host_endpoints(dep: DeploymentConfig) -> list[tuple[str, str]]:
    """``(field, endpoint)`` of every router endpoint this host uses: ``router_listen`` only where a router
    runs (or the clients connect to it), ``connect``, ``router_connect``."""
    clients = ("deployment.connect", dep.connect) if dep.connect else ("deployment.router_listen", (dep.router_listen,))
    fields = [*([("deployment.router_listen", dep.router_listen)] if "router" in dep.services else []),
              *((clients[0], ep) for ep in clients[1]),
              *(("deployment.router_connect", ep) for ep in dep.router_connect)]
    return [(name, ep) for name, ep in dict.fromkeys(fields) if ep]


def check_transport(zenoh: ZenohSettings, dep: DeploymentConfig, base_dir: Path) -> None:
    """Authenticated by default: an endpoint off loopback needs ``tls_dir``, a ``config`` file (relative
    to ``base_dir``) that makes TLS mutual with ``tls/`` endpoints (and, where this host's router listens,
    enables access control with default deny, as ``serve router`` asks), or ``insecure = true`` (a
    ConfigError naming the field); with ``tls_dir`` every endpoint must be ``tls/``. The endpoints are
    those this host uses (:func:`host_endpoints`)."""
    fields = host_endpoints(dep)
    if zenoh.tls_dir is not None:
        for name, ep in fields:
            if not ep.startswith("tls/"):
                raise ConfigError(f"zenoh.tls_dir: endpoint {ep} is not tls/...: set {name} to tls/HOST:PORT "
                                  "(mutual TLS)")
        return
    if zenoh.insecure:
        return
    for name, ep in fields:
        if on_loopback(ep):
            continue
        if zenoh.config is None:
            raise ConfigError(f"{name}: {ep} is off loopback and [zenoh] has neither tls_dir (mutual TLS and "
                              "access control) nor insecure = true (an explicit opt-out)")
        if not (ep.startswith("tls/") and read_zenoh_config(base_dir / zenoh.config, requires_client_certificates)):
            raise ConfigError(f"{name}: {ep} is off loopback and not tls/ with a [zenoh] config that makes TLS "
                              "mutual (transport.link.tls: enable_mtls = true and root_ca_certificate): give "
                              "insecure = true to allow it (an explicit opt-out)")
        if (name, ep) == ("deployment.router_listen", dep.router_listen) and "router" in dep.services \
                and not read_zenoh_config(base_dir / zenoh.config, denies_by_default):
            raise ConfigError(f"{name}: {ep} is off loopback and the [zenoh] config has no access control with "
                              "default deny (access_control: enabled = true, default_permission = \"deny\"), which "
                              "serve router asks of it: give insecure = true to allow it (an explicit opt-out)")


def read_zenoh_config(path: Path, read: Callable[[str], T]) -> T:
    """``read`` of the ``[zenoh] config`` file ``path``; a ConfigError naming ``zenoh.config`` when it is
    missing or cannot be used (``read``'s ValueError)."""
    if not path.is_file():
        raise ConfigError(f"zenoh.config: {path} does not exist")
    try:
        return read(str(path))
    except ValueError as exc:
        raise ConfigError(f"zenoh.config: {exc}") from None


def tls_config(tls_dir: Path, ident: str, router: bool) -> dict[str, Any]:
    """``transport/link/tls`` for ``ident``: mutual TLS with the deployment's CA. A router presents its
    certificate on both sides: to its clients and to the routers it joins (``router_connect``)."""
    cert, key = str(tls_dir / f"{ident}.pem"), str(tls_dir / f"{ident}.key")
    tls = {"root_ca_certificate": str(tls_dir / "ca.pem"), "enable_mtls": True,
           "connect_certificate": cert, "connect_private_key": key}
    if router:
        tls.update(listen_certificate=cert, listen_private_key=key)
    return tls


def write_configs(settings: ZenohSettings, base_dir: Path, keys: Keys, identities: list[str],
                  out_dir: Path, everyone: list[str] | None = None,
                  limits: RouterLimits = DEFAULT_LIMITS) -> dict[str, Path]:
    """Write one Zenoh config file per identity of this host (``identities``, and the launcher's;
    ``ident -> path``); empty without ``[zenoh]`` settings. With ``config`` every identity gets that
    file; with ``tls_dir`` each gets its own, and only these identities' certificates must be in
    ``tls_dir`` (made there if missing and the CA's key is there). The router's access control names
    ``everyone`` (every identity of the deployment, other hosts' too; default ``identities``) and the
    launcher's; its transport cuts slow readers and unopened links by ``limits`` (default: those of the
    default ``deadline_s``) and takes ``SESSIONS_PER_IDENTITY`` sessions per identity named."""
    if settings.config is not None:
        path = (base_dir / settings.config).resolve()
        read_zenoh_config(path, load_config_file)  # read before anything starts (was: the router exited with it)
        return {ident: path for ident in [*identities, LAUNCHER]}
    if settings.tls_dir is None:
        return {}
    tls_dir = (base_dir / settings.tls_dir).resolve()
    ensure_certificates(tls_dir, [*identities, LAUNCHER])
    out = out_dir / "zenoh"
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for ident in [*identities, LAUNCHER]:
        tls = tls_config(tls_dir, ident, ident == ROUTER)
        config: dict[str, Any] = {"transport": {"link": {"tls": tls}}}
        if ident == ROUTER:
            named = sorted({*(everyone if everyone is not None else identities), LAUNCHER})  # every host's monitor
            config["transport"] = router_transport(limits, tls, len(named))
            config["access_control"] = access_control(keys, named)
        paths[ident] = out / f"{ident}.json5"
        paths[ident].write_text(json.dumps(config, indent=2))
    return paths


def main(argv: list[str] | None = None) -> int:
    """``python -m fedtrack.deploy.security DIR IDENTITY...``: make the certificates by hand."""
    parser = argparse.ArgumentParser(prog="python -m fedtrack.deploy.security",
                                     description="Make a CA (if DIR has none) and a certificate per identity "
                                                 "without one; certificates already in DIR are kept.")
    parser.add_argument("dir", type=Path, metavar="DIR",
                        help="the certificate folder ([zenoh] tls_dir), created if missing (its own folder must exist)")
    parser.add_argument("identities", nargs="+", metavar="IDENTITY",
                        help="router, fusion, recorder, launcher, sensor-<id> or region-<rid> (docs/deploy.md)")
    parser.add_argument("--san", help="extra subject alternative names, e.g. IP:10.47.0.1,DNS:host-a "
                                      "(default: $FEDTRACK_CERT_SAN, else none)")
    parser.add_argument("--days", help=f"validity of new certificates in days, at least 1 (default: "
                                       f"$FEDTRACK_CERT_DAYS, else {CERT_DAYS})")
    args = parser.parse_args(argv)
    try:
        for ident in args.identities:
            known_identity(ident)
        san = args.san if args.san is not None else os.environ.get("FEDTRACK_CERT_SAN", "")
        subject_alt_names(san, "--san" if args.san is not None else "FEDTRACK_CERT_SAN")
        days = (cert_days(args.days, "--days") if args.days is not None
                else cert_days(os.environ.get("FEDTRACK_CERT_DAYS", str(CERT_DAYS))))
        for path in make_certificates(args.dir, args.identities, san, days):
            print(f"made {path}")
    except (ConfigError, InputError, OSError) as exc:
        print(f"fedtrack.deploy.security: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
