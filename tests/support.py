"""Helpers shared by the process tests (loopback only, bounded waits)."""

from __future__ import annotations

import time
from typing import Callable

from fedtrack.deploy.demo import free_port

WAIT_S = 10.0

__all__ = ["WAIT_S", "free_port", "wait_until"]


def wait_until(predicate: Callable[[], bool], timeout: float = WAIT_S) -> bool:
    """Poll ``predicate`` every 20 ms until it holds or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()
