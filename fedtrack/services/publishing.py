"""A service's outputs (:class:`Publishing`, a part of :class:`fedtrack.services.base.Service`):
each key's publisher, a ``zenoh.ext`` advanced publisher with a cache of about ``CACHE_BYTES`` of its
messages (``cache_depth``) and a heartbeat every ``HEARTBEAT_S``, or of the last N messages of a
windowed output, or a plain publisher without cache; a message beyond a bound of the wire goes as
its parts."""

from __future__ import annotations

import zenoh
import zenoh.ext

from fedtrack.wire import Message, payloads


def cache_depth(size: int) -> int:
    """The messages an advanced publisher keeps when its samples are ``size`` bytes: CACHE_BYTES
    worth, between MIN_CACHE_SAMPLES and CACHE_SAMPLES. The cache is what a restarted recorder
    receives of what it missed, seconds after it died (the launcher's backoff is at most 4 s), so
    minutes of it are plenty; 4,096 samples of a 1,000-track picture (150 kB) were 600 MB of a
    centre's memory after 68 minutes, of a 10,000-track one (5 parts of 0.5 MB) 2.2 GB after 14."""
    return max(MIN_CACHE_SAMPLES, min(CACHE_SAMPLES, CACHE_BYTES // max(size, 1)))


CACHE_SAMPLES = 4096  # messages an advanced publisher keeps per key, at most ...
# ... and about this many bytes of them (cache_depth): a restarted recorder needs what it missed,
# at most about 10 s under the launcher (three restarts: backoffs 0.5 + 1 + 2 s and a start of
# about 2 s each); 64 MiB is 25 s of 10,000-track pictures at 1 Hz (5 parts of 0.5 MB), 7.5
# minutes of 1,000-track ones; beyond about 30,000 tracks a picture at 1 Hz it holds less than 10 s
CACHE_BYTES = 64 * 1024 * 1024
MIN_CACHE_SAMPLES = 64  # the floor for the largest samples (2 MiB parts): 128 MiB a key
HEARTBEAT_S = 0.5
ENCODING = zenoh.Encoding("application/msgpack")


class Publishing:
    """The publishing of :class:`fedtrack.services.base.Service` (which sets ``session``,
    ``counters`` and ``_publishers`` up)."""

    def plain_outputs(self) -> tuple[str, ...]:
        """Key expressions of this service's outputs that only plain subscribers take (no
        ``Subscription(history=True)`` or ``recover`` anywhere reads them): published without the
        advanced publisher's cache of ``CACHE_SAMPLES`` messages, which nothing would read and
        which holds every message until it is full (a 1,000-track centre's answers: about 40 MB a
        minute; docs/multitarget.md, "Memory of a centre")."""
        return ()

    def windowed_outputs(self) -> dict[str, int]:
        """Key expressions of outputs whose advanced publisher keeps only the last N messages (key
        expression -> N; each message's parts, the cache declared again when a message has more parts
        than before), not ``CACHE_BYTES`` of them: a reader with history needs only the last few (the
        region pictures, for a restarted ``serve picture``)."""
        return {}

    def publish(self, key: str, msg: Message) -> None:
        """Encode ``msg`` and put it on ``key`` (reliable, blocking congestion control); a message
        beyond a per-message bound of the wire goes as its parts, one put each (:func:`fedtrack.wire.parts`).

        Call it from the hooks and handlers (the worker thread), not from other threads.
        """
        self._put(key, msg)
        self.counters["published"] += 1

    def declare_plain(self, key: str) -> None:
        """Declare the plain publisher of ``key`` (one of :meth:`plain_outputs`) now, before its first
        message: its matching status (:meth:`reaches`) is known once the router has answered the
        declaration (about a millisecond; a publisher declared with its first message said no
        subscriber for it)."""
        if self.session is None:
            raise RuntimeError("declare_plain() called before run() opened the session")
        if key not in self._publishers:
            self._publishers[key] = (self.session.declare_publisher(
                key, encoding=ENCODING, congestion_control=zenoh.CongestionControl.BLOCK), 0)

    def reaches(self, key: str) -> bool:
        """Whether a subscriber takes what this service publishes on ``key``, as its session knows
        (Zenoh's matching status of the key's plain publisher, :meth:`declare_plain`); True for a key
        without one (not known: as if taken)."""
        pub, depth = self._publishers.get(key, (None, 0))
        return pub is None or depth > 0 or bool(pub.matching_status.matching)

    def _put(self, key: str, msg: Message) -> None:
        if self.session is None:
            raise RuntimeError("publish() called before run() opened the session")
        encoded = payloads(msg)
        pub, depth = self._publishers.get(key, (None, 0))
        window = next((n for k, n in self.windowed_outputs().items()
                       if zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key))), None)
        needed = cache_depth(max(map(len, encoded))) if window is None else window * len(encoded)
        if pub is None and any(zenoh.KeyExpr(plain).includes(zenoh.KeyExpr(key)) for plain in self.plain_outputs()):
            self.declare_plain(key)
            pub = self._publishers[key][0]
        elif pub is None or (depth > 2 * needed if window is None else 0 < depth < needed):  # 0: a plain publisher
            # new, or its messages outgrew its cache (one grows from a few tracks to thousands): a
            # publisher with a cache of about CACHE_BYTES, or of its window's messages in their parts
            # (the old one's samples are dropped)
            if pub is not None:
                pub.undeclare()
            depth = needed
            pub = zenoh.ext.declare_advanced_publisher(
                self.session, key, encoding=ENCODING, congestion_control=zenoh.CongestionControl.BLOCK,
                cache=zenoh.ext.CacheConfig(max_samples=depth),
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=HEARTBEAT_S),
                publisher_detection=True)
            self._publishers[key] = (pub, depth)
        for payload in encoded:
            pub.put(payload)
