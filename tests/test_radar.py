"""Radar sensor: exact scenario geometry, polar transforms, angle wrapping, scan lines."""

import math

import numpy as np
import pytest

from fedtrack.config import ConfigError, parse_dataclass
from fedtrack.local_filters.radar.filters import parse_measurement
from fedtrack.local_filters.radar.measurement import (
    cartesian_from_polar,
    cartesian_from_polar_jacobian,
    polar_from_cartesian,
    wrap_angle,
)
from fedtrack.sensors.radar import RadarConfig, radar_scans, trajectory


def test_trajectory_is_the_exact_banked_half_circle():
    cfg = RadarConfig()
    tr = trajectory(cfg)
    turn = slice(tr.turn_start, None)
    np.testing.assert_allclose(np.linalg.norm(tr.vel, axis=1), 200.0, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.pos[turn] - [0.0, 0.0, 500.0], axis=1), 2000.0, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tr.acc[turn], axis=1), 20.0, rtol=1e-12)
    assert np.all(tr.acc[:tr.turn_start] == 0.0)
    assert tr.t[tr.turn_start] == pytest.approx(10.0, abs=1e-9)
    np.testing.assert_allclose(tr.pos[tr.turn_start], cfg.start, atol=1e-9)
    assert np.max(tr.pos[:, 2]) <= 1000.0 + 1e-9
    assert np.max(tr.pos[:, 2]) == pytest.approx(1000.0, abs=0.01)
    assert np.linalg.norm(tr.pos[-1] - np.array(cfg.end)) <= 200.0 * cfg.T
    # finite-difference velocity agrees with the analytic one (continuity at the turn onset too)
    fd = np.diff(tr.pos, axis=0) / cfg.T
    np.testing.assert_allclose(fd, 0.5 * (tr.vel[1:] + tr.vel[:-1]), atol=0.01)
    assert cfg.turn_acceleration / 9.80665 == pytest.approx(2.039, abs=1e-3)


def test_polar_round_trip_and_jacobian():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3)) * 3000.0
    np.testing.assert_allclose(cartesian_from_polar(polar_from_cartesian(d)), d, rtol=1e-12, atol=1e-9)
    z = polar_from_cartesian(d)
    J = cartesian_from_polar_jacobian(z)
    h = 1e-6 * np.array([1e3, 1.0, 1.0])
    fd = np.stack([(cartesian_from_polar(z + h[i] * np.eye(3)[i]) - cartesian_from_polar(z - h[i] * np.eye(3)[i]))
                   / (2 * h[i]) for i in range(3)], axis=-1)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)


def test_wrap_angle_interval():
    a = np.array([math.pi, -math.pi, 3 * math.pi, 0.1, -0.1 - 4 * math.pi, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    np.testing.assert_allclose(w, [math.pi, math.pi, math.pi, 0.1, -0.1, 7.0 - 2 * math.pi], atol=1e-12)


def test_radar_scans_lines_are_valid_and_seeded():
    cfg = RadarConfig(straight_s=1.0)
    lines = list(radar_scans(cfg, seed=5))
    assert len(lines) == trajectory(cfg).t.shape[0]
    assert lines == list(radar_scans(cfg, seed=5))
    assert lines[3]["z"] != list(radar_scans(cfg, seed=6))[3]["z"]
    for i, line in enumerate(lines[:20]):
        m = parse_measurement(line, f"line {i}")
        assert -math.pi < m.z[1] <= math.pi
    # the scan noise has the configured spread (range residual, 2000 samples)
    res = np.array([ln["z"][0] - np.linalg.norm(ln["truth"]["position"]) for ln in lines])
    assert np.std(res) == pytest.approx(15.0, rel=0.1)


def test_config_validation_names_the_key():
    with pytest.raises(ConfigError, match="apex_z"):
        parse_dataclass(RadarConfig, {"apex_z": 5000.0})
    with pytest.raises(ConfigError, match="sigma_range"):
        parse_dataclass(RadarConfig, {"sigma_range": -1.0})
