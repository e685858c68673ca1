"""The track-to-track centre's life rules take the estimates they look at from the report's own prediction
(``CentreLife._states_at``, perf60): no prediction of their own for a report that fused rows (three to four
predictions of a few tracks a report before, a fixed cost that a region centre paid as fully as the one
region), and every picture the same, to the bit, as with each estimate predicted again."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from fedtrack.config import load_tables
from fedtrack.fusion_center.mtt.central_track import CentralTracks
from fedtrack.fusion_center.mtt.centre.track_life import CentreLife
from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
from fedtrack.fusion_center.mtt.replay import pictures, read_scans, state_dim
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate


def in_life_rules_of_a_fused_report() -> bool:
    """Whether the caller runs inside ``_count_scan`` called by ``_fuse_rows`` (a report that fused rows)."""
    names = set()
    frame = sys._getframe(2)
    while frame is not None:
        names.add(frame.f_code.co_name)
        frame = frame.f_back
    return {"_count_scan", "_fuse_rows"} <= names


def run(folder: Path, feedback: bool) -> list[str]:
    cfg = load_tables(folder / "config.toml", MttSettings).mtt
    scans = read_scans(folder / "measurements.jsonl", cfg)
    engine = TrackToTrackEngine(cfg, state_dim(scans), feedback=feedback)
    return [tracks.line(T, {}) for T, tracks in pictures(engine, scans, cfg.period, cfg.picture_delay)]


@pytest.mark.parametrize("feedback", [True, False])
def test_life_rules_predict_nothing_again_and_pictures_are_unchanged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                     feedback: bool) -> None:
    simulate(Scenario(targets=20, duration=30.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 3, tmp_path)
    original = CentralTracks.states_at
    calls = {"life": 0, "all": 0}

    def counted(self: CentralTracks, slots: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        calls["all"] += 1
        calls["life"] += in_life_rules_of_a_fused_report()
        return original(self, slots, t)

    monkeypatch.setattr(CentralTracks, "states_at", counted)
    shared = run(tmp_path, feedback)
    assert calls["all"] > 100 and calls["life"] == 0  # (before, federated: 124 of 280)
    monkeypatch.setattr(CentreLife, "_states_at", lambda self, slots, t: self.tracks.states_at(slots, t),
                        raising=False)
    calls["life"] = 0
    again = run(tmp_path, feedback)
    assert calls["life"] > 50  # each estimate predicted again
    assert len(shared) == 30 and shared == again
