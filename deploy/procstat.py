"""Resident memory and CPU time of a running process, from Linux's ``/proc``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


class ProcessUsage(NamedTuple):
    """``rss_mb`` now, ``peak_rss_mb`` (``VmHWM``) so far, ``cpu_s`` user + system so far."""

    rss_mb: float
    peak_rss_mb: float
    cpu_s: float


def process_usage(pid: int) -> ProcessUsage | None:
    """The usage of ``pid``; None when it has exited or ``/proc`` cannot be read."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    kb = {}
    for line in status.splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            kb[key] = int(value.split()[0])
    fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state is fields[0]
    try:
        cpu = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15 of proc(5))
    except (IndexError, ValueError):
        return None
    if "VmRSS" not in kb:  # a zombie
        return None
    return ProcessUsage(kb["VmRSS"] / 1024.0, kb.get("VmHWM", kb["VmRSS"]) / 1024.0, cpu)
