"""Paper 004 scenarios (section IV) and simulated position sensors, batched over runs.

Truth: 2-D piecewise-constant acceleration from (21600, 10800) m with velocity
(-10, -400) m/s, sampled every T = 1 s from t = 0 to 100 s. Scenario 1 accelerates
with ``a_x = a_y = 30 sqrt(2)`` m/s^2 over 30-45 s and ``20 sqrt(2)`` over 70-85 s;
scenario 2 with ``60 sqrt(2)`` over both segments (the paper's per-axis values read
literally). The truth also carries the white-acceleration process noise the filters
assume (0.5^2 m^2/s^4 per axis, errata), so filter consistency (NEES) is testable.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass

import numpy as np

from fedtrack.local_filters.linear.models import cv_model

DEFAULT_R = np.array([[100.0, 5.0], [5.0, 100.0]])


@dataclass(frozen=True)
class ManeuverSegment:
    """Constant acceleration ``(ax, ay)`` applied for ``t_start <= t < t_end``."""

    t_start: float
    t_end: float
    ax: float
    ay: float


@dataclass(frozen=True)
class Scenario:
    """A 2-D maneuvering-target scenario sampled every ``T`` seconds."""

    name: str
    T: float
    duration: float
    position: tuple[float, float]
    velocity: tuple[float, float]
    segments: tuple[ManeuverSegment, ...]
    q: float = 0.25

    @property
    def times(self) -> np.ndarray:
        return np.arange(int(round(self.duration / self.T)) + 1) * self.T

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        """Commanded acceleration ``(len(t), 2)``."""
        acc = np.zeros((t.shape[0], 2))
        for seg in self.segments:
            on = (t >= seg.t_start) & (t < seg.t_end)
            acc[on] = (seg.ax, seg.ay)
        return acc


def paper004_scenario(number: int) -> Scenario:
    """Scenario 1 or 2 of paper 004."""
    if number == 1:
        a1, a2 = 30.0 * np.sqrt(2.0), 20.0 * np.sqrt(2.0)
    elif number == 2:
        a1 = a2 = 60.0 * np.sqrt(2.0)
    else:
        raise ValueError(f"paper 004 has scenarios 1 and 2, not {number!r}")
    return Scenario(
        name=str(number), T=1.0, duration=100.0, position=(21600.0, 10800.0),
        velocity=(-10.0, -400.0),
        segments=(ManeuverSegment(30.0, 45.0, a1, a1), ManeuverSegment(70.0, 85.0, a2, a2)),
    )


def simulate_truth(scenario: Scenario, runs: int, rng: np.random.Generator) -> np.ndarray:
    """True states ``(runs, K, 6)`` in the CA order ``[x, vx, ax, y, vy, ay]``.

    ``x(k+1) = F x(k) + G (a(k) + v(k))`` with ``v ~ N(0, q I)``; the stored
    acceleration is the commanded one, ``a(k)``.
    """
    t = scenario.times
    K = t.shape[0]
    model = cv_model(scenario.T, scenario.q)
    acc = scenario.acceleration(t)
    noise = rng.normal(scale=np.sqrt(scenario.q), size=(runs, K, 2))
    cv = np.zeros((runs, K, 4))
    cv[:, 0] = (scenario.position[0], scenario.velocity[0], scenario.position[1], scenario.velocity[1])
    for k in range(K - 1):
        cv[:, k + 1] = cv[:, k] @ model.F.T + (acc[k] + noise[:, k]) @ model.G.T
    truth = np.zeros((runs, K, 6))
    truth[..., [0, 1, 3, 4]] = cv
    truth[..., [2, 5]] = acc
    return truth


def simulate_positions(truth: np.ndarray, Rs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Position measurements ``(runs, K, N, 2)`` of ``N`` sensors with covariances ``Rs (N, 2, 2)``."""
    runs, K = truth.shape[:2]
    n_sensors = Rs.shape[0]
    L = np.linalg.cholesky(Rs)
    w = np.einsum("nij,rknj->rkni", L, rng.normal(size=(runs, K, n_sensors, 2)))
    return truth[:, :, None, :][..., [0, 3]] + w


def deployment_scenario(number: int, duration_s: float) -> Scenario:
    """Paper 004 scenario ``number`` run for ``duration_s`` seconds (the paper: 100; after the
    last maneuver the target goes on at constant velocity)."""
    return dataclasses.replace(paper004_scenario(number), duration=duration_s)


def deployment_truth(scenario: Scenario, seed: int) -> np.ndarray:
    """The one true trajectory ``(K, 6)`` every sensor of a deployment observes."""
    return simulate_truth(scenario, 1, np.random.default_rng(np.random.SeedSequence([seed, 0])))[0]


def sensor_measurements(truth: np.ndarray, R: np.ndarray, seed: int, sensor_id: str) -> np.ndarray:
    """Sensor ``sensor_id``'s measurements ``(K, 2)`` of ``truth``, with its own seeded noise."""
    entropy = [seed, 1, zlib.crc32(sensor_id.encode())]
    rng = np.random.default_rng(np.random.SeedSequence(entropy))
    return simulate_positions(truth[None], np.asarray(R)[None], rng)[0, :, 0]


def measurement_lines(times: np.ndarray, zs: np.ndarray, Rs: np.ndarray,
                      sensor_ids: list[str]) -> list[dict[str, object]]:
    """One run's measurements ``zs (K, N, 2)`` as replay input lines, scan by scan."""
    return [
        {"t": float(t), "sensor": sid, "z": zs[k, i].tolist(), "R": Rs[i].tolist()}
        for k, t in enumerate(times)
        for i, sid in enumerate(sensor_ids)
    ]
