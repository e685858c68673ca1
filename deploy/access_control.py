"""The identities of a deployment and the router's access control over them (default deny).

An identity is a certificate's common name (:func:`identity`): ``router``, ``fusion`` (the fusion
center, the multi-target centre of the whole area and the picture merger), ``region-<rid>`` (the
centre of region ``<rid>`` of ``[regions]`` and its standbys), ``recorder``, ``launcher`` (the
launcher's monitor), and ``sensor-<id>`` for sensor ``<id>`` **and** its local filter or local
multi-target tracker (they run together on the sensor's host).

The router's access control (:func:`access_control`) lets every identity receive anything of the
deployment and read every liveliness token, but subscribe to and query only what its roles read
(:func:`read_keys`), the advanced publishers' caches only of what it subscribes to with history or
recovery (:func:`cache_keys`), and lets an identity publish, reply (its cache), declare queryables
and liveliness tokens only on its own keys (:func:`own_keys`): ``sensor-<id>`` on
``sensor/<id>/meas``, ``local/<id>/estimate``, ``local/<id>/tracks`` and its health/alive keys;
``fusion`` on ``fusion/**`` (resets, tracks, events, pictures, the state queryable) and the health/alive keys of
its own services (``FUSION_SERVICES``: the ids the launcher gives them), not a region centre's;
``region-<rid>`` on its region's answers, picture, primary token and centre tokens, the health/alive keys of its centre
(``<rid>``) and of its standby (``<rid>-standby``: :func:`fedtrack.keys.standby_id`) and on its own hand-over keys
(``region/*/handover/<rid>``: it hands tracks to any neighbour, as itself), not on another region's
outputs;
``router`` (another host's router joined by ``router_connect``, forwarding its own clients'
messages) on anything of the deployment; the others on their health/alive keys. A denied put is
dropped at the router: nobody receives it.
"""

from __future__ import annotations

from typing import Any

from fedtrack.config import ConfigError
from fedtrack.keys import AREA_CENTRE_ID, FUSION_CENTER_ID, MERGER_ID, Keys, standby_id

OWN_MESSAGES = ["put", "delete", "reply", "declare_queryable", "liveliness_token"]
READ_MESSAGES = ["declare_subscriber", "query"]  # each identity on what its roles read (read_keys)
TOKEN_READS = ["liveliness_query", "declare_liveliness_subscriber"]  # every identity, every token
ALL_MESSAGES = OWN_MESSAGES + READ_MESSAGES + TOKEN_READS
LAUNCHER = "launcher"
ROUTER = "router"
SENSOR_ROLES = ("sensor", "local-filter", "mtt-local")  # run on the sensor's host, under its identity
CENTRE_ROLES = ("fusion-center", "mtt-centre", "picture")  # identity ``fusion`` (a region centre: ``region-<rid>``)
REGION_PREFIX = "region-"
# the services run as ``fusion`` (their ids the launcher's): it speaks (health, liveliness) for these only. It
# might for every ``<role>/*``: a region centre's Health (a final ``stopped`` made a SIGKILL at its stop no failure,
# its counters in the summary) and its ``alive`` token (the launcher's readiness wait) were forged by ``fusion``
FUSION_SERVICES = [("fusion-center", FUSION_CENTER_ID), ("mtt-centre", AREA_CENTRE_ID),
                   ("mtt-centre", standby_id(AREA_CENTRE_ID)), ("picture", MERGER_ID)]


def identity(role: str, service_id: str, region: str | None = None) -> str:
    """The certificate common name of a service (see the module docstring; a local filter's or local
    multi-target tracker's id is its sensor's; a centre of ``region``, primary or standby, is the region's)."""
    if role in SENSOR_ROLES:
        return f"sensor-{service_id}"
    if role == "mtt-centre" and region is not None:
        return REGION_PREFIX + region
    return "fusion" if role in CENTRE_ROLES else role


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


def own_keys(keys: Keys, ident: str) -> list[str]:
    """The keys ``ident`` may publish on (health and liveliness of its roles included)."""
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        data = [keys.sensor_meas(sid), keys.local_estimate(sid), keys.mtt_report(sid), keys.region_report(None, sid)]
        roles = [(role, sid) for role in SENSOR_ROLES]
    elif ident == "fusion":
        data = [keys.fusion_track().rsplit("/", 1)[0] + "/**", keys.primary("all"),  # the one centre's tokens
                keys.region_centre("all")]
        roles = FUSION_SERVICES
    elif ident.startswith(REGION_PREFIX):  # a region's centres: the region's id and its standby's
        rid = ident.removeprefix(REGION_PREFIX)
        data = [keys.region_resets(rid), keys.region_handover(None, rid), keys.region_picture(rid), keys.primary(rid),
                keys.region_centre(rid)]
        roles = [("mtt-centre", rid), ("mtt-centre", standby_id(rid))]
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
    (lockstep pacing) and ``fusion/state`` (a local filter's rejoin); a region's its region's keys, the
    hand-overs to it and its own (a standby watches its primary's); the launcher's monitor the tracks,
    measurements, health and pictures it summarises; ``fusion`` (the centres and the merger), the
    recorder and another host's router every key. Every identity could read every key: one whose
    session stops reading its link held up each publisher it reads for the router's
    ``wait_before_close``, so it now can only those it reads."""
    if ident.startswith("sensor-"):
        sid = ident.removeprefix("sensor-")
        read = [keys.sensor_meas(sid), keys.fusion_reset(sid), keys.mtt_resets(sid), keys.region_resets(None, sid),
                keys.fusion_track(), keys.tracker_track(None, sid), keys.fusion_state()]
    elif ident.startswith(REGION_PREFIX):
        rid = ident.removeprefix(REGION_PREFIX)
        read = [keys.region_report(rid), keys.region_handover(rid), keys.region_handover(None, rid),
                keys.region_picture(rid), keys.region_resets(rid)]
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
