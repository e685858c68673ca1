"""Authenticated transport for ``fedtrack launch``: mutual TLS and the router's access control.

A ``[zenoh]`` table with ``tls_dir`` makes the launcher give every service (and its own
monitor) a Zenoh configuration file (``--zenoh-config``) written to ``OUT/zenoh/``:

* every link is mutual TLS: the router listens with its certificate and asks every client
  for one signed by the deployment's CA (``TLS_DIR/ca.pem``); a client without a valid
  certificate cannot open a session;
* an identity is a certificate's common name: ``router``, ``fusion`` (the fusion center, the
  multi-target centre of the whole area and the picture merger), ``region-<rid>`` (the centre of
  region ``<rid>`` of ``[regions]`` and its standbys), ``recorder``, ``launcher`` (the launcher's
  monitor), and ``sensor-<id>`` for sensor ``<id>`` **and** its local filter or local multi-target
  tracker (they run together on the sensor's host);
* the router's access control (default deny) lets every identity receive anything of the deployment and
  read every liveliness token, but subscribe to and query only what its roles read (:func:`read_keys`), the
  advanced publishers' caches only of what it subscribes to with history or recovery (:func:`cache_keys`),
  and lets an identity publish, reply (its cache),
  declare queryables and liveliness tokens only on its own keys: ``sensor-<id>`` on
  ``sensor/<id>/meas``, ``local/<id>/estimate``, ``local/<id>/tracks`` and its health/alive
  keys; ``fusion`` on ``fusion/**`` (resets, tracks, events, pictures, the state queryable);
  ``region-<rid>`` on its region's answers, picture and primary token and on the hand-over keys
  (``region/*/handover``: it hands tracks to any neighbour), not on another region's outputs;
  ``router`` (another host's router joined by ``router_connect``, forwarding its own clients'
  messages) on anything of the deployment; the others on their health/alive keys. A denied put is
  dropped at the router: nobody receives it;
* the router cuts a reader that stops reading and a link that never opens its session
  (:func:`router_limits`).

Missing certificates are made on first use by :func:`make_certificates` (the ``cryptography``
package, a dependency: nothing else is needed on a fresh machine); ``python -m
fedtrack.deploy.security DIR IDENTITY...`` makes them by hand (for other hosts of a multi-host
deployment: each host needs ``ca.pem`` and its own identities' files, not the CA's key).

Without ``tls_dir``, ``launch`` refuses an endpoint off loopback unless ``[zenoh] insecure = true``
says so explicitly (:func:`check_transport`): a bus that other machines can reach is
authenticated unless the configuration opts out by name.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

if TYPE_CHECKING:  # imported where certificates are made: every service reads this module's settings
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

from fedtrack.atomic import write_atomic
from fedtrack.config import ConfigError
from fedtrack.deployment import DeploymentConfig, listen_address, on_loopback
from fedtrack.jsonl import InputError, output_folder
from fedtrack.keys import Keys
from fedtrack.zsession import denies_by_default, load_config_file, requires_client_certificates

T = TypeVar("T")
CA_NAME = "fedtrack-ca"
CERT_DAYS = 365  # validity of new certificates (``FEDTRACK_CERT_DAYS``)
OWN_MESSAGES = ["put", "delete", "reply", "declare_queryable", "liveliness_token"]
READ_MESSAGES = ["declare_subscriber", "query"]  # each identity on what its roles read (read_keys)
TOKEN_READS = ["liveliness_query", "declare_liveliness_subscriber"]  # every identity, every token
ALL_MESSAGES = OWN_MESSAGES + READ_MESSAGES + TOKEN_READS
LAUNCHER = "launcher"
ROUTER = "router"
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


SENSOR_ROLES = ("sensor", "local-filter", "mtt-local")  # run on the sensor's host, under its identity
CENTRE_ROLES = ("fusion-center", "mtt-centre", "picture")  # identity ``fusion`` (a region centre: ``region-<rid>``)
REGION_PREFIX = "region-"


def identity(role: str, service_id: str, region: str | None = None) -> str:
    """The certificate common name of a service (see the module docstring; a local filter's or local
    multi-target tracker's id is its sensor's; a centre of ``region``, primary or standby, is the region's)."""
    if role in SENSOR_ROLES:
        return f"sensor-{service_id}"
    if role == "mtt-centre" and region is not None:
        return REGION_PREFIX + region
    return "fusion" if role in CENTRE_ROLES else role


def own_keys(keys: Keys, ident: str) -> list[str]:
    """The keys ``ident`` may publish on (health and liveliness of its roles included)."""
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        data = [keys.sensor_meas(sid), keys.local_estimate(sid), keys.mtt_report(sid), keys.region_report(None, sid)]
        roles = [(role, sid) for role in SENSOR_ROLES]
    elif ident == "fusion":
        data = [keys.fusion_track().rsplit("/", 1)[0] + "/**", keys.primary("all")]  # the one centre's token
        roles = [(role, None) for role in CENTRE_ROLES]
    elif ident.startswith(REGION_PREFIX):  # a region's centres: their ids are the region's, or start "<rid>-"
        rid = ident.removeprefix(REGION_PREFIX)
        data = [keys.region_resets(rid), keys.region_handover(), keys.region_picture(rid), keys.primary(rid),
                keys.health("mtt-centre", rid) + "-$*", keys.alive("mtt-centre", rid) + "-$*"]  # its standbys
        roles = [("mtt-centre", rid)]
    elif ident == LAUNCHER:
        return []
    elif ident == ROUTER:  # another host's router (router_connect) forwards its own clients' messages, each
        # admitted there by its own identity; this router sees only the link's, ``router``
        data, roles = [f"fedtrack/{keys.deployment}/**"], []
    else:
        data, roles = [], [(ident, None)]
    own = data + [keys.health(r, i) for r, i in roles] + [keys.alive(r, i) for r, i in roles]
    return own + [f"{k}/@adv/**" for k in own]


def cache_keys(keys: Keys, ident: str) -> list[str]:
    """The advanced publishers' caches (``<key>/@adv/**``) ``ident`` may query: those of the keys it
    subscribes to with history or recovery (``Subscription(history=..., recover=...)``): the recorder
    every key, the fusion centre the estimates (and ``serve picture``, also ``fusion``, the region
    pictures), a sensor's local filter its measurements and resets,
    another host's router its clients'. Any identity could query every cache: asked again and again,
    every publisher sent its whole cache (up to 64 MiB a key) each time."""
    if ident in (ROUTER, "recorder"):
        return [f"fedtrack/{keys.deployment}/**/@adv/**"]
    if ident == "fusion":
        return [f"{keys.local_estimate()}/@adv/**", f"{keys.region_picture()}/@adv/**"]
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        return [f"{keys.sensor_meas(sid)}/@adv/**", f"{keys.fusion_reset(sid)}/@adv/**"]
    return []


def read_keys(keys: Keys, ident: str) -> list[str]:
    """The keys ``ident`` may subscribe to (with their advanced subscribers' ``.../@adv/**`` heartbeats) and
    query, caches aside (:func:`cache_keys`): what its roles read. A sensor's identity its measurements (its local
    filter or tracker), the centre's answers to it, the fused tracks and its single-sensor trackers'
    (lockstep pacing) and ``fusion/state`` (a local filter's rejoin); a region's its region's keys and the
    hand-overs (a standby watches its primary's); the launcher's monitor the tracks, measurements, health
    and pictures it summarises; ``fusion`` (the centres and the merger), the recorder and another host's
    router every key. Every identity could read every key: one whose session stops reading its link held
    up each publisher it reads for the router's ``wait_before_close``, so it now can only those it reads."""
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        read = [keys.sensor_meas(sid), keys.fusion_reset(sid), keys.mtt_resets(sid), keys.region_resets(None, sid),
                keys.fusion_track(), keys.tracker_track(None, sid), keys.fusion_state()]
    elif ident.startswith(REGION_PREFIX):
        rid = ident.removeprefix(REGION_PREFIX)
        read = [keys.region_report(rid), keys.region_handover(), keys.region_picture(rid), keys.region_resets(rid)]
    elif ident == LAUNCHER:
        read = [keys.fusion_track(), keys.sensor_meas(), keys.health(), keys.mtt_picture(), keys.region_picture()]
    elif ident in (ROUTER, "recorder", "fusion"):
        read = [f"fedtrack/{keys.deployment}/**"]
    else:
        read = []
    return read


def access_control(keys: Keys, identities: list[str]) -> dict[str, Any]:
    """The router's ``access_control`` section for the given identities."""
    everything = [f"fedtrack/{keys.deployment}/**", f"fedtrack/{keys.deployment}/**/@adv/**"]
    rules: list[dict[str, Any]] = [
        {"id": "receive", "messages": ALL_MESSAGES, "flows": ["egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "tokens", "messages": TOKEN_READS, "flows": ["ingress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "adv-sub", "messages": ["liveliness_token"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"fedtrack/{keys.deployment}/**/@adv/sub/**"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "authenticated"}]
    policies: list[dict[str, Any]] = [{"rules": ["receive", "tokens", "adv-sub"], "subjects": ["authenticated"]}]
    for ident in identities:
        subjects.append({"id": ident, "cert_common_names": [ident]})
        reads = read_keys(keys, ident)
        for name, messages, key_exprs in (("own", OWN_MESSAGES, own_keys(keys, ident)),
                                          ("read", ["declare_subscriber"], reads + [f"{k}/@adv/**" for k in reads]),
                                          ("query", ["query"], reads + cache_keys(keys, ident))):
            if key_exprs:
                rules.append({"id": f"{name}-{ident}", "messages": messages, "flows": ["ingress"],
                              "permission": "allow", "key_exprs": key_exprs})
                policies.append({"rules": [f"{name}-{ident}"], "subjects": [ident]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def tls_config(tls_dir: Path, ident: str, router: bool) -> dict[str, Any]:
    """``transport/link/tls`` for ``ident``: mutual TLS with the deployment's CA. A router presents its
    certificate on both sides: to its clients and to the routers it joins (``router_connect``)."""
    cert, key = str(tls_dir / f"{ident}.pem"), str(tls_dir / f"{ident}.key")
    tls = {"root_ca_certificate": str(tls_dir / "ca.pem"), "enable_mtls": True,
           "connect_certificate": cert, "connect_private_key": key}
    if router:
        tls.update(listen_certificate=cert, listen_private_key=key)
    return tls


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` readable by the owner only (created with mode 0600, replaced atomically)."""
    write_atomic(path, data, permissions=0o600)


def _certificate(subject: str, key: ec.EllipticCurvePrivateKey, issuer: x509.Name, signer: ec.EllipticCurvePrivateKey,
                 ca: bool, sans: list[x509.GeneralName], days: int) -> x509.Certificate:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)
    builder = (x509.CertificateBuilder()
               .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
               .issuer_name(issuer).public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
    if ca:
        builder = builder.add_extension(x509.KeyUsage(
            digital_signature=False, content_commitment=False, key_encipherment=False, data_encipherment=False,
            key_agreement=False, key_cert_sign=True, crl_sign=True, encipher_only=False, decipher_only=False),
            critical=True)
    else:
        builder = (builder.add_extension(x509.SubjectAlternativeName(sans), critical=False)
                   .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                         ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False))
    return builder.sign(signer, hashes.SHA256())


def subject_alt_names(extra: str = "", source: str = "FEDTRACK_CERT_SAN") -> list[x509.GeneralName]:
    """127.0.0.1 and localhost, plus ``extra`` (``IP:10.47.0.1,DNS:host-a``; a ConfigError naming
    ``source``, the option or variable it came from, when an item is neither)."""
    from cryptography import x509

    names: list[x509.GeneralName] = [x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]
    for item in filter(None, (part.strip() for part in extra.split(","))):
        kind, _, value = item.partition(":")
        if kind == "IP":
            try:
                names.append(x509.IPAddress(ipaddress.ip_address(value)))
            except ValueError:
                raise ConfigError(f"{source}: {item!r} is not IP:ADDRESS") from None
        elif kind == "DNS" and value:
            names.append(x509.DNSName(value))
        else:
            raise ConfigError(f"{source}: {item!r} is neither IP:ADDRESS nor DNS:NAME")
    return names


def cert_days(text: str, source: str = "FEDTRACK_CERT_DAYS") -> int:
    """A validity in whole days, at least 1 (a ConfigError naming ``source`` otherwise: 0 made a
    certificate that had expired when it was made, a negative number a traceback)."""
    try:
        days = int(text)
    except ValueError:
        raise ConfigError(f"{source}: expected a whole number of days, got {text!r}") from None
    if days < 1:
        raise ConfigError(f"{source}: must be at least 1 day, got {days}")
    return days


def known_identity(ident: str) -> str:
    """``ident`` if it is one of the identities a deployment uses (``router``, ``fusion``, ``recorder``,
    ``launcher``, ``sensor-<id>``, ``region-<rid>``); a ConfigError otherwise (``sensor1`` made a
    certificate nobody used)."""
    if ident in (ROUTER, "fusion", "recorder", LAUNCHER):
        return ident
    for prefix in ("sensor-", REGION_PREFIX):
        if ident.startswith(prefix) and ident != prefix:
            return ident
    raise ConfigError(f"unknown identity {ident!r} (router, fusion, recorder, launcher, sensor-<id> or region-<rid>)")


def make_certificates(tls_dir: Path, identities: list[str], extra_san: str = "", days: int = CERT_DAYS) -> list[Path]:
    """A CA (``ca.pem``, ``ca.key``) if ``tls_dir`` has none, and for each identity without one a
    key and a certificate signed by it (``IDENTITY.pem``, ``IDENTITY.key``; CN = the identity,
    which the router's access control matches; SAN = 127.0.0.1, localhost and ``extra_san``).
    ECDSA P-256 keys, written with mode 0600. Returns the certificates made. ``tls_dir`` is created
    when its own folder exists; the CA's key is read only when a certificate is to be made (a host
    given ``ca.pem`` and its own certificates needs no other)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    for ident in identities:
        if not ident or any(not (c.isalnum() or c in "._-") for c in ident):
            raise ConfigError(f"bad identity {ident!r} (letters, digits, . _ -)")
    sans = subject_alt_names(extra_san)
    missing = [ident for ident in identities if not (tls_dir / f"{ident}.pem").is_file()]
    ca_pem, ca_key_path = tls_dir / "ca.pem", tls_dir / "ca.key"
    if not missing and ca_pem.is_file():
        return []
    if ca_pem.is_file() and not ca_key_path.is_file():
        raise ConfigError(f"{tls_dir / missing[0]}.pem: missing, and {ca_key_path} is not there to sign it: make it "
                          f"where the CA's key is (python -m fedtrack.deploy.security DIR {' '.join(missing)}) "
                          "and copy each .pem and .key here")
    output_folder(tls_dir)
    pem = serialization.Encoding.PEM
    pkcs8 = serialization.PrivateFormat.PKCS8
    made = []
    if not ca_pem.is_file():
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, CA_NAME)])
        _write_private(ca_key_path, ca_key.private_bytes(pem, pkcs8, serialization.NoEncryption()))
        _write_private(ca_pem, _certificate(CA_NAME, ca_key, ca_name, ca_key, True, [], days).public_bytes(pem))
        made.append(ca_pem)
    ca_cert = x509.load_pem_x509_certificate(ca_pem.read_bytes())
    signer = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
    if not isinstance(signer, ec.EllipticCurvePrivateKey):
        raise ConfigError(f"{ca_key_path}: not an ECDSA key (make the directory again)")
    for ident in missing:
        key = ec.generate_private_key(ec.SECP256R1())
        _write_private(tls_dir / f"{ident}.key", key.private_bytes(pem, pkcs8, serialization.NoEncryption()))
        cert = _certificate(ident, key, ca_cert.subject, signer, False, sans, days)
        _write_private(tls_dir / f"{ident}.pem", cert.public_bytes(pem))
        made.append(tls_dir / f"{ident}.pem")
    return made


def ensure_certificates(tls_dir: Path, identities: list[str]) -> None:
    """Make the CA and the certificates of ``identities`` that ``tls_dir`` lacks, then check them all
    (:func:`check_certificates`; a ConfigError naming ``zenoh.tls_dir`` and the file when it cannot
    or one is unusable); ``FEDTRACK_CERT_SAN`` / ``FEDTRACK_CERT_DAYS`` as for the CLI."""
    try:
        make_certificates(tls_dir, identities, os.environ.get("FEDTRACK_CERT_SAN", ""),
                          cert_days(os.environ.get("FEDTRACK_CERT_DAYS", str(CERT_DAYS))))
    except ConfigError as exc:
        raise ConfigError(f"zenoh.tls_dir: {exc}") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"zenoh.tls_dir: making certificates in {tls_dir} failed: {exc}") from None
    check_certificates(tls_dir, identities)


def check_certificates(tls_dir: Path, identities: list[str]) -> None:
    """What every TLS handshake will need, checked before anything starts: the CA's certificate and,
    per identity, a PEM certificate signed by it, valid now, and its private key, which must match
    it. A ConfigError naming ``zenoh.tls_dir`` and the file otherwise (before, the services started
    and each failed its handshake: the launcher gave up after the ready timeout with Zenoh's
    ``Timeout!``, naming no certificate)."""
    from cryptography import x509
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization

    def load(path: Path) -> x509.Certificate:
        try:
            return x509.load_pem_x509_certificate(path.read_bytes())
        except OSError as exc:
            raise ConfigError(f"zenoh.tls_dir: {path}: cannot be read ({exc.strerror})") from None
        except ValueError:
            raise ConfigError(f"zenoh.tls_dir: {path}: not a PEM certificate (make it again: delete it and its "
                              "key, and launch makes the missing ones)") from None

    now = datetime.datetime.now(datetime.UTC)
    ca_path = tls_dir / "ca.pem"
    ca = load(ca_path)
    for ident in identities:
        path, key_path = tls_dir / f"{ident}.pem", tls_dir / f"{ident}.key"
        cert = load(path)
        for c, p in ((ca, ca_path), (cert, path)):
            if c.not_valid_after_utc <= now:
                raise ConfigError(f"zenoh.tls_dir: {p}: expired on {c.not_valid_after_utc:%Y-%m-%d %H:%M} UTC "
                                  "(make it again: delete it and its key, and launch makes the missing ones)")
            if c.not_valid_before_utc > now:
                raise ConfigError(f"zenoh.tls_dir: {p}: not valid before {c.not_valid_before_utc:%Y-%m-%d %H:%M} "
                                  "UTC (is this machine's clock right?)")
        try:
            cert.verify_directly_issued_by(ca)
        except (ValueError, TypeError, InvalidSignature):
            raise ConfigError(f"zenoh.tls_dir: {path}: not signed by the CA of {ca_path} (a certificate of another "
                              "CA: delete it and its key, and launch makes the missing ones)") from None
        if not key_path.is_file():
            raise ConfigError(f"zenoh.tls_dir: {key_path}: missing (the private key of {path.name})")
        try:
            key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        except (OSError, ValueError, TypeError):
            raise ConfigError(f"zenoh.tls_dir: {key_path}: not a PEM private key without a password") from None
        raw = (serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
        if key.public_key().public_bytes(*raw) != cert.public_key().public_bytes(*raw):
            raise ConfigError(f"zenoh.tls_dir: {key_path}: does not match the certificate {path.name}")


def check_router_names(tls_dir: Path, endpoints: list[tuple[str, str]]) -> None:
    """Every address this host reaches a router at (``(field, endpoint)``, :func:`host_endpoints`) must be
    one of the names of the deployment's router certificate, when this host has it: a client checks
    the router's certificate against the address it dials and refuses it otherwise (the launch then
    waited out ``ready_timeout_s``: 'no router reached', the router being up). A ConfigError naming
    ``zenoh.tls_dir``, the certificate, the field and the host."""
    from cryptography import x509

    path = tls_dir / "router.pem"
    if not path.is_file():
        return
    sans = x509.load_pem_x509_certificate(path.read_bytes()).extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    names = {str(ip) for ip in sans.get_values_for_type(x509.IPAddress)} | set(sans.get_values_for_type(x509.DNSName))
    for field, endpoint in endpoints:
        host = listen_address(endpoint, field)[0]
        try:
            host = str(ipaddress.ip_address(host))
            if ipaddress.ip_address(host).is_unspecified:  # a router listening on every address: dialled by another
                continue
            kind = "IP"
        except ValueError:
            kind = "DNS"
        if host not in names:
            raise ConfigError(f"zenoh.tls_dir: {path}: its names ({', '.join(sorted(names))}) do not include {host} "
                              f"of {field} ({endpoint}), so clients would refuse the router there (make it again with "
                              f"--san {kind}:{host}: delete router.pem and router.key)")


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
