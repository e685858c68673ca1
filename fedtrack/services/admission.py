"""Admission of received messages before their handler takes them: the sender named in a payload
against its key, the digest that tells a re-delivery from a conflict, the scan order and numbering
of a sender, and the contested scans an output names."""

from __future__ import annotations

from dataclasses import fields
from hashlib import blake2b

from fedtrack.keys import Keys
from fedtrack.services.rejections import Conflict, Rejected
from fedtrack.wire import (
    HandOver,
    Health,
    Measurement,
    Message,
    payloads,
)


def check_sender(keys: Keys, key: str, msg: Message) -> None:
    """Rejected("sender") when the id in the payload (a hand-over's ``source``) is not the id in the key
    it came on, or the region a payload names as its sender's (a region centre's answer) is not the
    region of its key."""
    named = keys.sender(key)
    claimed = (msg.id if isinstance(msg, Health) else msg.source if isinstance(msg, HandOver)
               else getattr(msg, "sensor", None))
    if named is not None and claimed is not None and claimed != named:
        raise Rejected("sender", f"payload from {claimed!r} on the key of {named!r}")
    region, claimed_region = keys.region_of(key), getattr(msg, "region", None)
    if region is not None and claimed_region is not None and claimed_region != region:
        raise Rejected("sender", f"answer of region {claimed_region!r} on the key of region {region!r}")


def digest(msg: Message) -> bytes:
    """A 16-byte digest of ``msg`` with its ``stamp_ns`` (if it has one) cleared: two messages for
    one (sensor, scan) are the same message when their digests are equal (a re-delivery), else a
    conflict. ``msg`` was checked when decoded: its copy is not checked again (a report's
    covariances and flags were half of a centre's decoding). A message beyond a per-message bound
    (joined from parts) is digested as the payloads of its parts."""
    if hasattr(msg, "stamp_ns"):
        msg = type(msg).unchecked(**{**{f.name: getattr(msg, f.name) for f in fields(msg)}, "stamp_ns": 0})
    return blake2b(b"".join(payloads(msg)), digest_size=16).digest()


class ScanOrder:
    """The last scan a single-sensor tracker took: a repeat of it is counted ``duplicate`` (if
    identical) or rejected as a :class:`Conflict` (a different message for the same scan, which
    would otherwise update the track twice); an older scan is rejected as ``late``."""

    def __init__(self) -> None:
        self.last: tuple[int, bytes] | None = None  # the scan number and digest of the message taken last

    def check(self, msg: Measurement) -> bool:
        """False for a duplicate to ignore; raises Rejected for a conflict or a late scan."""
        if self.last is None or msg.seq > self.last[0]:
            return True
        if msg.seq < self.last[0]:
            raise Rejected("late", f"scan {msg.seq} after scan {self.last[0]}")
        if digest(msg) == self.last[1]:
            return False
        raise Conflict(msg.seq, f"a second, different message for scan {msg.seq} (the first stays)")

    def took(self, msg: Measurement) -> None:
        self.last = (msg.seq, digest(msg))


class ReceivedScans:
    """Per sensor, the scan numbers a multi-target service took (with a digest of their payloads,
    stamps cleared, and their times): an identical repeat is a duplicate (``check`` returns False), a
    different message with a number already taken a :class:`Conflict`, and so is a new number at a
    time already taken under another (a scan or report sent again under a new number: the
    track-to-track centre fused such a report twice); a number more than ``max_seq_jump`` past the
    sensor's highest a ``seq_jump`` (both Rejected). Scans may come in any order, numbered in any
    order (a sensor may number its scans as it sends them, a late one after later ones). ``check``
    changes nothing; ``take`` records a checked message once its handling succeeded (so that a
    handler that fails in between leaves no trace)."""

    def __init__(self, max_seq_jump: int) -> None:
        self.max_seq_jump = max_seq_jump
        self.taken: dict[str, dict[int, tuple[bytes, float]]] = {}  # sensor -> number -> (digest, time)
        self.at: dict[str, dict[float, int]] = {}  # sensor -> time -> the number taken at it

    def check(self, msg: Message) -> bool:
        """True for a new scan; False for an identical repeat; Rejected for a conflict or a seq jump."""
        sensor, seq, t = msg.sensor, msg.seq, msg.t  # type: ignore[union-attr]
        seen = self.taken.get(sensor, {})
        if seq in seen:
            if seen[seq][0] == digest(msg):
                return False
            raise Conflict(seq, f"a second, different message for scan {seq} of {sensor!r} (the first stays)")
        if seen and seq > max(seen) + self.max_seq_jump:
            raise Rejected("seq_jump", f"scan {seq} of {sensor!r} is more than {self.max_seq_jump} after {max(seen)}")
        other = self.at.get(sensor, {}).get(t)
        if other is not None:
            raise Conflict(seq, f"scan {seq} of {sensor!r} at t={t:g}, the time of its scan {other} (the first stays)")
        return True

    def take(self, msg: Message) -> None:
        """Record ``msg`` (checked by :meth:`check`) as taken."""
        sensor, seq, t = msg.sensor, msg.seq, msg.t  # type: ignore[union-attr]
        seen, at = self.taken.setdefault(sensor, {}), self.at.setdefault(sensor, {})
        seen[seq] = (digest(msg), t)
        at[t] = seq
        if len(seen) > 4 * self.max_seq_jump:
            oldest = min(seen)
            oldest_t = seen.pop(oldest)[1]
            if at.get(oldest_t) == oldest:
                del at[oldest_t]


def contested_extra(scans: tuple[int, ...]) -> dict[str, list[float]]:
    """The ``FusedTrack.extra`` entry naming the contested scans an output depends on (none: {})."""
    return {"contested_scans": [float(s) for s in scans]} if scans else {}

MAX_CONTESTED = 64  # contested scans one output names at most (wire: MAX_LIST_ITEMS)
