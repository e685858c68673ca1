"""Active-sonar scans in clutter with amplitude information (paper 001, assumptions 1-7).

Each scan holds the target detection (probability ``P_D``) and Poisson clutter of density
``lambda`` per m^2 (counted *after* thresholding) uniform over a region. Amplitudes are
exponential (target mean ``1 + rho``, clutter mean 1), kept above the threshold ``tau``:
``P_D = exp(-tau / (1 + rho))``, ``P_FA = exp(-tau)``. By memorylessness the amplitude of a
thresholded detection is ``tau + Exp(mean)``.

The batched helpers take a leading Monte Carlo axis; :func:`sonar_scans` is the one-scan-
at-a-time generator (replay-format lines plus the truth) for services.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Iterator, NamedTuple

import numpy as np

from fedtrack.config import ConfigError, require_finite_keys

G0 = 9.80665  # standard gravity, m/s^2


@dataclasses.dataclass(frozen=True)
class ScenarioConfig:
    """The paper's target: (5000, 4000) m, 4 m/s, T = 25 s, 1500 s, -0.001 g from 800 s.

    The paper gives neither the heading nor the maneuver axis: the target heads along +x
    and the -0.001 g acceleration acts along y (a slow turn), see docs/hpda.md.
    """

    start: tuple[float, float] = (5000.0, 4000.0)
    velocity: tuple[float, float] = (4.0, 0.0)
    T: float = 25.0
    duration: float = 1500.0
    maneuver_start: float = 800.0
    maneuver_accel: tuple[float, float] = (0.0, -0.001 * G0)

    def validate(self) -> None:
        require_finite_keys(self, ("start", "velocity", "T", "duration", "maneuver_start", "maneuver_accel"))
        if not self.T > 0.0:
            raise ConfigError(f"T: must be > 0, got {self.T}")
        if not self.duration >= self.T:
            raise ConfigError(f"duration: must be >= T, got {self.duration}")


@dataclasses.dataclass(frozen=True)
class SonarConfig:
    """A simulated cluttered sonar (TOML table ``[sonar]``)."""

    sensor: str = "sonar1"
    pd: float = 0.9
    clutter_density: float = 2.5e-5
    snr: float = 20.0
    sigma_r: float = 15.0
    region_half_width: float = 1000.0
    blackout_scans: int = 0
    scenario: ScenarioConfig = ScenarioConfig()

    def validate(self) -> None:
        require_finite_keys(self, ("clutter_density", "snr", "sigma_r", "region_half_width"))  # inf passed (tour62)
        if not 0.0 < self.pd < 1.0:
            raise ConfigError(f"pd: must lie in (0, 1), got {self.pd}")
        for name in ("clutter_density", "sigma_r", "region_half_width"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: must be > 0, got {getattr(self, name)}")
        if not self.snr >= 0.0:
            raise ConfigError(f"snr: must be >= 0, got {self.snr}")
        if self.blackout_scans < 0:
            raise ConfigError(f"blackout_scans: must be >= 0, got {self.blackout_scans}")

    @property
    def tau(self) -> float:
        """Amplitude threshold from ``P_D = exp(-tau / (1 + rho))`` (assumption 3)."""
        return float(-(1.0 + self.snr) * np.log(self.pd))


def truth_states(sc: ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
    """Scan times (K,) and true states (K, 6) in CA order ``[x, vx, ax, y, vy, ay]``.

    Constant velocity, then constant acceleration from ``maneuver_start`` (exact kinematics).
    """
    t = np.arange(0.0, sc.duration + 0.5 * sc.T, sc.T)
    p0, v0, a = (np.asarray(v, dtype=float) for v in (sc.start, sc.velocity, sc.maneuver_accel))
    dt = np.maximum(t - sc.maneuver_start, 0.0)[:, None]
    on = (t >= sc.maneuver_start)[:, None]
    pos = p0 + v0 * t[:, None] + 0.5 * a * dt**2
    vel = v0 + a * dt
    acc = np.where(on, a, 0.0)
    x = np.stack([pos[:, 0], vel[:, 0], acc[:, 0], pos[:, 1], vel[:, 1], acc[:, 1]], axis=-1)
    return t, x


class Detections(NamedTuple):
    """One scan per batch item, padded: positions (..., M, 2), amplitudes, validity mask."""

    z: np.ndarray
    amplitude: np.ndarray
    valid: np.ndarray


def target_detections(rng: np.random.Generator, pos: np.ndarray, pd: float, snr: float,
                      tau: float, sigma_r: float) -> Detections:
    """The target's detection per batch item (M = 1): detected w.p. ``P_D``, noisy position."""
    shape = pos.shape[:-1]
    z = pos + sigma_r * rng.standard_normal(pos.shape)
    amp = tau + rng.exponential(1.0 + snr, size=shape)
    detected = rng.random(shape) < pd
    return Detections(z[..., None, :], amp[..., None], detected[..., None])


def clutter_in_boxes(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, density: float,
                     tau: float) -> Detections:
    """Poisson clutter of ``density`` per m^2 uniform in boxes ``[lo, hi]`` (B, 2), padded."""
    area = np.prod(np.maximum(hi - lo, 0.0), axis=-1)
    count = np.asarray(rng.poisson(density * area))
    n_max = int(np.max(count, initial=0))
    u = rng.random(lo.shape[:-1] + (n_max, 2))
    z = lo[..., None, :] + u * (hi - lo)[..., None, :]
    amp = tau + rng.exponential(1.0, size=lo.shape[:-1] + (n_max,))
    valid = np.arange(n_max) < count[..., None]
    return Detections(z, amp, valid)


def concat(a: Detections, b: Detections) -> Detections:
    """Join two padded detection sets along the detection axis."""
    return Detections(np.concatenate([a.z, b.z], axis=-2),
                      np.concatenate([a.amplitude, b.amplitude], axis=-1),
                      np.concatenate([a.valid, b.valid], axis=-1))


def scan(rng: np.random.Generator, config: SonarConfig, k: int, x_true: np.ndarray) -> Detections:
    """Scan ``k`` (unpadded, all valid): target unless blacked out, clutter in the region."""
    pos = x_true[[0, 3]]
    clu = clutter_in_boxes(rng, pos - config.region_half_width, pos + config.region_half_width,
                           config.clutter_density, config.tau)
    if k >= config.blackout_scans:
        tgt = target_detections(rng, pos, config.pd, config.snr, config.tau, config.sigma_r)
        clu = concat(tgt, clu)
    keep = clu.valid
    return Detections(clu.z[keep], clu.amplitude[keep], clu.valid[keep])


def sonar_scans(config: SonarConfig, seed: int) -> Iterator[dict[str, Any]]:
    """Yield one replay-format line per scan plus ``truth`` (the true CA state).

    ``{"t", "sensor", "kind": "sonar", "z": [], "detections": [{"z", "amplitude"}], "R",
    "truth"}`` (without ``truth`` it is what ``fedtrack.wire.measurement_from_replay``
    reads). Clutter is uniform over the square of half-width ``region_half_width`` centred
    on the true target; the target is not detected during the first ``blackout_scans`` scans.
    """
    rng = np.random.default_rng(seed)
    times, states = truth_states(config.scenario)
    R = (config.sigma_r**2 * np.eye(2)).tolist()
    for k, (t, x) in enumerate(zip(times, states)):
        dets = scan(rng, config, k, x)
        order = rng.permutation(dets.z.shape[0])
        yield {
            "t": float(t),
            "sensor": config.sensor,
            "kind": "sonar",
            "z": [],
            "detections": [{"z": dets.z[j].tolist(), "amplitude": float(dets.amplitude[j])}
                           for j in order],
            "R": R,
            "truth": x.tolist(),
        }
