"""Linear motion and measurement models (2-D CV and CA, position measurements).

State orders (fixed across fedtrack):

* CV: ``[x, vx, y, vy]``
* CA: ``[x, vx, ax, y, vy, ay]``

Process noise is the discrete white-acceleration ("piecewise constant") model of
paper 004 eq. (1)/(23): ``Q = G diag(q, q) G'`` with ``G`` the per-axis noise gain
``[T^2/2, T]'`` (CV) or ``[T^2/2, T, 1]'`` (CA) and ``q`` the acceleration variance.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

CV = "cv"
CA = "ca"


class LinearModel(NamedTuple):
    """A time-invariant linear-Gaussian motion model with position measurements.

    ``F`` and ``Q`` propagate the state; ``H`` picks the 2-D position; ``G`` is the
    process-noise gain (state x 2) and ``B`` the known-input gain used by input
    estimation (state x 2). ``pos`` / ``vel`` / ``acc`` index the state.
    """

    name: str
    T: float
    q: float
    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    G: np.ndarray
    B: np.ndarray
    pos: tuple[int, int]
    vel: tuple[int, int]
    acc: tuple[int, int] | None

    @property
    def dim(self) -> int:
        return self.F.shape[0]


def _block2(a: np.ndarray) -> np.ndarray:
    """Two copies of the per-axis block ``a`` on the diagonal (x axis, then y axis)."""
    n = a.shape[0]
    out = np.zeros((2 * n, 2 * n))
    out[:n, :n] = a
    out[n:, n:] = a
    return out


def _axis_columns(col: np.ndarray) -> np.ndarray:
    """Per-axis column ``col`` placed for x (first column) and y (second column)."""
    n = col.shape[0]
    out = np.zeros((2 * n, 2))
    out[:n, 0] = col
    out[n:, 1] = col
    return out


def cv_model(T: float, q: float) -> LinearModel:
    """Constant-velocity model, paper 004 eq. (1)-(2), state ``[x, vx, y, vy]``."""
    f = np.array([[1.0, T], [0.0, 1.0]])
    g = np.array([0.5 * T * T, T])
    G = _axis_columns(g)
    H = np.zeros((2, 4))
    H[0, 0] = H[1, 2] = 1.0
    return LinearModel(CV, T, q, _block2(f), q * G @ G.T, H, G, G.copy(), (0, 2), (1, 3), None)


def ca_model(T: float, q: float) -> LinearModel:
    """Constant-acceleration model, paper 004 eq. (23)-(24), state ``[x, vx, ax, y, vy, ay]``.

    ``B`` selects the acceleration components: the pulse input of eq. (72).
    """
    f = np.array([[1.0, T, 0.5 * T * T], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    g = np.array([0.5 * T * T, T, 1.0])
    G = _axis_columns(g)
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 3] = 1.0
    B = _axis_columns(np.array([0.0, 0.0, 1.0]))
    return LinearModel(CA, T, q, _block2(f), q * G @ G.T, H, G, B, (0, 3), (1, 4), (2, 5))


def model_by_name(name: str, T: float, q: float) -> LinearModel:
    """``cv`` or ``ca`` model by name."""
    if name == CV:
        return cv_model(T, q)
    if name == CA:
        return ca_model(T, q)
    raise ValueError(f"unknown motion model {name!r} (expected 'cv' or 'ca')")


# Index maps between the CV and CA state orders.
CV_IN_CA = np.array([0, 1, 3, 4])  # CA indices of x, vx, y, vy
CA_ACC = np.array([2, 5])  # CA indices of ax, ay


def cv_to_ca(x: np.ndarray, P: np.ndarray, acc: np.ndarray, P_acc: np.ndarray,
             P_cross: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Embed a CV state plus an acceleration estimate into the CA order.

    ``acc`` (..., 2), ``P_acc`` (..., 2, 2) and ``P_cross`` (..., 4, 2) = cov(CV part, acc).
    This is the permutation the errata asks for in eq. (69): the paper stacks
    ``[x, vx, y, vy, ax, ay]`` while the CA order is ``[x, vx, ax, y, vy, ay]``.
    """
    batch = x.shape[:-1]
    xs = np.concatenate([x, acc], axis=-1)
    Ps = np.zeros(batch + (6, 6))
    Ps[..., :4, :4] = P
    Ps[..., :4, 4:] = P_cross
    Ps[..., 4:, :4] = np.swapaxes(P_cross, -1, -2)
    Ps[..., 4:, 4:] = P_acc
    order = np.array([0, 1, 4, 2, 3, 5])  # stacked index for each CA slot
    return xs[..., order], Ps[..., order[:, None], order[None, :]]


def ca_to_cv(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marginalize a CA state onto the CV state (drop the accelerations)."""
    return x[..., CV_IN_CA], P[..., CV_IN_CA[:, None], CV_IN_CA[None, :]]
