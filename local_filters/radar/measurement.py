"""Radar measurement model: range / azimuth / elevation of a position relative to the sensor.

Paper 002 eq. (39), paper 003 eq. (2) with atan2 per the errata::

    r  = |d|,  az = atan2(d_y, d_x),  el = atan2(d_z, sqrt(d_x^2 + d_y^2)),  d = p - sensor

Azimuth is wrapped to (-pi, pi]. Shared by the radar filters and the radar simulator. A plot given as
input is checked by :func:`polar_error`: angles in radians, the azimuth within one turn either way of
zero (so (-pi, pi] and [0, 2 pi) both read as meant), the elevation strictly between -pi/2 and pi/2.
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


#: the largest azimuth magnitude [rad] of a plot: one turn either way of zero. Beyond it the value is no
#: angle in radians (an azimuth of 400 degrees, or a plot in degrees, which the trackers took as radians)
AZIMUTH_BOUND = 2.0 * math.pi


def polar_error(z: np.ndarray) -> tuple[int, str] | None:
    """The first plot (row of ``z`` (M, 3) ``[range m, azimuth rad, elevation rad]``, finite) that is no
    radar plot, and what is wrong with it naming its component: a range <= 0, an azimuth beyond
    :data:`AZIMUTH_BOUND`, an elevation not strictly between -pi/2 and pi/2 (None: every row is one)."""
    z = np.asarray(z, float).reshape(-1, 3)
    tests = ((z[:, 0] <= 0.0, 0, "range", "must be > 0 [m]"),
             (np.abs(z[:, 1]) > AZIMUTH_BOUND, 1, "azimuth",
              "must be in [-2 pi, 2 pi] [rad] (radians, not degrees)"),
             (np.abs(z[:, 2]) >= math.pi / 2, 2, "elevation", "must be in (-pi/2, pi/2) [rad] (radians, not degrees)"))
    bad = [(int(np.argmax(rows)), k, name, rule) for rows, k, name, rule in tests if rows.any()]
    if not bad:
        return None
    row, k, name, rule = min(bad)
    return row, f"z[{k}] ({name}) {rule}, got {z[row, k]:g}"


def polar_from_cartesian(d: np.ndarray) -> np.ndarray:
    """``[r, az, el]`` (..., 3) of relative positions ``d`` (..., 3) (paper 002 eq. (39))."""
    if d.ndim == 1:  # one position: Python floats, a third of the cost of 0-d numpy arithmetic
        dx, dy, dz = d.tolist()
        rho = math.hypot(dx, dy)
        return np.array([math.sqrt(rho * rho + dz ** 2), math.atan2(dy, dx), math.atan2(dz, rho)])
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    rho = np.hypot(dx, dy)
    out = np.empty(d.shape)
    out[..., 0], out[..., 1], out[..., 2] = np.sqrt(rho * rho + dz ** 2), np.arctan2(dy, dx), np.arctan2(dz, rho)
    return out


def cartesian_from_polar(z: np.ndarray) -> np.ndarray:
    """Relative position (..., 3) of ``[r, az, el]`` (paper 003 eq. (4), corrected: z = r sin(el))."""
    r, az, el = z[..., 0], z[..., 1], z[..., 2]
    return np.stack([r * np.cos(az) * np.cos(el), r * np.sin(az) * np.cos(el), r * np.sin(el)],
                    axis=-1)


def cartesian_from_polar_jacobian(z: np.ndarray) -> np.ndarray:
    """Jacobian (..., 3, 3) of :func:`cartesian_from_polar` with respect to ``[r, az, el]``."""
    r, az, el = z[..., 0], z[..., 1], z[..., 2]
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    rows = [
        [ca * ce, -r * sa * ce, -r * ca * se],
        [sa * ce, r * ca * ce, -r * sa * se],
        [se, np.zeros_like(r), r * ce],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)
