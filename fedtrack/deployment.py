"""Deployment configuration: which services run, where they meet, how sensors are paced."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from fedtrack.config import ConfigError, in_file, load_tables, load_toml
from fedtrack.keys import DEFAULT_DEPLOYMENT

MODES = ("federated", "decentralized")
PACINGS = ("lockstep", "realtime")
ROLES = ("router", "sensor", "local-filter", "fusion-center", "recorder", "mtt-centre", "mtt-local", "picture")


@dataclass(frozen=True)
class SensorConfig:
    """One ``[[sensor]]`` table: a simulated position sensor."""

    id: str
    R: tuple[tuple[float, float], tuple[float, float]] = ((100.0, 5.0), (5.0, 100.0))

    def validate(self) -> None:
        if not self.id or any(c in self.id for c in "/*$?#@ "):
            raise ConfigError(f"id: {self.id!r} is not a valid sensor id (no '/', '*', '$', '?', '#', '@', spaces)")
        (a, b), (c, d) = self.R
        if not all(math.isfinite(v) for v in (a, b, c, d)) or b != c or a <= 0 or a * d - b * c <= 0:
            raise ConfigError("R: must be a finite symmetric positive-definite 2x2 matrix")


# [deployment] max_time_jump_s' default: the longest gap in a tracker's data it predicts across (a scan later is a
# broken or forged clock, or the data resuming after a pause: fedtrack.services.clock), and the longest a
# multi-target centre makes pictures for before its data (fedtrack.fusion_center.mtt.engines.PictureClock)
MAX_TIME_JUMP_S = 3600.0


@dataclass(frozen=True)
class DeploymentConfig:
    """The ``[deployment]`` table."""

    name: str = DEFAULT_DEPLOYMENT
    mode: str = "federated"
    scenario: int = 1
    seed: int = 1
    pacing: str = "lockstep"
    speed: float = 1.0
    deadline_s: float = 2.0
    max_seq_jump: int = 1000
    max_time_jump_s: float = MAX_TIME_JUMP_S
    duration_s: float = 100.0
    router_listen: str = "tcp/127.0.0.1:7447"
    router_connect: tuple[str, ...] = ()  # other hosts' routers this host's router joins (one router per host)
    connect: tuple[str, ...] | None = None
    services: tuple[str, ...] = ROLES
    local_sensors: tuple[str, ...] | None = None
    local_regions: tuple[str, ...] | None = None  # the region centres this host runs (default all)
    out: str = "fedtrack-out"
    ready_timeout_s: float = 30.0

    @property
    def connect_endpoints(self) -> tuple[str, ...]:
        """Where clients connect: ``connect`` if given, else this host's router."""
        if self.connect:
            return self.connect
        if not self.router_listen:
            raise ConfigError("connect: no endpoint to connect to (set deployment.connect or router_listen)")
        return (self.router_listen,)

    def validate(self) -> None:
        for role in self.services:
            if role not in ROLES:
                raise ConfigError(f"services: unknown role {role!r} (roles: {', '.join(ROLES)})")
        if not 0 < self.ready_timeout_s < math.inf:  # inf: launch's traceback (its Zenoh connect timeout; tour61)
            raise ConfigError("ready_timeout_s: must be finite and > 0")
        if self.mode not in MODES:
            raise ConfigError(f"mode: must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.pacing not in PACINGS:
            raise ConfigError(f"pacing: must be one of {', '.join(PACINGS)}, got {self.pacing!r}")
        if self.scenario not in (1, 2):
            raise ConfigError(f"scenario: paper 004 has scenarios 1 and 2, got {self.scenario}")
        if not 0 < self.speed < math.inf:
            raise ConfigError("speed: must be finite and > 0")
        if not 0 < self.deadline_s < math.inf:  # as serve fusion-center --deadline (tour60); inf passed (tour61)
            raise ConfigError("deadline_s: must be finite and > 0")
        if not 0 < self.duration_s < math.inf:
            raise ConfigError("duration_s: must be finite and > 0")
        if self.seed < 0:
            raise ConfigError(f"seed: must be a whole number >= 0, got {self.seed}")
        if not 0 < self.max_time_jump_s < math.inf:  # inf passed: no gap refused, no picture skipped (tour62)
            raise ConfigError("max_time_jump_s: must be finite and > 0")
        if not self.max_seq_jump >= 1:
            raise ConfigError("max_seq_jump: must be >= 1")
        if not self.name or any(c in self.name for c in "/*$?#@ "):
            raise ConfigError(f"name: {self.name!r} is not a valid deployment name")
        if self.router_listen:
            listen_address(self.router_listen, "router_listen")
        for endpoint in self.connect or ():
            listen_address(endpoint, "connect")
        for endpoint in self.router_connect:
            listen_address(endpoint, "router_connect")
        if self.router_connect and "router" not in self.services:
            raise ConfigError("router_connect: needs a router on this host (\"router\" in services)")


@dataclass(frozen=True)
class DeploymentTable:
    """The ``[deployment]`` table alone (what a replay reads of it)."""

    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)


def max_time_jump(config: Path | None) -> float:
    """``[deployment] max_time_jump_s`` of ``config`` (its default without a file): a replay
    starts its estimator again after a gap longer than this, where a live service rejects the
    measurement (predicting over it would leave the covariance meaningless)."""
    return load_tables(config, DeploymentTable).deployment.max_time_jump_s


def listen_address(endpoint: str, field: str) -> tuple[str, int]:
    """``(host, port)`` of a Zenoh endpoint ``PROTO/HOST:PORT``; a ConfigError naming ``field`` if malformed."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.partition("#")[0].rpartition(":")
    if not proto or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{field}: {endpoint!r} is not PROTO/HOST:PORT with a port in 1-65535")
    return host.strip("[]"), int(port)


def on_loopback(endpoint: str) -> bool:
    """True when a ``PROTO/HOST:PORT`` endpoint's host is this machine's loopback (127.0.0.0/8, ::1,
    localhost; a host name may resolve anywhere); a ConfigError if it is malformed."""
    import ipaddress

    host = listen_address(endpoint, "endpoint")[0]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def listen_problem(endpoint: str) -> str | None:
    """Why a TCP endpoint cannot be listened on here, None when it can (or it is no TCP endpoint): ``port N is
    already in use`` (another process holds it), or ``address H is not an address of this host`` (a file of another
    host, such as deploy/multihost's 10.47.0.1: before the tour58 session said to be a port in use).

    The probe binds as the Zenoh router does, with ``SO_REUSEADDR``: the connections of a run that
    just ended, left in TIME_WAIT for a minute, do not hold the port (a socket listening on it does)."""
    import errno
    import socket

    if not endpoint.startswith(("tcp/", "tls/")):
        return None
    host, port = listen_address(endpoint, "router_listen")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRNOTAVAIL:
                return f"address {host} is not an address of this host ({endpoint})"
            return f"port {port} is already in use ({endpoint})"
    return None


def port_in_use(endpoint: str) -> bool:
    """True when a TCP endpoint cannot be bound on this host (:func:`listen_problem`)."""
    return listen_problem(endpoint) is not None


@dataclass(frozen=True)
class DeploymentSettings:
    """Only the ``[deployment]`` table of a configuration file."""

    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)


def deployment_of(path: str | Path | None) -> DeploymentConfig | None:
    """The ``[deployment]`` table of the file at ``path``; None without a file or without that table."""
    if path is None or "deployment" not in load_toml(path):
        return None
    return load_tables(path, DeploymentSettings).deployment


def endpoints_of(path: str | Path, dep: DeploymentConfig) -> tuple[str, ...]:
    """Where a client of ``dep`` connects (errors name the file)."""
    with in_file(path):
        return dep.connect_endpoints
