"""A dependency-free progress bar on stderr for long Monte Carlo work."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``with Progress(total, "label") as p: p.advance(n)``; redraws at most 10x per second."""

    def __init__(self, total: int, label: str, stream: TextIO | None = None) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.done = 0
        self.stream = stream if stream is not None else sys.stderr
        self._start = time.monotonic()
        self._last_draw = 0.0
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_decile = -1

    def __enter__(self) -> "Progress":
        self._draw(force=True)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._tty:
            self._draw(force=True)
            self.stream.write("\n")
        self.stream.flush()

    def advance(self, n: int = 1) -> None:
        self.done = min(self.done + n, self.total)
        self._draw()

    def _draw(self, force: bool = False) -> None:
        """Redraw in place on a terminal; elsewhere (logs, CI) one line per 10 %."""
        now = time.monotonic()
        frac = self.done / self.total
        if self._tty:
            if not force and now - self._last_draw < 0.1 and self.done < self.total:
                return
        else:
            decile = int(frac * 10)
            if decile == self._last_decile:
                return
            self._last_decile = decile
        self._last_draw = now
        width = 30
        filled = int(round(width * frac))
        elapsed = now - self._start
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        prefix, suffix = ("\r", "") if self._tty else ("", "\n")
        self.stream.write(
            f"{prefix}{self.label} [{'#' * filled}{'.' * (width - filled)}] "
            f"{self.done}/{self.total} {elapsed:5.1f}s eta {eta:5.1f}s{suffix}"
        )
        self.stream.flush()
