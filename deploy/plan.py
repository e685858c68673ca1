"""The plan of a host's service processes for ``fedtrack launch`` and ``fedtrack demo``: which
``fedtrack serve`` processes this host starts and with which arguments, the Zenoh / TLS
configuration each is given (``[zenoh]``), the sensors' common start time and the failover scopes.
No process is started here (:mod:`fedtrack.deploy.launcher` runs the plan)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from fedtrack.atomic import write_atomic
from fedtrack.config import in_file
from fedtrack.deploy.access_control import LAUNCHER, identity
from fedtrack.deploy.certificates import check_router_names
from fedtrack.deploy.multitarget import SCENARIO_DIR, sensor_ids, service_args
from fedtrack.deploy.security import host_endpoints, router_limits, write_configs
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import ROLES
from fedtrack.keys import FUSION_CENTER_ID, Keys, standby_id
from fedtrack.local_filters.mtt.service import RESET_TIMEOUT_S
from fedtrack.local_filters.regions import load_regions

SNAPSHOT = "fusion-center.snapshot"  # the fusion center's state, for its restarts within this run
PICTURE_SNAPSHOT = "picture.snapshot"  # serve picture's last merged time, for its restarts within this run
NUMBERS = "{sid}.numbers"  # a region centre's reserved track ids and hand-over numbers, for its restarts in this run
START_FILE = "start-at"  # beside the sensors' logs: their common start time, written once all are ready


@dataclass
class ServiceProcess:
    """One process of the plan: its role, service id, command line and log file, and once started
    its ``proc``."""

    role: str
    id: str
    argv: list[str]
    log_path: Path
    proc: subprocess.Popen[bytes] | None = None
    kill_at_s: float | None = None  # scenario seconds: SIGKILLed then, never restarted (``kill_at``)
    killed: bool = False

    @property
    def name(self) -> str:
        """``role/id``, as the launcher's lines and summary name the process."""
        return f"{self.role}/{self.id}"

    @property
    def region(self) -> str | None:
        """The region of a region centre (``--region RID``), else None."""
        return self.argv[self.argv.index("--region") + 1] if "--region" in self.argv else None

    @property
    def standby(self) -> bool:
        """Whether it is a hot standby (``--standby``)."""
        return "--standby" in self.argv

    def log_tail(self, lines: int = 15) -> str:
        """The last ``lines`` lines of its log, or ``(no log)``."""
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


def service_plan(settings: Settings, config_path: Path, out_dir: Path, log_dir: Path,
                 recorder_exports: bool = True) -> list[ServiceProcess]:
    """The processes this host starts, in start order (sensors last). The recorder writes
    ``out_dir``'s JSON Lines files itself when it stops (``--out``) unless ``recorder_exports``
    is false: ``fedtrack launch`` writes them once everything has stopped."""
    dep = settings.deployment
    connect = [a for ep in dep.connect_endpoints for a in ("--connect", ep)]
    common = ["--deployment", dep.name, *connect]
    base = [sys.executable, "-m", "fedtrack.cli", "serve"]
    sensors = [s.id for s in settings.sensor]
    here = [s for s in sensors if dep.local_sensors is None or s in dep.local_sensors]
    plan: list[ServiceProcess] = []
    exports = ["--out", str(out_dir)] if recorder_exports else []

    def add(role: str, sid: str, args: list[str]) -> None:
        plan.append(ServiceProcess(role, sid, base + [role, "--id", sid] + args,
                                   log_dir / f"{role}-{sid}.log"))

    if "router" in dep.services and dep.router_listen:
        peers = [a for ep in dep.router_connect for a in ("--connect", ep)]
        add("router", "router", ["--deployment", dep.name, "--listen", dep.router_listen, *peers])
    cfg = ["--config", str(config_path)]
    if settings.multitarget is not None:
        if "recorder" in dep.services:
            add("recorder", "recorder", ["--db", str(out_dir / "recording.db"), *exports, *common])
        mt = settings.multitarget
        for role, sid, args in service_args(settings, out_dir / SCENARIO_DIR / "measurements.jsonl",
                                            load_regions(config_path)):
            if runs_here(settings, role, sid, args):
                snapshot = ["--snapshot", str(out_dir / PICTURE_SNAPSHOT)] if role == "picture" else []
                add(role, sid, [*args, *cfg, *common, *snapshot, *numbers_args(out_dir, sid, args)])
                if role in ("sensor", "mtt-local"):
                    plan[-1].kill_at_s = mt.kill_at.get(sid)
                if role == "mtt-centre" and mt.standby:
                    standby = standby_id(sid)
                    add(role, standby, [*args, *cfg, *common, "--standby", *numbers_args(out_dir, standby, args)])
        return plan
    if "local-filter" in dep.services:
        for s in here:
            add("local-filter", s, ["--sensor", s, *cfg, *common])
    if "fusion-center" in dep.services:
        add("fusion-center", FUSION_CENTER_ID, [*cfg, *common, "--snapshot", str(out_dir / SNAPSHOT)])
    if "recorder" in dep.services:
        add("recorder", "recorder", ["--db", str(out_dir / "recording.db"), *exports, *common])
    if "sensor" in dep.services:
        for s in here:
            add("sensor", s, [*cfg, *common])
    return plan


def numbers_args(out_dir: Path, sid: str, args: list[str]) -> list[str]:
    """A region centre's ``--numbers`` file (its own per process id: a standby numbers as itself), else none."""
    return ["--numbers", str(out_dir / NUMBERS.format(sid=sid))] if "--region" in args else []


def runs_here(settings: Settings, role: str, sid: str, args: list[str]) -> bool:
    """Whether this host runs a multi-target service: its role is in ``deployment.services``, a
    sensor's services only for ``local_sensors``, a region's centre only for ``local_regions``."""
    dep = settings.deployment
    if role in ("sensor", "mtt-local") and sid not in here_mtt(settings):
        return False
    region = args[args.index("--region") + 1] if "--region" in args else None
    if region is not None and dep.local_regions is not None and region not in dep.local_regions:
        return False
    return role in dep.services or role not in ROLES


def here_mtt(settings: Settings) -> list[str]:
    """The multi-target scenario's sensors this host runs (``deployment.local_sensors``, default all)."""
    assert settings.multitarget is not None
    ids = sensor_ids(settings.multitarget)
    local = settings.deployment.local_sensors
    return [s for s in ids if local is None or s in local]


def apply_zenoh_settings(settings: Settings, config_path: Path, out_dir: Path,
                         plan: list[ServiceProcess]) -> str | None:
    """Hand every service of ``plan`` its Zenoh configuration (``[zenoh]`` table, see
    :mod:`fedtrack.deploy.security`) with ``--zenoh-config``; returns the launcher monitor's file."""
    dep = settings.deployment

    def ident(sp: ServiceProcess) -> str:
        return identity(sp.role, sp.id, sp.region)

    if settings.zenoh.insecure:  # the file's explicit opt-out, which every ``serve`` then needs off loopback
        for sp in plan:
            sp.argv = [*sp.argv, "--insecure"]
    here = sorted({ident(sp) for sp in plan})  # the certificates this host needs (other hosts hold theirs)
    sensors = sensor_ids(settings.multitarget) if settings.multitarget is not None else [s.id for s in settings.sensor]
    regions = load_regions(config_path) if settings.multitarget is not None else None
    centres = [identity("mtt-centre", rid, rid) for rid in (regions.ids if regions is not None else ())]
    everyone = sorted({*here, *(identity("sensor", sid) for sid in sensors), *centres, "router", "fusion", "recorder"})
    with in_file(config_path):
        paths = write_configs(settings.zenoh, config_path.parent, Keys(dep.name), here, out_dir, everyone,
                              router_limits(dep.deadline_s, RESET_TIMEOUT_S))
        if settings.zenoh.tls_dir is not None:
            check_router_names((config_path.parent / settings.zenoh.tls_dir).resolve(), host_endpoints(dep))
    if not paths:
        return None
    for sp in plan:
        sp.argv = [*sp.argv, "--zenoh-config", str(paths[ident(sp)])]
    return str(paths[LAUNCHER])


def await_start(sensors: list[ServiceProcess]) -> Path | None:
    """Have the ``sensors`` wait, once ready, for their common start time in one file
    (``START_FILE`` beside their logs, an earlier run's removed): ``--start-file``; returns the file."""
    if not sensors:
        return None
    path = sensors[0].log_path.parent / START_FILE
    path.unlink(missing_ok=True)
    for sp in sensors:
        sp.argv = [*sp.argv, "--start-file", str(path)]
    return path


def release_sensors(sensors: list[ServiceProcess], path: Path | None, start_at: float) -> float:
    """Give the ``sensors`` one wall-clock start time (realtime pacing schedules scan k at
    start + k T / speed, so they stay in step and do not drift; lockstep pacing sends scan 0 then, so
    that none is fused before a sensor still starting could send its own): written to ``path`` for those
    waiting on it, and ``--start-at`` instead of ``--start-file`` for their later starts
    (restarts); returns it."""
    if path is not None:
        write_atomic(path, f"{start_at:.6f}\n".encode())
    for sp in sensors:
        if "--start-file" in sp.argv:
            i = sp.argv.index("--start-file")
            sp.argv = [*sp.argv[:i], *sp.argv[i + 2:]]
        sp.argv = [*sp.argv, "--start-at", f"{start_at:.6f}"]
    return start_at


def failover_scopes(settings: Settings, config_path: Path) -> frozenset[str]:
    """The scopes of a deployment's multi-target centres (their primary tokens' second-last chunk):
    each region of ``[regions]``, or ``all`` for the one centre; none without ``[multitarget]``, and none
    without its ``standby = true``: a centre's token going is then its end, no failover (host A of
    deploy/multihost-regions/, run in its documented order, reported host C's centre stopping as
    'failover of x1y0 ... took over after - s')."""
    if settings.multitarget is None or not settings.multitarget.standby:
        return frozenset()
    regions = load_regions(config_path)
    return frozenset(regions.ids) if regions is not None else frozenset({"all"})


