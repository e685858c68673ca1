"""A region centre's numbers file (``serve mtt-centre --region RID --numbers PATH``, issue 27): the
track ids and hand-over numbers it has reserved, so that a process of it started again after a crash
(without a standby: ``[multitarget] standby = false``) numbers after every one its former process
issued (docs/deploy.md#a-region-centre-started-again-its-numbers-file).

Region ``r`` of ``R`` numbers its tracks ``r, r + R, ...`` and its hand-overs ``0, 1, ...``; a fresh
process started from those again, and its neighbours refused its hand-overs (a second, different
hand-over of a number they had taken: ``contested``; or ``late``) and showed its new tracks under
ids they held for other targets. Before it fuses a sub-report, which can issue at most one id and
one hand-over per row, the centre writes (atomically, fsync'ed) a reservation past what the
sub-report can issue (:func:`reservation`), ``RESERVE_AHEAD`` more at a time so that a write is
rare; a process started with the file numbers from the reservation on (a few thousand ids skipped).

The file is one JSON object: ``{"region": RID, "next_id": N, "serial": S}`` (``N`` in region
``RID``'s sequence, both below ``NUMBER_ROOM``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

from fedtrack.atomic import write_atomic
from fedtrack.config import ConfigError, read_small_file
from fedtrack.fusion_center.mtt.failover.standby import NUMBER_ROOM
from fedtrack.wire import MAX_TRACKS

# reserved beyond what the sub-report at hand can issue: a write per MAX_TRACKS ids or hand-overs at most, and
# a restart skips at most that many and one sub-report's rows (MAX_PARTS x MAX_TRACKS): far from NUMBER_ROOM
RESERVE_AHEAD = MAX_TRACKS
# the file is one short line (a region id of at most 64 characters, two integers below 2^62): a larger one, or
# one that is no regular file (/dev/zero, a FIFO that would block the start), is no numbers file and is read no further
MAX_NUMBERS_BYTES = 4096


class Numbers(NamedTuple):
    """A region centre's next track id and next hand-over number (issued, or reserved)."""

    next_id: int
    serial: int


def reservation(issued: Numbers, reserved: Numbers | None, step: int, rows: int) -> Numbers | None:
    """The reservation to write before a sub-report of ``rows`` rows is fused (ids step by ``step``):
    None while ``reserved`` covers the ``rows`` ids and hand-overs it can issue past ``issued``, else
    ``RESERVE_AHEAD`` more than that."""
    need = Numbers(issued.next_id + rows * step, issued.serial + rows)
    if reserved is not None and need.next_id <= reserved.next_id and need.serial <= reserved.serial:
        return None
    return Numbers(need.next_id + RESERVE_AHEAD * step, need.serial + RESERVE_AHEAD)


def read_numbers(path: Path, region: str, index: int, step: int) -> Numbers | None:
    """The reservation in ``path`` of region ``region`` (region ``index`` of ``step``), None when
    there is no file (a first start); ConfigError naming the file and field for one it cannot
    number after (another region's, not its sequence, beyond ``NUMBER_ROOM``, not JSON)."""
    raw = read_small_file(path, MAX_NUMBERS_BYTES, "numbers file")
    if raw is None:
        return None
    try:
        obj = json.loads(raw.decode())
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}:1: not UTF-8 text (byte {exc.start})") from None
    except (ValueError, RecursionError) as exc:
        reason = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
        raise ConfigError(f"{path}:1: not a JSON object ({reason})") from None
    if not isinstance(obj, dict) or set(obj) != {"region", "next_id", "serial"}:
        raise ConfigError(f"{path}:1: expected {{\"region\", \"next_id\", \"serial\"}}")
    if obj["region"] != region:
        raise ConfigError(f"{path}:1: region: the numbers of {str(obj['region'])[:40]!r}, not of {region!r}")
    for name in ("next_id", "serial"):
        value = obj[name]
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < NUMBER_ROOM:
            raise ConfigError(f"{path}:1: {name}: expected an integer in [0, 2^62), got {str(value)[:40]}")
    if obj["next_id"] % step != index:
        raise ConfigError(f"{path}:1: next_id: {obj['next_id']} is not in region {region}'s sequence "
                          f"({index} modulo {step})")
    return Numbers(obj["next_id"], obj["serial"])


def write_numbers(path: Path, region: str, numbers: Numbers) -> None:
    """Replace ``path`` with the reservation ``numbers`` (atomic, fsync'ed; OSError as raised)."""
    write_atomic(path, json.dumps({"region": region, **numbers._asdict()}).encode() + b"\n")
