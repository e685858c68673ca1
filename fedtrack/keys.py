"""Zenoh key expressions of one deployment: ``fedtrack/<deployment>/...``.

Every key a service publishes, subscribes to or queries comes from :class:`Keys`;
no module builds key strings itself. Passing ``None`` for an id gives the
single-chunk wildcard ``*`` (for subscribers).

==============================  ===========================  =================
key (under fedtrack/<dep>/)     payload (fedtrack.wire)      publisher
==============================  ===========================  =================
sensor/<id>/meas                Measurement                  sensor <id>
local/<id>/estimate             LocalEstimate                local filter <id>
fusion/reset/<id>               Reset                        fusion center
fusion/track                    FusedTrack                   fusion center
fusion/event                    ManeuverEvent                fusion center
fusion/state (queryable)        FusedTrack (reply)           fusion center
health/<role>/<id>              Health                       every service
alive/<role>/<id> (liveliness)  none (token)                 every service
==============================  ===========================  =================

The multi-target keys (``local/<id>/tracks``, ``fusion/mtt-resets/<id>``, ``fusion/picture``) and,
with ``[regions]``, the region centres' ``region/<rid>/...`` keys are in docs/wire.md.
"""

from __future__ import annotations

from dataclasses import dataclass

ROOT = "fedtrack"
DEFAULT_DEPLOYMENT = "demo"  # also ``[deployment] name``'s: ``serve`` without --config, a config and the examples
MAX_ID_LENGTH = 64
_FORBIDDEN = frozenset("/*$?#")


# the ids the launcher gives the services run under the identity ``fusion``, the only ones that identity may speak
# for (health, liveliness; ``deploy/access_control.py``): the fusion center, the one multi-target centre of the whole
# area (and its standby, :func:`standby_id`) and the picture merger
FUSION_CENTER_ID, AREA_CENTRE_ID, MERGER_ID = "fusion", "centre", "picture"


def standby_id(centre: str) -> str:
    """The id of centre ``centre``'s hot standby (``launch``: ``serve mtt-centre --standby``), under the
    centre's identity (``deploy/access_control.py`` names it exactly)."""
    return f"{centre}-standby"


def is_identity_name(name: str) -> bool:
    """Whether ``name`` may name a TLS identity (its certificate's CN and files, ``deploy/certificates.py``):
    letters (of any script), digits, ``.``, ``_`` and ``-``."""
    return bool(name) and all(c.isalnum() or c in "._-" for c in name)


class InvalidName(ValueError):
    """A deployment, role or id that cannot be one key-expression chunk."""


def check_id(value: object, what: str = "id") -> str:
    """Return ``value`` if it is a usable key chunk, else raise :class:`InvalidName` naming ``what``.

    A chunk is a non-empty string of at most 64 printable characters without
    ``/ * $ ? #`` or whitespace.
    """
    if not isinstance(value, str):
        raise InvalidName(f"{what} must be a string, got {type(value).__name__}")
    if not value:
        raise InvalidName(f"{what} must not be empty")
    if len(value) > MAX_ID_LENGTH:
        raise InvalidName(f"{what} is longer than {MAX_ID_LENGTH} characters")
    bad = sorted({c for c in value if c in _FORBIDDEN or not c.isprintable() or c.isspace()})
    if bad:
        raise InvalidName(f"{what} {value!r} contains forbidden character(s) {''.join(bad)!r}")
    return value


@dataclass(frozen=True)
class Keys:
    """Key expressions of deployment ``deployment`` (validated on construction)."""

    deployment: str = DEFAULT_DEPLOYMENT

    def __post_init__(self) -> None:
        check_id(self.deployment, "deployment")

    def _key(self, *chunks: str) -> str:
        return "/".join((ROOT, self.deployment, *chunks))

    @staticmethod
    def _chunk(value: str | None, what: str) -> str:
        return "*" if value is None else check_id(value, what)

    def sender(self, key: str) -> str | None:
        """The sensor or service id a concrete key names as its publisher's (``sensor/<id>/meas``,
        ``local/<id>/estimate``, ``local/<id>/tracks``, ``fusion/reset/<id>``,
        ``fusion/mtt-resets/<id>``, ``health/<role>/<id>``, ``region/<rid>/local/<id>/tracks``,
        ``region/<rid>/mtt-resets/<id>``, ``region/<rid>/handover/<src>``: region ``<src>``), else None."""
        parts = key.split("/")
        if len(parts) < 4 or parts[0] != ROOT or parts[1] != self.deployment:
            return None
        rest = parts[2:]
        if len(rest) == 5 and rest[0] == "region" and (rest[2], rest[4]) == ("local", "tracks"):
            return rest[3]
        if len(rest) == 4 and rest[0] == "region" and rest[2] in ("mtt-resets", "handover"):
            return rest[3]
        if len(rest) == 3 and (rest[0], rest[2]) in (("sensor", "meas"), ("local", "estimate"), ("local", "tracks")):
            return rest[1]
        if len(rest) == 3 and rest[0] in ("health", "fusion") and (rest[0] == "health"
                                                                    or rest[1] in ("reset", "mtt-resets")):
            return rest[2]
        return None

    def region_of(self, key: str) -> str | None:
        """The region a concrete ``region/<rid>/...`` key is of, else None."""
        parts = key.split("/")
        if len(parts) >= 5 and parts[0] == ROOT and parts[1] == self.deployment and parts[2] == "region":
            return parts[3]
        return None

    def sensor_meas(self, sensor: str | None = None) -> str:
        """``sensor/<id>/meas``: a sensor's measurements."""
        return self._key("sensor", self._chunk(sensor, "sensor id"), "meas")

    def local_estimate(self, sensor: str | None = None) -> str:
        """``local/<id>/estimate``: the local filter of sensor ``<id>``."""
        return self._key("local", self._chunk(sensor, "sensor id"), "estimate")

    def fusion_reset(self, sensor: str | None = None) -> str:
        """``fusion/reset/<id>``: the fusion center's reset of local filter ``<id>``."""
        return self._key("fusion", "reset", self._chunk(sensor, "sensor id"))

    def mtt_report(self, sensor: str | None = None) -> str:
        """``local/<id>/tracks``: the local multi-target tracker of sensor ``<id>`` (``TrackReport``)."""
        return self._key("local", self._chunk(sensor, "sensor id"), "tracks")

    def mtt_resets(self, sensor: str | None = None) -> str:
        """``fusion/mtt-resets/<id>``: the multi-target centre's resets of sensor ``<id>``'s tracker."""
        return self._key("fusion", "mtt-resets", self._chunk(sensor, "sensor id"))

    def region_report(self, region: str | None = None, sensor: str | None = None) -> str:
        """``region/<rid>/local/<id>/tracks``: sensor ``<id>``'s tracker's sub-report for region ``<rid>``."""
        return self._key("region", self._chunk(region, "region id"), "local", self._chunk(sensor, "sensor id"), "tracks")

    def region_resets(self, region: str | None = None, sensor: str | None = None) -> str:
        """``region/<rid>/mtt-resets/<id>``: region ``<rid>``'s centre's answer to sensor ``<id>``'s sub-report."""
        return self._key("region", self._chunk(region, "region id"), "mtt-resets", self._chunk(sensor, "sensor id"))

    def region_handover(self, region: str | None = None, source: str | None = None) -> str:
        """``region/<rid>/handover/<src>``: central tracks region ``<src>``'s centre hands to region
        ``<rid>``'s (``HandOver``; one key per sender, which the access control ties to its identity)."""
        return self._key("region", self._chunk(region, "region id"), "handover", self._chunk(source, "region id"))

    def region_picture(self, region: str | None = None) -> str:
        """``region/<rid>/picture``: region ``<rid>``'s centre's picture (``TrackPicture``)."""
        return self._key("region", self._chunk(region, "region id"), "picture")

    def mtt_picture(self) -> str:
        """``fusion/picture``: the multi-target centre's track picture, every period (``TrackPicture``)."""
        return self._key("fusion", "picture")

    def fusion_track(self) -> str:
        """``fusion/track``: the fused track, one per scan."""
        return self._key("fusion", "track")

    def tracker_track(self, tracker: str | None = None, sensor: str | None = None) -> str:
        """``tracker/<tracker>/<sensor>/track``: a single-sensor tracker's tracks (``imm``, ``hpda``)."""
        return self._key("tracker", self._chunk(tracker, "tracker"), self._chunk(sensor, "sensor id"), "track")

    def fusion_event(self) -> str:
        """``fusion/event``: maneuver onset / model change / end events."""
        return self._key("fusion", "event")

    def fusion_state(self) -> str:
        """``fusion/state``: queryable answering with the latest fused track."""
        return self._key("fusion", "state")

    def health(self, role: str | None = None, service_id: str | None = None) -> str:
        """``health/<role>/<id>``: periodic :class:`fedtrack.wire.Health` of a service."""
        return self._key("health", self._chunk(role, "role"), self._chunk(service_id, "service id"))

    def primary(self, scope: str | None = None, instance: str | None = None) -> str:
        """``alive/mtt-primary/<scope>/<instance>``: liveliness token held by the primary centre of
        ``<scope>`` (a region, or ``all``); ``<instance>``: its claim (the claim's time, then its Zenoh
        session id: ``claim_instance``); of two, the later claim keeps it."""
        return self._key("alive", "mtt-primary", self._chunk(scope, "scope"), self._chunk(instance, "instance"))

    def region_centre(self, region: str | None = None, instance: str | None = None) -> str:
        """``alive/mtt-region/<rid>/<instance>``: liveliness token held by every centre of region ``<rid>``
        (``all``: the unsharded centre's), primary or standby, while it runs (``<instance>``: its Zenoh session
        id); ``serve picture`` does not wait for the picture of a region none holds, and a primary stopped
        mid-run steps aside for another holder."""
        return self._key("alive", "mtt-region", self._chunk(region, "region id"), self._chunk(instance, "instance"))

    def alive(self, role: str | None = None, service_id: str | None = None) -> str:
        """``alive/<role>/<id>``: liveliness token held while a service is ready."""
        return self._key("alive", self._chunk(role, "role"), self._chunk(service_id, "service id"))
