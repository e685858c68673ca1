"""``Reassembly``: a receiver's parts of split messages, held until each message is whole.

A message beyond a per-message bound of the wire is sent as :func:`fedtrack.wire.parts`, one put
each (docs/wire.md, "Messages in parts"). :class:`fedtrack.services.base.Service` decodes and
checks every part under the per-message bounds, then hands it here; the joined message goes to the
handler once, as if it had come whole. The parts are untrusted, so what is held is bounded:

- per stream (key expression, sender, message type) at most ``MAX_PENDING_PER_STREAM`` = 2
  messages in assembly (one publisher puts a message's parts back to back, so a stream has one in
  flight; a second covers a re-delivery overlapping the next message); a third evicts the oldest;
- in all at most ``MAX_PENDING`` = 2 x MAX_LIST_ITEMS = 128 messages (a service takes batched
  streams from at most MAX_LIST_ITEMS = 64 senders, the sensors a track may list) and
  ``MAX_HELD_BYTES`` = MAX_PARTS x MAX_PAYLOAD_BYTES = 128 MiB of payload (one largest message
  whole); beyond either the oldest message in assembly of the stream holding the most bytes is
  evicted (a sender flooding parts loses its own messages, not another stream's);
- a message still incomplete ``PARTS_TIMEOUT_S`` after its first part came is dropped: the
  largest message, 128 MiB, takes 10.7 s at 100 Mbit/s; 16 s leaves half as much again;
- when a message of a stream completes, the older ones of that stream still in assembly are
  dropped (their missing parts would only come after the newer message's).

Each eviction or drop is counted ``parts_incomplete``. A part whose index is already held is a
``duplicate`` (the same bytes: a re-delivery) or, different, ``rejected_parts`` (the first stays);
so is a part whose ``parts`` differs from its message's first part, and a set of parts that
:func:`fedtrack.wire.join` refuses (fields that differ, a track in two parts): the message is
dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from hashlib import blake2b
from typing import Any, Callable

from fedtrack import wire
from fedtrack.wire import Message, join

MAX_PENDING_PER_STREAM = 2
MAX_PENDING = 2 * wire.MAX_LIST_ITEMS
MAX_HELD_BYTES = wire.MAX_PARTS * wire.MAX_PAYLOAD_BYTES
PARTS_TIMEOUT_S = 16.0


@dataclass
class _Partial:
    """The parts of one message received so far (by index) with their payload digests and sizes."""

    first_at: float
    parts: dict[int, tuple[Message, bytes]] = field(default_factory=dict)
    size: int = 0


class Reassembly:
    """Parts held until their message is whole (module docstring); ``count(name)`` adds to a counter."""

    def __init__(self, count: Callable[[str], None], timeout_s: float = PARTS_TIMEOUT_S,
                 max_pending: int = MAX_PENDING, max_bytes: int = MAX_HELD_BYTES) -> None:
        self.count = count
        self.timeout_s = timeout_s
        self.max_pending = max_pending
        self.max_bytes = max_bytes
        self.pending: dict[tuple[Any, ...], _Partial] = {}  # oldest first (insertion order)
        self.held_bytes = 0

    def add(self, key: str, msg: Message, payload: bytes, now: float) -> tuple[Message, int] | None:
        """Hold part ``msg`` (decoded from ``payload`` on ``key``); the joined message and the
        bytes of all its parts once every part is in, else None. WireError (from :func:`join`)
        when the parts are not one message's: the caller counts it ``rejected_parts``."""
        stream = (key, getattr(msg, "sensor", None), type(msg).__name__)
        ident = (*stream, msg.seq)  # type: ignore[union-attr]
        self.expire(now)
        partial = self.pending.get(ident)
        if partial is None:
            same = [k for k in self.pending if k[:3] == stream]
            for old in same[:max(0, len(same) - MAX_PENDING_PER_STREAM + 1)]:
                self._drop(old, "parts_incomplete")
            partial = self.pending[ident] = _Partial(now)
        first = next(iter(partial.parts.values()), None)
        mark = blake2b(payload, digest_size=16).digest()
        if msg.part in partial.parts:  # type: ignore[union-attr]
            self.count("duplicate" if partial.parts[msg.part][1] == mark else "rejected_parts")  # type: ignore[union-attr]
            return None
        if first is not None and first[0].parts != msg.parts:  # type: ignore[union-attr]
            self.count("rejected_parts")
            return None
        partial.parts[msg.part] = (msg, mark)  # type: ignore[union-attr]
        partial.size += len(payload)
        self.held_bytes += len(payload)
        if len(partial.parts) < msg.parts:  # type: ignore[union-attr]
            self._bound()
            return None
        self._drop(ident)
        for old in [k for k in self.pending if k[:3] == stream and k[3] < ident[3]]:
            self._drop(old, "parts_incomplete")
        return join([p for p, _ in partial.parts.values()]), partial.size

    def expire(self, now: float) -> None:
        """Drop the messages whose first part came more than ``timeout_s`` before ``now``."""
        for ident in [k for k, p in self.pending.items() if now - p.first_at > self.timeout_s]:
            self._drop(ident, "parts_incomplete")

    def _bound(self) -> None:
        """Evict messages in assembly until within ``max_pending`` and ``max_bytes``: each time the
        oldest of the stream that holds the most bytes, so that a sender flooding parts loses its
        own messages, not another stream's."""
        while len(self.pending) > self.max_pending or self.held_bytes > self.max_bytes:
            held: dict[tuple[Any, ...], int] = {}
            for ident, partial in self.pending.items():
                held[ident[:3]] = held.get(ident[:3], 0) + partial.size
            heaviest = max(held, key=held.__getitem__)  # the first of equals: the oldest stream
            self._drop(next(k for k in self.pending if k[:3] == heaviest), "parts_incomplete")

    def _drop(self, ident: tuple[Any, ...], counter: str | None = None) -> None:
        partial = self.pending.pop(ident)
        self.held_bytes -= partial.size
        if counter is not None:
            self.count(counter)
