"""The ``[fusion]`` table: configuration of the paper-004 fusion trackers and their local filters."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fedtrack.config import ConfigError, require_finite_keys
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.linear.tracking import equal_sharing, validate_sharing
from fedtrack.local_filters.vdie.estimation import VdieParams


@dataclass(frozen=True)
class FusionConfig:
    """Configuration of the fusion trackers (TOML table ``[fusion]``; see README)."""

    q: float = 0.25
    initial_velocity_std: float = 500.0
    sensors: tuple[str, ...] | None = None
    sharing: tuple[float, ...] | None = None
    x0: tuple[float, ...] | None = None
    P0: tuple[tuple[float, ...], ...] | None = None
    vdie: VdieParams = field(default_factory=VdieParams)

    def validate(self) -> None:
        # inf passed: q made every estimate NaN, initial_velocity_std a LinAlgError traceback (before tour62)
        require_finite_keys(self, ("q", "initial_velocity_std", "sharing", "P0"))
        if not self.q > 0:
            raise ConfigError("q: process noise must be > 0")
        if not self.initial_velocity_std > 0:
            raise ConfigError("initial_velocity_std: must be > 0")
        if self.sensors is not None and len(set(self.sensors)) != len(self.sensors):
            raise ConfigError("sensors: sensor ids must be unique")
        if self.sharing is not None and self.sensors is not None and len(self.sharing) != len(self.sensors):
            raise ConfigError(f"sharing: {len(self.sharing)} factors for {len(self.sensors)} sensors")
        if self.sharing is not None:
            try:
                validate_sharing(np.asarray(self.sharing))
            except ValueError as exc:
                raise ConfigError(f"sharing: {exc}") from exc
        if (self.x0 is None) != (self.P0 is None):
            raise ConfigError("x0: x0 and P0 must be given together")
        if self.x0 is not None:
            if len(self.x0) != 4 or not np.all(np.isfinite(self.x0)):
                raise ConfigError("x0: must be 4 finite numbers [x, vx, y, vy]")
            P0 = np.asarray(self.P0, dtype=float)
            if P0.shape != (4, 4) or not np.allclose(P0, P0.T) or np.any(np.linalg.eigvalsh(P0) <= 0):
                raise ConfigError("P0: must be a symmetric positive-definite 4x4 matrix")

    def betas(self, n_sensors: int) -> np.ndarray:
        if self.sharing is None:
            return equal_sharing(n_sensors)
        if len(self.sharing) != n_sensors:
            raise ConfigError(f"sharing: {len(self.sharing)} factors for {n_sensors} sensors")
        return np.asarray(self.sharing, dtype=float)


@dataclass(frozen=True)
class PipelineSettings:
    """The tables the fusion replay, the local filters and the fusion centre read.

    ``[radar_filter]`` is checked by the radar filter chosen with ``--filter``.
    """

    fusion: FusionConfig = field(default_factory=FusionConfig)
    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    sensor: tuple[SensorConfig, ...] = ()
    radar_filter: Any = None

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        """``[fusion] sensors`` if given, else the ``[[sensor]]`` ids in order."""
        return self.fusion.sensors or tuple(s.id for s in self.sensor)
