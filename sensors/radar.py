"""3-D radar: range / azimuth / elevation measurements of a target flying paper 002's scenario.

Measurement model (paper 002 eq. (39), paper 003 eq. (2) with atan2 per the errata)::

    r  = |d|,  az = atan2(d_y, d_x),  el = atan2(d_z, sqrt(d_x^2 + d_y^2)),  d = p - sensor

with independent zero-mean Gaussian noise per component; azimuth is wrapped to (-pi, pi].

Trajectory (paper 002 section 5, made geometrically exact): the paper asks for a 200 m/s turn
of radius 2000 m from A = (2000, 0, 500) to B = (-2000, 0, 500) reaching z = 1000 m, and calls
it "3 g". A planar circle through A and B with radius 2000 m has A and B as a diameter, so its
centre is C = (A + B)/2 = (0, 0, 500); it reaches z = 1000 m only if its plane is banked by
asin(500/2000) = 14.48 deg about the A-B line. The half circle A -> apex (0, 1936.5, 1000) -> B
satisfies every stated number; its centripetal acceleration is v^2/R = 20 m/s^2 = 2.04 g (not
3 g: the errata's "about 2 g"). A 10 s straight segment at the same speed, tangent at A,
precedes the turn, so the whole run is straight for ``straight_s`` then turns for pi R / v.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterator, NamedTuple

import numpy as np

from fedtrack.config import ConfigError, require_finite_keys
from fedtrack.local_filters.radar.measurement import polar_from_cartesian, wrap_angle

G0 = 9.80665  # standard gravity, m/s^2, used only to state accelerations in g


@dataclass(frozen=True)
class RadarConfig:
    """Radar and scenario parameters; defaults are paper 002's (section 5)."""

    rate_hz: float = 50.0
    sigma_range: float = 15.0
    sigma_azimuth: float = 0.002
    sigma_elevation: float = 0.002
    speed: float = 200.0
    start: tuple[float, float, float] = (2000.0, 0.0, 500.0)
    end: tuple[float, float, float] = (-2000.0, 0.0, 500.0)
    apex_z: float = 1000.0
    straight_s: float = 10.0
    sensor_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sensor: str = "radar-1"

    def validate(self) -> None:
        require_finite_keys(self, ("rate_hz", "sigma_range", "sigma_azimuth", "sigma_elevation", "speed", "start",
                                   "end", "apex_z", "straight_s", "sensor_position"))  # inf passed (before tour62)
        for name in ("rate_hz", "sigma_range", "sigma_azimuth", "sigma_elevation", "speed"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: must be > 0")
        if self.straight_s < 0.0:
            raise ConfigError("straight_s: must be >= 0")
        if self.start[2] != self.end[2]:
            raise ConfigError("end: must have the same altitude as start (the turn is a half circle)")
        radius = self.turn_radius
        if radius <= 0.0:
            raise ConfigError("end: must differ from start")
        if not 0.0 <= self.apex_z - self.start[2] <= radius:
            raise ConfigError(f"apex_z: must lie between start altitude and start altitude + {radius:g}")

    @property
    def T(self) -> float:
        """Sampling interval, s."""
        return 1.0 / self.rate_hz

    @property
    def turn_radius(self) -> float:
        """Half the start-end distance: the circle through start and end with them as a diameter."""
        return 0.5 * float(np.linalg.norm(np.subtract(self.end, self.start)))

    @property
    def turn_acceleration(self) -> float:
        """Centripetal acceleration of the turn, m/s^2."""
        return self.speed ** 2 / self.turn_radius

    @property
    def duration(self) -> float:
        """Straight segment plus the half circle, s."""
        return self.straight_s + math.pi * self.turn_radius / self.speed

    @property
    def R(self) -> np.ndarray:
        """Measurement noise covariance, diag(sigma_r^2, sigma_az^2, sigma_el^2)."""
        return np.diag([self.sigma_range ** 2, self.sigma_azimuth ** 2, self.sigma_elevation ** 2])


class Trajectory(NamedTuple):
    """Truth sampled at the radar times: ``t`` (K,), ``pos``/``vel``/``acc`` (K, 3)."""

    t: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    turn_start: int  # first sample index of the turn

    def state(self, order: str = "cv") -> np.ndarray:
        """Truth in a 3-D filter state order: cv ``[x, vx, y, vy, z, vz]`` or ca (with ``a``)."""
        parts = (self.pos, self.vel) if order == "cv" else (self.pos, self.vel, self.acc)
        return np.stack(parts, axis=-1).reshape(self.pos.shape[0], -1)


def trajectory(config: RadarConfig) -> Trajectory:
    """Sample the straight-then-banked-half-circle trajectory at ``rate_hz`` (see module doc)."""
    A, B = np.asarray(config.start, float), np.asarray(config.end, float)
    C = 0.5 * (A + B)
    R, v = config.turn_radius, config.speed
    e1 = (A - C) / R
    n_h = np.cross([0.0, 0.0, 1.0], e1)
    sin_tilt = (config.apex_z - C[2]) / R
    e2 = math.sqrt(1.0 - sin_tilt ** 2) * n_h + sin_tilt * np.array([0.0, 0.0, 1.0])
    K = int(math.floor(config.duration * config.rate_hz + 1e-9)) + 1
    t = np.arange(K) * config.T
    tau = t - config.straight_s
    turning = tau >= 0.0
    theta = np.where(turning, v * tau / R, 0.0)[:, None]
    circle = C + R * (np.cos(theta) * e1 + np.sin(theta) * e2)
    line = A + v * np.minimum(tau, 0.0)[:, None] * e2
    pos = np.where(turning[:, None], circle, line)
    vel = v * (-np.sin(theta) * e1 + np.cos(theta) * e2)
    acc = np.where(turning[:, None], -(v * v / R) * (np.cos(theta) * e1 + np.sin(theta) * e2), 0.0)
    return Trajectory(t, pos, vel, acc, int(np.argmax(turning)))


def measure(pos: np.ndarray, config: RadarConfig, rng: np.random.Generator) -> np.ndarray:
    """Noisy ``[r, az, el]`` for true positions ``pos`` (..., 3); azimuth wrapped to (-pi, pi]."""
    z = polar_from_cartesian(pos - np.asarray(config.sensor_position, float))
    sig = np.array([config.sigma_range, config.sigma_azimuth, config.sigma_elevation])
    z = z + sig * rng.standard_normal(z.shape)
    z[..., 1] = wrap_angle(z[..., 1])
    return z


def simulate(config: RadarConfig, runs: int, rng: np.random.Generator) -> tuple[Trajectory, np.ndarray]:
    """The scenario's truth and ``runs`` independent measurement sequences (runs, K, 3)."""
    traj = trajectory(config)
    return traj, measure(np.broadcast_to(traj.pos, (runs,) + traj.pos.shape), config, rng)


def radar_scans(config: RadarConfig, seed: int) -> Iterator[dict[str, Any]]:
    """One run of the scenario as replay-format lines plus ``truth`` (position, velocity, acceleration).

    Each line: ``{"t", "sensor", "z": [r, az, el], "R": 3x3, "sensor_position": [x, y, z],
    "truth": {"position", "velocity", "acceleration"}}``. ``fedtrack replay`` ignores ``truth``.
    """
    traj, z = simulate(config, 1, np.random.default_rng(seed))
    R = config.R.tolist()
    sensor_position = [float(c) for c in config.sensor_position]
    for k in range(traj.t.shape[0]):
        yield {
            "t": float(traj.t[k]),
            "sensor": config.sensor,
            "z": z[0, k].tolist(),
            "R": R,
            "sensor_position": sensor_position,
            "truth": {"position": traj.pos[k].tolist(), "velocity": traj.vel[k].tolist(),
                      "acceleration": traj.acc[k].tolist()},
        }
