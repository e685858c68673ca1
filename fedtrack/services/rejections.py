"""Rejections: what a handler raises to refuse a decoded message (counted ``rejected_<reason>``,
docs/wire.md "Rejections"), the reason of any exception a handler raised, and the text of an
untrusted value in a log line."""

from __future__ import annotations

from typing import Any

import numpy as np

from fedtrack.wire import acceptable_covariances


class Rejected(Exception):
    """Raised by a handler to reject a decoded message: counted in ``rejected`` and
    ``rejected_<reason>``, logged (rate-limited), never fatal; the state is restored."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


class Conflict(Rejected):
    """A second, different message for scan ``seq`` of one sender (the first stays): counted as
    ``rejected_conflict`` and, by a service that calls :meth:`Service.contest`, ``contested``."""

    def __init__(self, seq: int, detail: str) -> None:
        super().__init__("conflict", detail)
        self.seq = seq


class Numerical(Rejected):
    """A computation that came out non-finite or not positive definite: ``rejected_numerical``."""

    def __init__(self, detail: str) -> None:
        super().__init__("numerical", detail)

NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError, OverflowError)

LOG_CHARS = 300  # a log line's untrusted part (key, reason) is cut to this many characters


def clip(text: str, limit: int = LOG_CHARS) -> str:
    """``text`` cut to ``limit`` characters for a log line (its length said when cut)."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def text_of(exc: Exception) -> str:
    """``str(exc)``, or its type's name if even that fails (an argument whose text recurses)."""
    try:
        return str(exc)
    except Exception:  # noqa: BLE001
        return f"<{type(exc).__name__} that cannot be shown>"


def reason_of(exc: Exception) -> str:
    """The rejection reason of an exception a handler raised (docs/wire.md, "Rejections")."""
    if isinstance(exc, Rejected):
        return exc.reason
    return "numerical" if isinstance(exc, NUMERICAL_ERRORS) else "handler_error"


def require_finite(what: str, *arrays: Any) -> None:
    """:class:`Numerical` unless every value of ``arrays`` is finite (a result about to be kept)."""
    for a in arrays:
        if not np.all(np.isfinite(a)):
            raise Numerical(f"{what} is not finite")


def require_covariances(what: str, *covariances: np.ndarray) -> None:
    """:class:`Numerical` unless every covariance (each argument one matrix or a stack of them) is
    one a receiver accepts (:func:`fedtrack.wire.acceptable_covariances`): an estimate that every
    receiver would refuse is a failure of the scan that made it, undone there, not a message sent."""
    for P in covariances:
        if not acceptable_covariances(P):
            raise Numerical(f"{what}: a covariance is not positive definite within the wire's bounds")
