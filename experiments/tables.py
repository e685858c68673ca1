"""Plain-text result tables that every ``fedtrack reproduce`` prints at its end."""

from __future__ import annotations

import sys


def announce(text: str) -> None:
    """Say on stderr what a reproduction is about to do (progress bars only show on a terminal)."""
    print(text, file=sys.stderr, flush=True)


def print_table(title: str, header: list[str], rows: list[list[str]]) -> None:
    """``title`` then the rows in columns (first column left-aligned, the others right-aligned)."""
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    print(f"\n{title}")
    for r in [header, *rows]:
        cells = [f"{r[0]:<{widths[0]}}", *(f"{c:>{w}}" for c, w in zip(r[1:], widths[1:]))]
        print("  " + "  ".join(cells).rstrip())


def pm(mean: float | None, se: float | None, digits: int = 2) -> str:
    """``mean +- se`` (``-`` when missing)."""
    if mean is None:
        return "-"
    return f"{mean:.{digits}f}" + (f" +- {se:.{digits}f}" if se is not None else "")
