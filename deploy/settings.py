"""The deployment tables of the configuration file, as ``launch`` and ``demo`` read them.

Every table is optional; unknown tables or keys fail at start naming the file, the table
and the key. ``launch`` checks every table of the file (also ``[imm]`` and ``[pda]``, which
it does not use itself), so that a typo fails before any process starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError, in_file, load_tables
from fedtrack.deploy.security import ZenohSettings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.pda.replay import PDAReplayConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.radar import RadarConfig
from fedtrack.sensors.sonar import SonarConfig


@dataclass(frozen=True)
class Settings:
    """``[fusion]``, ``[deployment]``, ``[[sensor]]``; ``[sonar]`` / ``[radar]`` for those sensor
    kinds, ``[radar_filter]`` (checked by the radar filter chosen with ``--filter``), ``[imm]``
    and ``[pda]``; ``[zenoh]`` (the services' Zenoh configuration, :mod:`fedtrack.deploy.security`)."""

    fusion: FusionConfig = field(default_factory=FusionConfig)
    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    sensor: tuple[SensorConfig, ...] = ()
    sonar: SonarConfig = field(default_factory=SonarConfig)
    radar: RadarConfig = field(default_factory=RadarConfig)
    radar_filter: Any = None
    imm: IMMConfig = field(default_factory=IMMConfig)
    pda: PDAReplayConfig = field(default_factory=PDAReplayConfig)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)


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
        if users and not ids and not settings.fusion.sensors:
            raise ConfigError(f"sensor: no [[sensor]] table, but the services {', '.join(sorted(users))} "
                              "need at least one sensor")


def load_settings(path: Path | None) -> Settings:
    """Parse a config file (or the defaults when ``path`` is None)."""
    return load_tables(path, Settings)
