"""The top-level TOML configuration shared by `replay`, `launch` and `demo`.

Every section is optional; unknown sections or keys fail at start naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fedtrack.config import load_toml, parse_dataclass
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.radar import RadarConfig
from fedtrack.sensors.sonar import SonarConfig


@dataclass(frozen=True)
class Settings:
    """``[fusion]``, ``[deployment]``, ``[[sensor]]``; ``[sonar]`` / ``[radar]`` for those sensor
    kinds and ``[radar_filter]`` (checked by the radar filter chosen with ``--filter``)."""

    fusion: FusionConfig = field(default_factory=FusionConfig)
    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    sensor: tuple[SensorConfig, ...] = ()
    sonar: SonarConfig = field(default_factory=SonarConfig)
    radar: RadarConfig = field(default_factory=RadarConfig)
    radar_filter: Any = None


def load_settings(path: Path | None) -> Settings:
    """Parse a config file (or the defaults when ``path`` is None)."""
    if path is None:
        return Settings()
    return parse_dataclass(Settings, load_toml(path))
