"""A service's inbox: what the Zenoh callbacks hand to the worker thread, bounded and fair.

The callbacks put each sample (or query) here and the single worker takes them out
(:class:`fedtrack.services.base.Service`). Two bounds, the callback waiting beyond either (so
nothing is dropped while a service runs, as before): ``max_items`` messages (``QUEUE_SIZE``) and
``max_bytes`` of payloads, ``MAX_QUEUED_BYTES`` = ``MAX_PARTS`` x ``MAX_PAYLOAD_BYTES`` (128 MiB:
one largest message whole, the bound the reassembly holds too); one message is always taken into
an empty inbox. The worker serves the *streams* (a subscription's key expression: one sender's
key) in turn, each stream in its own order: a sender flooding its key delays another sender's
message by one turn, not by everything it queued ahead (docs/wire.md, "Flooding").
"""

from __future__ import annotations

import queue
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Hashable
from typing import Any

from fedtrack.wire import MAX_PARTS, MAX_PAYLOAD_BYTES

MAX_QUEUED_BYTES = MAX_PARTS * MAX_PAYLOAD_BYTES


def _size(item: tuple[Any, ...]) -> int:
    return len(item[3]) if isinstance(item[3], bytes) else 0


class Inbox:
    """Bounded (messages and payload bytes), its streams ``(kind, subscription, key)`` served in turn."""

    def __init__(self, max_items: int, max_bytes: int = MAX_QUEUED_BYTES) -> None:
        self.max_items, self.max_bytes = max_items, max_bytes
        self._streams: OrderedDict[Hashable, deque[tuple[Any, ...]]] = OrderedDict()
        self._items = self._bytes = 0
        self._changed = threading.Condition()

    def put(self, item: tuple[Any, ...], timeout: float) -> bool:
        """Queue ``item`` (``(kind, index, key, payload or query)``), waiting up to ``timeout`` s for
        room; False when there was none."""
        size = _size(item)
        deadline = time.monotonic() + timeout
        with self._changed:
            while self._items and (self._items >= self.max_items or self._bytes + size > self.max_bytes):
                left = deadline - time.monotonic()
                if left <= 0.0:
                    return False
                self._changed.wait(left)
            self._streams.setdefault(item[:3], deque()).append(item)
            self._items += 1
            self._bytes += size
            self._changed.notify_all()
        return True

    def get(self, timeout: float) -> tuple[Any, ...]:
        """The next stream's oldest item, waiting up to ``timeout`` s (``queue.Empty`` after)."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while not self._items:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    raise queue.Empty
                self._changed.wait(left)
            stream, items = self._streams.popitem(last=False)
            item = items.popleft()
            if items:
                self._streams[stream] = items  # to the end of the turn
            self._items -= 1
            self._bytes -= _size(item)
            self._changed.notify_all()
        return item

    def get_nowait(self) -> tuple[Any, ...]:
        return self.get(0.0)

    def qsize(self) -> int:
        return self._items
