"""IMM configuration: model set, groups, transition matrix, noise, thresholds, prior.

Defaults are paper 000: the 13 acceleration modes of eq. (9), the 5 groups of eq. (10)
(first model = the group's centre, used by the activation logic) and the 13x13
transition matrix (11) as read in the errata (row = from). Any other set can be given
in the ``[imm]`` table of the configuration file (``[[imm.models]]``, ``[[imm.groups]]``);
unknown keys fail naming the file, the table and the key (``fedtrack.config.load_tables``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError, load_tables, require_finite_keys
from fedtrack.local_filters.imm.filter import (
    GROUP_PROBABILITY,
    TERMINATION_RULES,
    ModelBank,
    Thresholds,
    make_bank,
)


@dataclass(frozen=True)
class ModelSpec:
    """One mode: its name and known acceleration ``[ax, ay]`` in m/s^2 (paper 000 eq. (9))."""

    name: str
    acceleration: tuple[float, float]


@dataclass(frozen=True)
class GroupSpec:
    """A model group (paper 000 eq. (10)); its first model is the centre of the activation logic."""

    name: str
    models: tuple[str, ...]


def _paper_models() -> tuple[ModelSpec, ...]:
    acc = [(0, 0), (20, 0), (0, 20), (-20, 0), (0, -20), (20, 20), (-20, 20), (-20, -20),
           (20, -20), (40, 0), (0, 40), (-40, 0), (0, -40)]  # eq. (9)
    return tuple(ModelSpec(f"m{i + 1}", (float(a), float(b))) for i, (a, b) in enumerate(acc))


def _paper_groups() -> tuple[GroupSpec, ...]:
    members = [(1, 2, 3, 4, 5), (2, 10, 6, 1, 9), (3, 11, 7, 1, 6), (4, 12, 8, 1, 7),
               (5, 13, 9, 1, 8)]  # eq. (10)
    return tuple(GroupSpec(f"M{g + 1}", tuple(f"m{i}" for i in ms)) for g, ms in enumerate(members))


def paper_transition() -> np.ndarray:
    """The 13x13 transition matrix (11) as read in the errata (row = from, row-stochastic)."""
    Pi = np.zeros((13, 13))
    Pi[0, 0] = 116 / 120
    Pi[0, 1:5] = 1 / 120
    spokes = {1: (5, 8, 9), 2: (5, 6, 10), 3: (6, 7, 11), 4: (7, 8, 12)}  # m2..m5 -> 0.01 each
    for i, outs in spokes.items():
        Pi[i, 0], Pi[i, i] = 0.02, 0.95
        Pi[i, list(outs)] = 0.01
    for i, (a, b) in {5: (1, 2), 6: (2, 3), 7: (3, 4), 8: (1, 4)}.items():  # m6..m9
        Pi[i, [a, b]] = 1 / 30
        Pi[i, i] = 28 / 30
    for i in range(9, 13):  # m10..m13 -> m2..m5
        Pi[i, i - 8], Pi[i, i] = 0.1, 0.9
    return Pi


def _matrix_rows(Pi: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in row) for row in Pi)


@dataclass(frozen=True)
class IMMConfig:
    """Everything an IMM run needs besides the measurements (the ``[imm]`` table)."""

    models: tuple[ModelSpec, ...] = field(default_factory=_paper_models)
    groups: tuple[GroupSpec, ...] = field(default_factory=_paper_groups)
    transition: tuple[tuple[float, ...], ...] = field(
        default_factory=lambda: _matrix_rows(paper_transition()))
    q: float = 100.0  # process-noise variance per axis, Q = 10^2 I (paper 000 eq. (7))
    activation_threshold: float = 0.4  # t_a, eq. (8)
    termination_probability: tuple[float, float] = (0.85, 0.93)  # t_1^mu, t_2^mu, eq. (8)
    termination_likelihood_ratio: tuple[float, float] = (0.9, 1.0)  # t_1^L, t_2^L, eq. (8)
    termination_rule: str = GROUP_PROBABILITY  # or "as-printed" (see fedtrack.local_filters.imm.filter)
    initial_group: str = ""  # empty: the first group
    x0: tuple[float, float, float, float] | None = None  # [x, vx, y, vy]; None: from first z
    P0: tuple[tuple[float, ...], ...] | None = None
    initial_position_std: float = 1000.0  # m, when x0 is not given
    initial_velocity_std: float = 400.0  # m/s, when x0 is not given
    transition_interval: float = 1.0  # s: the sampling interval the transition matrix is given for

    def validate(self) -> None:
        # inf passed: an initial std made every estimate NaN (none written), x0's likewise (before tour62)
        require_finite_keys(self, ("transition_interval", "termination_likelihood_ratio", "x0", "P0",
                              "initial_position_std", "initial_velocity_std"))
        if not self.transition_interval > 0:
            raise ConfigError("transition_interval: must be > 0")
        names = [m.name for m in self.models]
        if not names:
            raise ConfigError("models: at least one model is required")
        if len(set(names)) != len(names):
            raise ConfigError("models: model names must be unique")
        for i, m in enumerate(self.models):
            if not np.all(np.isfinite(m.acceleration)):
                raise ConfigError(f"models[{i}].acceleration: must be finite")
        Pi = np.array(self.transition, dtype=float) if self.transition else np.zeros((0, 0))
        n = len(names)
        if Pi.shape != (n, n):
            raise ConfigError(f"transition: expected a {n}x{n} matrix for {n} models, got {Pi.shape}")
        if not np.all(np.isfinite(Pi)) or np.any(Pi < 0):
            raise ConfigError("transition: entries must be finite and non-negative")
        bad = np.flatnonzero(np.abs(Pi.sum(axis=1) - 1.0) > 1e-6)
        if bad.size:
            raise ConfigError(f"transition: row {int(bad[0])} sums to {Pi[bad[0]].sum():.6g}, not 1 (row = from)")
        if not self.groups:
            raise ConfigError("groups: at least one group is required")
        gnames = [g.name for g in self.groups]
        if len(set(gnames)) != len(gnames):
            raise ConfigError("groups: group names must be unique")
        centres = []
        for i, g in enumerate(self.groups):
            if not g.models:
                raise ConfigError(f"groups[{i}].models: empty group {g.name!r}")
            unknown = [m for m in g.models if m not in names]
            if unknown:
                raise ConfigError(f"groups[{i}].models: unknown model {unknown[0]!r}")
            if len(set(g.models)) != len(g.models):
                raise ConfigError(f"groups[{i}].models: repeated model in {g.name!r}")
            centres.append(g.models[0])
        if len(set(centres)) != len(centres):
            raise ConfigError("groups: two groups share the same centre (first) model")
        if self.initial_group and self.initial_group not in gnames:
            raise ConfigError(f"initial_group: unknown group {self.initial_group!r}")
        if not 0.0 <= self.activation_threshold < 1.0:
            raise ConfigError("activation_threshold: must be in [0, 1)")
        lo, hi = self.termination_probability
        if not 0.0 <= lo <= hi <= 1.0:
            raise ConfigError("termination_probability: need 0 <= t1 <= t2 <= 1")
        lo, hi = self.termination_likelihood_ratio
        if not 0.0 < lo <= hi:
            raise ConfigError("termination_likelihood_ratio: need 0 < t1 <= t2")
        if self.termination_rule not in TERMINATION_RULES:
            raise ConfigError(f"termination_rule: expected one of {', '.join(TERMINATION_RULES)}")
        if not (np.isfinite(self.q) and self.q > 0):
            raise ConfigError("q: must be a positive number")
        if self.initial_position_std <= 0 or self.initial_velocity_std <= 0:
            raise ConfigError("initial_position_std/initial_velocity_std: must be positive")
        if self.P0 is not None:
            P0 = np.array(self.P0, dtype=float)
            if P0.shape != (4, 4) or not np.allclose(P0, P0.T) or np.any(np.linalg.eigvalsh(P0) <= 0):
                raise ConfigError("P0: must be a symmetric positive-definite 4x4 matrix")

    def bank(self) -> ModelBank:
        names = tuple(m.name for m in self.models)
        index = {n: i for i, n in enumerate(names)}
        Pi = np.array(self.transition, dtype=float)
        return make_bank(names, np.array([m.acceleration for m in self.models], dtype=float),
                         Pi / Pi.sum(axis=1, keepdims=True),
                         tuple(tuple(index[m] for m in g.models) for g in self.groups),
                         tuple(g.name for g in self.groups))

    def thresholds(self) -> Thresholds:
        return Thresholds(self.activation_threshold, *self.termination_probability,
                          *self.termination_likelihood_ratio, self.termination_rule)

    def initial_group_index(self) -> int:
        return [g.name for g in self.groups].index(self.initial_group) if self.initial_group else 0


@dataclass(frozen=True)
class IMMSettings:
    """The table the IMM replay and ``serve imm`` read from the configuration file."""

    imm: IMMConfig = field(default_factory=IMMConfig)


def load_imm_config(path: Path | None) -> IMMConfig:
    """Paper defaults, overridden by the ``[imm]`` table of the file at ``path`` if given."""
    return load_tables(path, IMMSettings).imm
