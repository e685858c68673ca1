"""Configuration of the PDA trackers (``[pda.tracker]``, ``[pda.existence]``): dataclasses only,
so that loading a deployment's settings imports none of the trackers' maths (and its scipy).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError, load_tables, require_finite_keys


@dataclasses.dataclass(frozen=True)
class PDAParams:
    """Data-association parameters shared by PDA-AI and HPDA (TOML table ``[tracker]``).

    ``clutter_density`` is lambda, the density of clutter detections *after* thresholding
    (per m^2); the threshold tau follows from ``pd`` and ``snr`` (assumption 3), so
    ``P_FA = exp(-tau)`` only normalizes the clutter amplitude density.
    """

    pd: float = 0.9
    clutter_density: float = 2.5e-5
    snr: float = 20.0
    gate: float = 9.21
    sigma_a: float = 0.01
    tau_s: float = 500.0
    max_accel: float = 0.0  # m/s^2, the targets' largest acceleration: > 0 adds a maneuver model (IMM)

    def validate(self) -> None:
        require_finite_keys(self, ("clutter_density", "snr", "gate", "sigma_a", "tau_s"))  # inf passed their > 0 checks
        if not 0.0 < self.pd < 1.0:
            raise ConfigError(f"pd: must lie in (0, 1), got {self.pd}")
        if not self.clutter_density > 0.0:
            raise ConfigError(f"clutter_density: must be > 0, got {self.clutter_density}")
        if not self.snr >= 0.0:
            raise ConfigError(f"snr: must be >= 0, got {self.snr}")
        for name in ("gate", "sigma_a", "tau_s"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.max_accel < np.inf:
            raise ConfigError(f"max_accel: must be a finite number >= 0 (0: no maneuver model), got {self.max_accel}")

    @property
    def sigmas(self) -> tuple[float, ...]:
        """The Singer models' ``sigma_a``: the paper's, and with ``max_accel`` a maneuver model's
        ``max_accel / sqrt(3)`` (Singer's rule ``A_max^2 (1 + 4 P_max - P_0) / 3`` with ``P_max = P_0 = 0``:
        accelerations uniform over ``[-A_max, A_max]``)."""
        return (self.sigma_a,) if self.max_accel == 0.0 else (self.sigma_a, self.max_accel / np.sqrt(3.0))


@dataclasses.dataclass(frozen=True)
class ExistenceConfig:
    """Existence and initiation parameters (TOML table ``[existence]``)."""

    p11: float = 0.98
    p21: float = 0.0
    initial_existence: float = 0.2
    confirm_threshold: float = 0.6
    confirm_scans: int = 3
    delete_threshold: float = 0.02
    max_speed: float = 10.0
    max_tentative: int = 200
    false_track_rate: float = 0.01
    one_track_per_detection: bool = True
    clutter_from_scans: bool = True
    supported_streak: bool = True
    amplitude_existence: bool = True

    def evidence_threshold(self, births: int) -> float:
        """``log(births / false_track_rate)``; ``-inf`` with the test off."""
        if self.false_track_rate == 0.0:
            return -np.inf
        return float(np.log(births / self.false_track_rate))

    def validate(self) -> None:
        for name in ("p11", "p21"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name}: must lie in [0, 1], got {getattr(self, name)}")
        for name in ("initial_existence", "confirm_threshold", "delete_threshold"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ConfigError(f"{name}: must lie in (0, 1), got {getattr(self, name)}")
        # a track is born at initial_existence, deleted below delete_threshold, confirmed above confirm_threshold
        # (local_filters/pda/tracks.py): born at or below the deletion, a track must jump past it at its first update or
        # go (delete_threshold 0.9 confirmed none of 61 sonar scans' tracks); born at or above the confirmation, the
        # threshold asks no evidence of it
        if not self.delete_threshold < self.initial_existence < self.confirm_threshold:
            raise ConfigError(f"delete_threshold, initial_existence, confirm_threshold: must rise in that order "
                              f"(delete < initial < confirm), got {self.delete_threshold:g}, "
                              f"{self.initial_existence:g}, {self.confirm_threshold:g}")
        if self.confirm_scans < 1:
            raise ConfigError(f"confirm_scans: must be >= 1, got {self.confirm_scans}")
        if self.max_tentative < 1:
            raise ConfigError(f"max_tentative: must be >= 1, got {self.max_tentative}")
        require_finite_keys(self, ("max_speed",))
        if not self.max_speed > 0.0:
            raise ConfigError(f"max_speed: must be > 0, got {self.max_speed}")
        if not self.false_track_rate >= 0.0:
            raise ConfigError(f"false_track_rate: must be >= 0, got {self.false_track_rate}")


@dataclasses.dataclass(frozen=True)
class PDAReplayConfig:
    """The ``[pda]`` table: ``[pda.tracker]`` (:class:`PDAParams`) and ``[pda.existence]``."""

    tracker: PDAParams = PDAParams()
    existence: ExistenceConfig = ExistenceConfig()


@dataclasses.dataclass(frozen=True)
class PDASettings:
    """The table the PDA replay and ``serve hpda`` read from the configuration file."""

    pda: PDAReplayConfig = PDAReplayConfig()


def load_config(path: Path | None) -> PDAReplayConfig:
    """Strict config (unknown keys fail, naming the file, table and key); defaults without a file."""
    return load_tables(path, PDASettings).pda
