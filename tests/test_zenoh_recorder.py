"""The recorder's seq-ordered JSON Lines writer, driven by a fake clock (no Zenoh needed)."""

from __future__ import annotations

import json
from pathlib import Path

from fedtrack.services.recorder import SeqOrderedWriter


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def lines(path: Path) -> list[tuple[int, str]]:
    return [(row["seq"], row["sensor"]) for row in map(json.loads, path.read_text().splitlines())]


def make(tmp_path: Path, window: int = 64) -> tuple[SeqOrderedWriter, FakeClock, Path]:
    clock = FakeClock()
    path = tmp_path / "out.jsonl"
    return SeqOrderedWriter(path, window=window, settle_s=0.2, max_wait_s=1.0, clock=clock), clock, path


def add(writer: SeqOrderedWriter, sensor: str, seq: int) -> None:
    writer.add(sensor, seq, (0.1 * seq, sensor), {"seq": seq, "sensor": sensor})


def test_interleaved_sources_are_written_in_seq_then_sensor_order(tmp_path: Path) -> None:
    writer, clock, path = make(tmp_path)
    for sensor, seq in [("b", 1), ("a", 1), ("b", 0), ("a", 0)]:
        add(writer, sensor, seq)
    writer.release()
    assert lines(path) == []  # nothing before the settle time
    clock.now += 0.2
    writer.release()
    assert lines(path) == [(0, "a"), (0, "b"), (1, "a"), (1, "b")]
    assert writer.written == 4 and writer.late == 0
    writer.close()


def test_a_scan_waits_for_every_known_source_then_for_max_wait(tmp_path: Path) -> None:
    writer, clock, path = make(tmp_path)
    add(writer, "a", 0)
    add(writer, "b", 0)
    add(writer, "a", 1)  # b has not sent scan 1 yet
    clock.now += 0.5
    writer.release()
    assert lines(path) == [(0, "a"), (0, "b")]
    clock.now += 0.5  # scan 1 has now waited max_wait_s: b is considered silent
    writer.release()
    assert lines(path) == [(0, "a"), (0, "b"), (1, "a")]
    add(writer, "b", 1)  # too late: still written (never lost), counted
    assert lines(path)[-1] == (1, "b") and writer.late == 1
    writer.close()


def test_window_bounds_the_buffer_and_close_flushes(tmp_path: Path) -> None:
    writer, _clock, path = make(tmp_path, window=2)
    add(writer, "a", 0)
    add(writer, "b", 5)
    add(writer, "b", 3)
    assert lines(path) == [(0, "a")]  # three scans buffered > window 2: the oldest is written
    writer.close()
    assert lines(path) == [(0, "a"), (3, "b"), (5, "b")]
