"""The deployment tables of the configuration file, as ``launch`` and ``demo`` read them.

Every table is optional; unknown tables or keys fail at start naming the file, the table
and the key. ``launch`` checks every table of the file (also ``[imm]``, ``[pda]`` and ``[regions]``,
which it does not use itself, or not in every deployment), so that a typo fails before any process starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError, did_you_mean, in_file, load_tables, load_toml
from fedtrack.deploy.security import ZenohSettings, check_transport
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.geodetic import FrameConfig, geodetic_error
from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.pda.config import PDAReplayConfig
from fedtrack.local_filters.radar.filters import check_radar_filter
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.multitarget import MAX_CLUTTER, Scenario
from fedtrack.sensors.radar import RadarConfig
from fedtrack.sensors.sonar import SonarConfig
from fedtrack.sensors.state_vectors import UNITS

MTT_ALGORITHMS = ("mtt-federated", "mtt-decentralized", "mtt-centralized")


@dataclass(frozen=True)
class MultitargetSettings:
    """``[multitarget]``: a live multi-target deployment and its simulated scenario (the options of
    ``fedtrack simulate multitarget``; the seed is ``deployment.seed``)."""

    algorithm: str = "mtt-federated"
    targets: int = 20
    sensors: str = "pos:1.0,pos:0.7,pos:1.3"
    duration: float = 60.0
    pd: float = 0.9
    clutter: float = 10.0
    half_width: float = Scenario.region  # m: the simulated square's half side (``simulate multitarget --half-width``)
    join_at: dict[str, float] = field(default_factory=dict)  # sensor -> scenario seconds it starts at
    kill_at: dict[str, float] = field(default_factory=dict)  # sensor -> scenario seconds it is killed at
    standby: bool = False  # a hot standby per centre (region), promoted when its primary dies (docs/deploy.md)
    # recorded air traffic instead of simulated targets (``fedtrack simulate traffic``'s options; docs/geodetic.md)
    source: str = ""  # the recording; empty: simulated targets
    # the common frame's WGS-84 origin; None with source: [frame] origin, else the window's (multitarget.prepare)
    origin: tuple[float, float, float] | None = None
    box: float = 100.0  # km
    start: float = 0.0  # s after the recording's first sample
    units: str = "si"  # the recording's units (``simulate traffic --units``: si or aviation, the traffic library's)

    def validate(self) -> None:
        if self.algorithm not in MTT_ALGORITHMS:
            raise ConfigError(f"algorithm: must be one of {', '.join(MTT_ALGORITHMS)}, got {self.algorithm!r}")
        for name, ok, rule in (("targets", self.targets >= 1, ">= 1"),
                               ("duration", 0 < self.duration < math.inf, "finite and > 0"),
                               ("pd", 0 < self.pd <= 1, "in (0, 1]"),
                               ("clutter", 0 <= self.clutter <= MAX_CLUTTER, f"in [0, {MAX_CLUTTER:.0f}]")):
            if not ok:
                raise ConfigError(f"{name}: must be {rule}, got {getattr(self, name):g}")
        if not 0 < self.half_width < math.inf:
            raise ConfigError(f"half_width: must be finite and > 0, got {self.half_width:g}")
        if self.units not in UNITS:
            raise ConfigError(f"units: must be one of {', '.join(sorted(UNITS))}, got {self.units!r}")
        if self.source and (not 0 < self.box < math.inf or not 0 <= self.start < math.inf):
            raise ConfigError("source: needs a finite box > 0 and a finite start >= 0")
        problem = None if self.origin is None else geodetic_error(*self.origin)
        if problem:  # the [frame] range: the scenario's config.toml carries it as [frame] origin
            raise ConfigError(f"origin: {problem}, got {list(self.origin)}")
        for key in ("join_at", "kill_at"):
            for sensor, t in getattr(self, key).items():
                if not 0 < t < self.duration:
                    raise ConfigError(f"{key}.{sensor}: must be inside the scenario (0, duration = {self.duration:g})")
        for sensor, t in self.kill_at.items():
            if self.join_at.get(sensor, 0.0) >= t:
                raise ConfigError(f"kill_at.{sensor}: must be after join_at.{sensor}")


@dataclass(frozen=True)
class Settings:
    """``[fusion]``, ``[deployment]``, ``[[sensor]]``; ``[sonar]`` / ``[radar]`` for those sensor
    kinds, ``[radar_filter]`` (its keys those of some radar filter; the one chosen with ``--filter`` reads its
    own), ``[imm]`` and ``[pda]``; ``[mtt]`` and ``[multitarget]`` (a live multi-target deployment,
    :mod:`fedtrack.deploy.multitarget`); ``[zenoh]`` (the services' Zenoh configuration, :mod:`fedtrack.deploy.security`)."""

    fusion: FusionConfig = field(default_factory=FusionConfig)
    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    sensor: tuple[SensorConfig, ...] = ()
    sonar: SonarConfig = field(default_factory=SonarConfig)
    radar: RadarConfig = field(default_factory=RadarConfig)
    radar_filter: Any = None
    imm: IMMConfig = field(default_factory=IMMConfig)
    pda: PDAReplayConfig = field(default_factory=PDAReplayConfig)
    mtt: MttConfig = field(default_factory=MttConfig)
    multitarget: MultitargetSettings | None = None
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    frame: FrameConfig | None = None  # [frame]: the common frame's WGS-84 origin and sensor sites (fedtrack.geodetic)


def check_launchable(settings: Settings, path: Path) -> None:
    """What ``launch`` must know before it starts any process (other commands read the same file
    for their own tables and need no sensors): a ConfigError naming ``path`` and the field."""
    ids = [s.id for s in settings.sensor]
    with in_file(path):
        for sid in ids:
            if ids.count(sid) > 1:
                raise ConfigError(f"sensor: duplicate id {sid!r} (each [[sensor]] needs its own id)")
        if settings.fusion.sensors is not None and len(settings.fusion.sensors) == 0:
            raise ConfigError("fusion.sensors: empty list (omit it to use the [[sensor]] ids)")
        users = {"sensor", "local-filter", "fusion-center"} & set(settings.deployment.services)
        if users and settings.multitarget is None and not ids and not settings.fusion.sensors:
            raise ConfigError(f"sensor: no [[sensor]] table, but the services {', '.join(sorted(users))} "
                              f"need at least one sensor{not_a_deployment(path)}")
        if settings.multitarget is None and ids:
            check_paper_sensors(settings, ids)
        check_local_regions(settings.deployment, load_regions(path))
        mt = settings.multitarget
        if (mt is not None and mt.source and mt.origin is not None and settings.frame is not None
                and settings.frame.origin != mt.origin):
            raise ConfigError(f"frame.origin: {list(settings.frame.origin)} is not multitarget.origin "
                              f"{list(mt.origin or ())}, "
                              "the frame the recording's scenario is simulated in (the tracks' lat, lon and lat_lon "
                              "regions would be placed in another)")
        check_transport(settings.zenoh, settings.deployment, path.parent)


def not_a_deployment(path: Path) -> str:
    """``" (FILE holds [imm] only: a replay config, ...)"``: what a file without any deployment table is for."""
    tables = sorted(load_toml(path))
    if {"deployment", "sensor", "multitarget", "fusion"} & set(tables):
        return ""
    return (f"; the file holds {', '.join(f'[{t}]' for t in tables) or 'no table'} only: a configuration for "
            "`fedtrack replay --config` or `fedtrack serve ROLE --config`, not a deployment to launch")


def check_paper_sensors(settings: Settings, ids: list[str]) -> None:
    """A paper deployment's sensors: ``[fusion] sensors`` and ``[deployment] local_sensors`` name
    ``[[sensor]]`` ids, and ``[fusion] sharing`` has a factor per sensor."""
    fused = settings.fusion.sensors or tuple(ids)
    for key, named in (("fusion.sensors", settings.fusion.sensors or ()),
                       ("deployment.local_sensors", settings.deployment.local_sensors or ())):
        stray = [sid for sid in named if sid not in ids]
        if stray:
            raise ConfigError(f"{key}: {stray[0]!r} is no [[sensor]] id ({', '.join(ids)})"
                              + did_you_mean(stray[0], ids))
    unfused = [sid for sid in ids if sid not in fused]
    if unfused:
        raise ConfigError(f"fusion.sensors: leaves out [[sensor]] {unfused[0]!r} (list every sensor the centre fuses)")
    sharing = settings.fusion.sharing
    if sharing is not None and len(sharing) != len(fused):
        raise ConfigError(f"fusion.sharing: {len(sharing)} factors for the {len(fused)} sensors "
                          f"{', '.join(fused)} (one factor per sensor)")


def check_local_regions(dep: DeploymentConfig, regions: Regions | None) -> None:
    """``[deployment] local_regions`` names regions of ``[regions]``."""
    if dep.local_regions is None:
        return
    if regions is None:
        raise ConfigError("deployment.local_regions: the file has no [regions] table to name regions of")
    stray = [rid for rid in dep.local_regions if rid not in regions.ids]
    if stray:
        raise ConfigError(f"deployment.local_regions: {stray[0]!r} is no region of [regions] "
                          f"({', '.join(regions.ids[:8])}{', ...' if len(regions.ids) > 8 else ''})"
                          + did_you_mean(stray[0], regions.ids))


def load_settings(path: Path | None) -> Settings:
    """Parse a config file (or the defaults when ``path`` is None), ``[regions]`` too (its keys and its
    geometry, :func:`~fedtrack.local_filters.regions.load_regions`), which its own consumers read."""
    settings = load_tables(path, Settings)
    if settings.radar_filter is not None:
        with in_file(path):
            check_radar_filter(settings.radar_filter)
    load_regions(path)
    return settings
