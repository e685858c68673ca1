"""The deployment's certificates: a CA, and per identity (:mod:`fedtrack.deploy.access_control`) a key
and a certificate signed by it (:func:`make_certificates`, the ``cryptography`` package, a dependency:
nothing else is needed on a fresh machine), written with mode 0600; and the checks, before anything
starts, that every TLS handshake will find what it needs (:func:`check_certificates`) and that the
router's certificate names every address its clients dial (:func:`check_router_names`).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where certificates are made: every service imports deploy.security, which imports this
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

from fedtrack.atomic import write_atomic
from fedtrack.config import ConfigError
from fedtrack.deployment import listen_address
from fedtrack.jsonl import output_folder
from fedtrack.keys import is_identity_name

CA_NAME = "fedtrack-ca"
CERT_DAYS = 365  # validity of new certificates (``FEDTRACK_CERT_DAYS``)
#: the last time an X.509 certificate can hold (RFC 5280's GeneralizedTime 99991231235959Z): --days 100000000 was
#: an OverflowError traceback before the tour60 session
LAST_DATE = datetime.datetime(9999, 12, 31, 23, 59, 59, tzinfo=datetime.UTC)


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
               .not_valid_before(now - datetime.timedelta(minutes=5))
               .not_valid_after(now + datetime.timedelta(days=days))
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
    """A validity in whole days, at least 1 and ending by ``LAST_DATE`` (a ConfigError naming ``source`` otherwise: 0
    made a certificate that had expired when it was made, a negative number a traceback)."""
    try:
        days = int(text)
    except ValueError:
        raise ConfigError(f"{source}: expected a whole number of days, got {text!r}") from None
    if days < 1:
        raise ConfigError(f"{source}: must be at least 1 day, got {days}")
    last = (LAST_DATE - datetime.datetime.now(datetime.UTC)).days  # a certificate ends by X.509's last date
    if days > last:
        raise ConfigError(f"{source}: must be at most {last} days (a certificate ends by 9999-12-31, the last date "
                          f"X.509 can write), got {days}")
    return days


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
        if not is_identity_name(ident):
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
    """Every address this host reaches a router at (``(field, endpoint)``,
    :func:`~fedtrack.deploy.security.host_endpoints`) must be one of the names of the deployment's
    router certificate, when this host has it: a client checks the router's certificate against the
    address it dials and refuses it otherwise (the launch then waited out ``ready_timeout_s``: 'no
    router reached', the router being up). A ConfigError naming ``zenoh.tls_dir``, the certificate,
    the field and the host."""
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
