"""A detected local track's covariance against its detection's: a row that carries an observation ``(H, R, z)``
was updated with it, and a Kalman update's posterior is never vaguer than the detection in the detection's
space, ``H P+ H' = R - R S^-1 R <= R`` (Loewner order; ``S = H P- H' + R``). A row whose ``H P H'`` exceeds
``R`` (the centre's ``R``, raised to the sensor's noise floor) cannot be an honest posterior: a compromised
tracker's local track with an enormous ``P`` passes every association test with whatever central track it
claims, so that its observation, reported anywhere, was fused into it for good (docs/multitarget.md, "A local
track vaguer than its detection").

The bound holds where the local trackers' update is one Kalman update of one model: ``gnn`` and ``mht`` (a hard
assignment, the EKF in Joseph form with ``H`` linearized where the observation reports it), without two motion
modes (``process_noise = "imm"``: their combination adds the spread of the modes' means) and without VDIE on a
2-D tracker (its switch to CA compensates the state after the update); a federated tracker has neither (the
centre's resets own its state). ``jipda``'s PDA mixture adds the spread of the innovations to its equivalent
observation's update, bounded only through the prediction, which the centre does not have: no rule there.
"""
from __future__ import annotations

import numpy as np

from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport

# a posterior at the bound to rounding passes: a one-point start's H P H' is R (1 + 8e-14 measured on radars), and
# the Joseph form's rounding exceeds it by 3.4e-5 at most over 2,000 random priors of 1-1,000 m and detections of
# 0.1-100 m (tests/test_mtt_posterior_bound.py); a lie within 0.1 % moves an association test by as much
BOUND_TOL = 1e-3


def kalman_rows(cfg: MttConfig, feedback: bool, dim: int) -> bool:
    """Whether the local trackers of local state size ``dim`` report each detected track's posterior after one
    Kalman update (so that :func:`vaguer_than_detection` holds it to its detection): a hard associator, one
    motion model (a federated tracker's always)."""
    if cfg.associator == "jipda":
        return False
    return feedback or (cfg.motion == "fixed" and not (cfg.maneuver == "vdie" and dim == 4))


def vaguer_than_detection(H: np.ndarray, P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Per observation (``H`` (K, m, d), ``R`` (K, m, m)) of a track with covariance ``P`` (K, d, d): whether
    ``H P H'`` exceeds ``R`` beyond :data:`BOUND_TOL`, the largest eigenvalue of ``L^-1 H P H' L^-T``
    (``R = L L'``, both scaled by ``R``'s largest variance) above ``1 + BOUND_TOL`` (or not a number)."""
    s = np.max(np.diagonal(R, axis1=-2, axis2=-1), axis=-1)[:, None, None]
    L = np.linalg.cholesky(R / s)
    A = np.linalg.solve(L, H @ P @ np.swapaxes(H, -1, -2) / s)
    A = np.linalg.solve(L, np.swapaxes(A, -1, -2))
    top = np.linalg.eigvalsh(0.5 * (A + np.swapaxes(A, -1, -2)))[:, -1]
    return ~(top <= 1.0 + BOUND_TOL)


def undetected(report: LocalReport, drop: np.ndarray) -> LocalReport:
    """The report with the detected rows whose observation is marked in ``drop`` (K,) as if the scan had not
    detected them (their observations gone; the tracks kept)."""
    detected = report.detected.copy()
    detected[report.detected.nonzero()[0][drop]] = False
    keep = ~drop
    return report._replace(detected=detected, obs_H=report.obs_H[keep], obs_R=report.obs_R[keep],
                           obs_z=report.obs_z[keep], started=report.started[keep])
