"""``fedtrack serve recorder --out DIR``: record a deployment as replayable JSON Lines.

Writes ``DIR/measurements.jsonl`` (replay input, one line per Measurement, see
:func:`fedtrack.wire.measurement_to_replay`) and ``DIR/tracks.jsonl`` (replay
output, one line per FusedTrack, see :func:`fedtrack.wire.track_to_replay`, with ``event``
always present as in the fusion replay: null when the scan took no maneuver decision),
flushed line by line, in scan (``seq``) order. It publishes only its Health.

Ordering: messages from several sensors arrive interleaved, so lines are buffered
per ``seq`` (the scan index, shared by all sensors) and a scan is written, sorted
by ``t`` then sensor id, once it has waited ``SETTLE_S`` (so the other sensors'
messages of that scan, published at about the same time, can arrive) and every
source seen so far has sent that scan or a later one. A source that goes silent
cannot hold the file back for long: a scan is also written when it has waited
``MAX_WAIT_S`` or when more than ``REORDER_WINDOW`` scans are buffered. A message
for an already written scan is still written (never lost), out of order, and
counted in the ``*_late`` counter of the Health.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, TextIO

from fedtrack.deployment import deployment_of
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.wire import (
    FusedTrack,
    Measurement,
    measurement_to_replay,
    track_to_replay,
)

REORDER_WINDOW = 64
SETTLE_S = 0.2
MAX_WAIT_S = 1.0


class SeqOrderedWriter:
    """A JSON Lines file written in ``(seq, sort key)`` order from interleaved sources."""

    def __init__(self, path: Path, window: int = REORDER_WINDOW, settle_s: float = SETTLE_S,
                 max_wait_s: float = MAX_WAIT_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.path = path
        self.window = window
        self.settle_s = settle_s
        self.max_wait_s = max_wait_s
        self.clock = clock
        self.late = 0
        self.written = 0
        self._fh: TextIO = path.open("w")
        self._pending: dict[int, list[tuple[tuple[Any, ...], str]]] = {}
        self._first_seen: dict[int, float] = {}
        self._latest: dict[str, int] = {}
        self._released_up_to = -1

    def add(self, source: str, seq: int, sort_key: tuple[Any, ...], row: dict[str, Any]) -> None:
        """Buffer ``row`` of scan ``seq`` from ``source`` and write every scan that is complete."""
        line = json.dumps(row)
        if seq <= self._released_up_to:
            self.late += 1
            self._write(line)
            return
        self._pending.setdefault(seq, []).append((sort_key, line))
        self._first_seen.setdefault(seq, self.clock())
        self._latest[source] = max(self._latest.get(source, -1), seq)
        self.release()

    def release(self, everything: bool = False) -> None:
        """Write the buffered scans that are complete, too old, or beyond the window."""
        watermark = min(self._latest.values(), default=-1)
        now = self.clock()
        while self._pending:
            seq = min(self._pending)
            waited = now - self._first_seen[seq]
            if not (everything or (seq <= watermark and waited >= self.settle_s) or waited >= self.max_wait_s
                    or len(self._pending) > self.window):
                return
            for _, line in sorted(self._pending.pop(seq), key=lambda item: item[0]):
                self._write(line)
            del self._first_seen[seq]
            self._released_up_to = max(self._released_up_to, seq)

    def close(self) -> None:
        """Write everything still buffered and close the file."""
        self.release(everything=True)
        self._fh.close()

    def _write(self, line: str) -> None:
        self._fh.write(line + "\n")
        self._fh.flush()
        self.written += 1


class Recorder(Service):
    """Subscribes to every sensor's measurements and to the fused track; writes replay files."""

    role = "recorder"
    tick_period_s = 0.05

    def __init__(self, out: Path, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.out = out
        self._measurements: SeqOrderedWriter | None = None
        self._tracks: SeqOrderedWriter | None = None

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas(), Measurement, self.on_measurement),
                Subscription(self.keys.fusion_track(), FusedTrack, self.on_track)]

    def on_start(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        self._measurements = SeqOrderedWriter(self.out / "measurements.jsonl")
        self._tracks = SeqOrderedWriter(self.out / "tracks.jsonl")
        self.log.info("recording to %s", self.out)

    def on_measurement(self, msg: Measurement) -> None:
        assert self._measurements is not None
        self._measurements.add(msg.sensor, msg.seq, (msg.t, msg.sensor), measurement_to_replay(msg))
        self._update_counters()

    def on_track(self, msg: FusedTrack) -> None:
        assert self._tracks is not None
        row = track_to_replay(msg)
        row.setdefault("event", None)  # the fusion replay's field: null when no maneuver decision
        self._tracks.add("fusion", msg.seq, (msg.t,), row)
        self._update_counters()

    def on_tick(self) -> None:
        for writer in (self._measurements, self._tracks):
            if writer is not None:
                writer.release()
        self._update_counters()

    def on_stop(self) -> None:
        for writer in (self._measurements, self._tracks):
            if writer is not None:
                writer.close()
        self._update_counters()

    def _update_counters(self) -> None:
        for name, writer in (("measurements", self._measurements), ("tracks", self._tracks)):
            if writer is not None:
                self.counters[f"{name}_written"] = writer.written
                self.counters[f"{name}_late"] = writer.late


def main(argv: list[str]) -> int:
    parser = service_parser("recorder", "record measurements and fused tracks as replayable JSON Lines")
    parser.add_argument("--out", type=Path, help="output directory, created if missing (default: deployment.out "
                        "of --config)")
    parser.add_argument("--config", type=Path, help="configuration file; reads [deployment] (name, connect, out)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args)
    dep = deployment_of(args.config)
    out = args.out or (Path(dep.out) if dep is not None else None)
    if out is None:
        parser.error("--out is required (or --config with a [deployment] table)")
    return Recorder(out=out, **kwargs).run()
