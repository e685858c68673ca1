"""Field validators: each takes (value, path) and returns the normalized value or raises WireError(path, ...)."""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from fedtrack.keys import InvalidName, check_id
from fedtrack.wire.limits import (
    _INT64_MAX,
    MAX_ARRAY_ELEMENTS,
    MAX_LIST_ITEMS,
    MAX_MAGNITUDE,
    MAX_MAP_ITEMS,
    MAX_PARTS,
    MAX_STRING_LENGTH,
    PD_RTOL,
    SYMMETRY_RTOL,
    WireError,
    brief,
)

# Each takes (value, path) and returns the normalized value or raises WireError(path, ...).

def _identifier(value: Any, path: str) -> str:
    try:
        return check_id(value, "value")
    except InvalidName as exc:
        raise WireError(path, str(exc).removeprefix("value ")) from None


def _text(value: Any, path: str) -> str:
    if not isinstance(value, str):
        raise WireError(path, f"expected a string, got {type(value).__name__}")
    if len(value) > MAX_STRING_LENGTH:
        raise WireError(path, f"string longer than {MAX_STRING_LENGTH} characters")
    return value


def _choice(*options: str) -> Callable[[Any, str], str]:
    def check(value: Any, path: str) -> str:
        if not isinstance(value, str) or value not in options:
            raise WireError(path, f"expected one of {', '.join(options)}; got {brief(value)}")
        return value
    return check


def _count(value: Any, path: str) -> int:
    """A non-negative 64-bit integer."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise WireError(path, f"expected an integer, got {type(value).__name__}")
    if not 0 <= int(value) <= _INT64_MAX:
        raise WireError(path, f"must be in [0, 2**63), got {value}")
    return int(value)


def _real(value: Any, path: str) -> float:
    """A finite real within +-MAX_MAGNITUDE, as every array's values (a time of 1e300 s was taken: a
    multi-target centre's picture numbers then left the wire's integers)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise WireError(path, f"expected a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise WireError(path, f"must be finite, got {value}")
    if not abs(value) <= MAX_MAGNITUDE:
        raise WireError(path, f"beyond +-{MAX_MAGNITUDE:g} (overflow-scale), got {brief(value)}")
    return float(value)


def _scans(value: Any, path: str) -> tuple[int, ...]:
    """Scan numbers (at most MAX_LIST_ITEMS): the contested scans an output names."""
    return tuple(_count(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, MAX_LIST_ITEMS)))


def _flag(value: Any, path: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise WireError(path, f"expected true or false, got {type(value).__name__}")
    return bool(value)


def _array(value: Any, path: str, ndim: int, limit: int = MAX_ARRAY_ELEMENTS) -> np.ndarray:
    """A finite read-only float64 array of ``ndim`` dimensions within the size bound ``limit``."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"dtype {arr.dtype}")
        arr = arr.astype(np.float64, copy=arr.flags.writeable)
    except (TypeError, ValueError) as exc:
        raise WireError(path, f"expected an array of real numbers ({exc})") from None
    if arr.ndim != ndim:
        raise WireError(path, f"expected {ndim} dimension(s), got shape {arr.shape}")
    if arr.size > limit:
        raise WireError(path, f"{arr.size} elements exceed the limit of {limit}")
    # one reduction for both checks: NaN fails every comparison, infinity exceeds the bound
    if arr.size and not np.abs(arr).max() <= MAX_MAGNITUDE:
        if not np.isfinite(arr).all():
            raise WireError(path, "contains NaN or infinity")
        raise WireError(path, f"values beyond +-{MAX_MAGNITUDE:g} (overflow-scale)")
    arr.setflags(write=False)
    return arr


def _vector(value: Any, path: str) -> np.ndarray:
    return _array(value, path, 1)


def _covariance(value: Any, path: str) -> np.ndarray:
    """Square, symmetric within SYMMETRY_RTOL, positive definite (eigenvalue ratio > PD_RTOL)."""
    arr = _array(value, path, 2)
    if arr.shape[0] != arr.shape[1]:
        raise WireError(path, f"expected a square matrix, got shape {arr.shape}")
    if arr.size == 0:
        return arr
    scale = float(np.abs(arr).max())
    if np.abs(arr - arr.T).max() > SYMMETRY_RTOL * scale:
        raise WireError(path, "not symmetric")
    sym = 0.5 * (arr + arr.T)
    try:
        eig = np.linalg.eigvalsh(sym)
    except np.linalg.LinAlgError:
        raise WireError(path, "eigenvalues could not be computed") from None
    if not eig[0] > PD_RTOL * eig[-1] or eig[-1] <= 0.0:
        raise WireError(path, f"not positive definite (eigenvalues {eig[0]:.3g} .. {eig[-1]:.3g})")
    sym.setflags(write=False)
    return sym


def predictable(values: np.ndarray, P: np.ndarray, horizon: float) -> bool:
    """Whether states ``values`` and covariances ``P`` (any shapes) stay within the receivers'
    +-MAX_MAGNITUDE once a tracker predicts them over ``horizon`` seconds (docs/wire.md, "Values a
    centre predicts"). One step of a constant-acceleration block ``[p, v, a]`` multiplies a value
    by at most its transition's row sum ``g = 1 + h + h^2 / 2`` (constant velocity: ``1 + h``) and a
    covariance by ``g^2``; half of the bound is kept for the process noise and for fusion's
    rounding. So ``max |x| <= MAX_MAGNITUDE / (2 g)`` and ``max |P| <= MAX_MAGNITUDE / (2 g^2)``."""
    g = 1.0 + horizon + 0.5 * horizon * horizon
    x, C = np.asarray(values, dtype=np.float64), np.asarray(P, dtype=np.float64)
    return bool((x.size == 0 or np.max(np.abs(x)) * g <= 0.5 * MAX_MAGNITUDE)
                and (C.size == 0 or np.max(np.abs(C)) * g * g <= 0.5 * MAX_MAGNITUDE))


def acceptable_covariances(P: np.ndarray) -> bool:
    """Whether every covariance in ``P`` (one (d, d), a stack (n, d, d) or n stacked (n d, d)) is one
    a receiver accepts (:func:`_covariance`): within +-MAX_MAGNITUDE, symmetric within SYMMETRY_RTOL,
    positive definite with an eigenvalue ratio above PD_RTOL. A service checks what it is about to
    keep and publish with it: an estimate every receiver would refuse fails where it arises."""
    P = np.asarray(P, dtype=np.float64)
    if P.size == 0:
        return True
    stack = P.reshape(-1, P.shape[-1], P.shape[-1])
    scale = np.max(np.abs(stack), axis=(1, 2))
    if not np.all(scale <= MAX_MAGNITUDE):  # NaN too
        return False
    T = np.swapaxes(stack, 1, 2)
    if np.any(np.max(np.abs(stack - T), axis=(1, 2)) > SYMMETRY_RTOL * scale):
        return False
    eig = np.linalg.eigvalsh(0.5 * (stack + T))
    return bool(np.all((eig[:, -1] > 0.0) & (eig[:, 0] > PD_RTOL * eig[:, -1])))


def _whole(limit: int) -> int:
    """The bound of a batch in a whole message (built in Python, sent in parts): MAX_PARTS times
    ``limit``, the bound in one message on the wire (:func:`encode` and :func:`decode` check that)."""
    return MAX_PARTS * limit


def _optional(check: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
    def optional(value: Any, path: str) -> Any:
        return None if value is None else check(value, path)
    return optional


def _sequence(value: Any, path: str, limit: int) -> list[Any]:
    if not isinstance(value, (list, tuple)):
        raise WireError(path, f"expected a list, got {type(value).__name__}")
    if len(value) > limit:
        raise WireError(path, f"{len(value)} items exceed the limit of {limit}")
    return list(value)


def _mapping(value: Any, path: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise WireError(path, f"expected a map, got {type(value).__name__}")
    if len(value) > MAX_MAP_ITEMS:
        raise WireError(path, f"{len(value)} entries exceed the limit of {MAX_MAP_ITEMS}")
    for key in value:
        _identifier(key, f"{path} key {brief(key)}")
    return value


def _identifiers(value: Any, path: str) -> tuple[str, ...]:
    return tuple(_identifier(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, MAX_LIST_ITEMS)))


def _counters(value: Any, path: str) -> dict[str, int]:
    return {k: _count(v, f"{path}.{k}") for k, v in _mapping(value, path).items()}


def _check_part(part: int, parts: int) -> None:
    """A part's index and count: 0 <= part < parts <= MAX_PARTS."""
    if not 1 <= parts <= MAX_PARTS:
        raise WireError("parts", f"must be in [1, {MAX_PARTS}], got {parts}")
    if part >= parts:
        raise WireError("part", f"must be below parts ({parts}), got {part}")


def _check_square(P: np.ndarray, n: int, path: str, against: str) -> None:
    if P.shape != (n, n):
        raise WireError(path, f"expected shape ({n}, {n}) to match {against}, got {P.shape}")


def _check_state(x: np.ndarray, P: np.ndarray, path: str = "x", cov_path: str = "P") -> None:
    """A state ``x`` (not empty) and its covariance ``P`` (square, of its size)."""
    if x.shape[0] == 0:
        raise WireError(path, "must not be empty")
    _check_square(P, x.shape[0], cov_path, path)
