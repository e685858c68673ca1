"""Authenticated transport for ``fedtrack launch``: mutual TLS and the router's access control.

A ``[zenoh]`` table with ``tls_dir`` makes the launcher give every service (and its own
monitor) a Zenoh configuration file (``--zenoh-config``) written to ``OUT/zenoh/``:

* every link is mutual TLS: the router listens with its certificate and asks every client
  for one signed by the deployment's CA (``TLS_DIR/ca.pem``); a client without a valid
  certificate cannot open a session;
* an identity is a certificate's common name: ``router``, ``fusion`` (the fusion center),
  ``recorder``, ``launcher`` (the launcher's monitor), and ``sensor-<id>`` for sensor
  ``<id>`` **and** its local filter (they run together on the sensor's host);
* the router's access control (default deny) lets every identity subscribe, query and
  receive anything of the deployment, and lets an identity publish, reply (its cache),
  declare queryables and liveliness tokens only on its own keys: ``sensor-<id>`` on
  ``sensor/<id>/meas``, ``local/<id>/estimate`` and its health/alive keys; ``fusion``
  on ``fusion/**`` (resets, tracks, events, the state queryable); the others on their
  health/alive keys. A denied put is dropped at the router: nobody receives it.

Missing certificates are made with ``deploy/secure/make-certs.sh`` (openssl) on first use.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError
from fedtrack.keys import Keys

MAKE_CERTS = Path(__file__).resolve().parent / "secure" / "make-certs.sh"
OWN_MESSAGES = ["put", "delete", "reply", "declare_queryable", "liveliness_token"]
READ_MESSAGES = ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"]
ALL_MESSAGES = OWN_MESSAGES + READ_MESSAGES
LAUNCHER = "launcher"


@dataclass(frozen=True)
class ZenohSettings:
    """The ``[zenoh]`` table: ``config`` (a Zenoh JSON5 file every service of this host loads)
    or ``tls_dir`` (mutual TLS + access control, certificates in that directory); relative
    paths are relative to the configuration file."""

    config: str | None = None
    tls_dir: str | None = None

    def validate(self) -> None:
        if self.config is not None and self.tls_dir is not None:
            raise ConfigError("tls_dir: give either config or tls_dir, not both")


def identity(role: str, service_id: str) -> str:
    """The certificate common name of a service (see the module docstring; a local filter's id is its sensor's)."""
    if role in ("sensor", "local-filter"):
        return f"sensor-{service_id}"
    return {"fusion-center": "fusion"}.get(role, role)


def _own_keys(keys: Keys, ident: str) -> list[str]:
    """The keys ``ident`` may publish on (health and liveliness of its roles included)."""
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        data = [keys.sensor_meas(sid), keys.local_estimate(sid)]
        roles = [("sensor", sid), ("local-filter", sid)]
    elif ident == "fusion":
        data = [keys.fusion_track().rsplit("/", 1)[0] + "/**"]
        roles = [("fusion-center", None)]
    elif ident == LAUNCHER:
        return []
    else:
        data, roles = [], [(ident, None)]
    own = data + [keys.health(r, i) for r, i in roles] + [keys.alive(r, i) for r, i in roles]
    return own + [f"{k}/@adv/**" for k in own]


def access_control(keys: Keys, identities: list[str]) -> dict[str, Any]:
    """The router's ``access_control`` section for the given identities."""
    everything = [f"fedtrack/{keys.deployment}/**", f"fedtrack/{keys.deployment}/**/@adv/**"]
    rules: list[dict[str, Any]] = [
        {"id": "receive", "messages": ALL_MESSAGES, "flows": ["egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "read", "messages": READ_MESSAGES, "flows": ["ingress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "adv-sub", "messages": ["liveliness_token"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"fedtrack/{keys.deployment}/**/@adv/sub/**"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "authenticated"}]
    policies: list[dict[str, Any]] = [{"rules": ["receive", "read", "adv-sub"], "subjects": ["authenticated"]}]
    for ident in identities:
        own = _own_keys(keys, ident)
        subjects.append({"id": ident, "cert_common_names": [ident]})
        if own:
            rules.append({"id": f"own-{ident}", "messages": OWN_MESSAGES, "flows": ["ingress"],
                          "permission": "allow", "key_exprs": own})
            policies.append({"rules": [f"own-{ident}"], "subjects": [ident]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def tls_config(tls_dir: Path, ident: str, router: bool) -> dict[str, Any]:
    """``transport/link/tls`` for ``ident``: mutual TLS with the deployment's CA."""
    cert, key = str(tls_dir / f"{ident}.pem"), str(tls_dir / f"{ident}.key")
    side = ("listen_certificate", "listen_private_key") if router else ("connect_certificate", "connect_private_key")
    return {"root_ca_certificate": str(tls_dir / "ca.pem"), "enable_mtls": True, side[0]: cert, side[1]: key}


def ensure_certificates(tls_dir: Path, identities: list[str]) -> None:
    """Make the CA and the certificates of ``identities`` that ``tls_dir`` lacks (openssl)."""
    missing = [i for i in identities if not (tls_dir / f"{i}.pem").is_file()]
    if not missing and (tls_dir / "ca.pem").is_file():
        return
    if shutil.which("openssl") is None:
        raise ConfigError(f"zenoh.tls_dir: {tls_dir} lacks certificates for {', '.join(missing)} and openssl is not "
                          "installed to make them")
    done = subprocess.run(["sh", str(MAKE_CERTS), str(tls_dir), *missing], check=False, capture_output=True,
                          text=True, timeout=120)
    if done.returncode != 0:
        raise ConfigError(f"zenoh.tls_dir: making certificates in {tls_dir} failed: {done.stderr.strip()[-300:]}")


def write_configs(settings: ZenohSettings, base_dir: Path, keys: Keys, endpoints: list[str],
                  identities: list[str], out_dir: Path) -> dict[str, Path]:
    """Write one Zenoh config file per identity (``ident -> path``); empty without ``[zenoh]`` settings.

    With ``config`` every identity gets that file; with ``tls_dir`` each gets its own.
    """
    if settings.config is not None:
        path = (base_dir / settings.config).resolve()
        if not path.is_file():
            raise ConfigError(f"zenoh.config: {path} does not exist")
        return {ident: path for ident in [*identities, LAUNCHER]}
    if settings.tls_dir is None:
        return {}
    plain = [ep for ep in endpoints if not ep.startswith("tls/")]
    if plain:
        raise ConfigError(f"zenoh.tls_dir: endpoint {plain[0]} is not tls/...: set deployment.router_listen "
                          "(and connect) to tls/HOST:PORT")
    tls_dir = (base_dir / settings.tls_dir).resolve()
    ensure_certificates(tls_dir, [*identities, LAUNCHER])
    out = out_dir / "zenoh"
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for ident in [*identities, LAUNCHER]:
        config: dict[str, Any] = {"transport": {"link": {"tls": tls_config(tls_dir, ident, ident == "router")}}}
        if ident == "router":
            config["access_control"] = access_control(keys, identities)
        paths[ident] = out / f"{ident}.json5"
        paths[ident].write_text(json.dumps(config, indent=2))
    return paths
