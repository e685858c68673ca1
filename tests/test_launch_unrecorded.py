"""A paper deployment whose recording lacks fused tracks the launcher saw live ends with exit 1 and says
which (in process: the run itself replaced by its outcome)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.deploy import launcher
from fedtrack.deploy.demo import free_port, write_config
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig


def test_fused_tracks_missing_from_the_recording_end_the_launch_with_exit_1(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """At CI load 11 a lockstep run's recorder, stopped with a backlog, left 32 of the 101 fused tracks the
    launcher had seen out of tracks.jsonl and the launch exited 0, its summary saying '69 of 101'."""
    cfg = tmp_path / "config.toml"
    write_config(Settings(fusion=FusionConfig(sensors=("a",)), sensor=(SensorConfig(id="a"),),
                          deployment=DeploymentConfig(name="unrec", router_listen=f"tcp/127.0.0.1:{free_port()}",
                                                      out=str(tmp_path))), cfg)

    def run(self: launcher.Launcher) -> LaunchReport:  # the live run: 5 tracks seen, 3 of them recorded
        lines = [{"t": float(k), "x": [0.0, 0.0, 0.0, 0.0], "P": np.eye(4).tolist(), "model": "cv", "maneuver": False,
                  "degraded": False, "seq": k, "sensors": ["a"], "event": None} for k in (0, 1, 3)]
        (tmp_path / "tracks.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
        return LaunchReport(scans_fused=5, track_arrivals_ns=dict.fromkeys(range(5), 1))

    monkeypatch.setattr(launcher.Launcher, "run", run)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 1  # before: 0
    out, err = capsys.readouterr()
    assert "3 of 101 (0 degraded, 2 seen live but not recorded)" in out
    assert "fedtrack launch: 2 fused tracks seen live are not in the recording (scans 2, 4;" in err
    assert json.loads((tmp_path / "summary.json").read_text())["tracks_not_recorded"] == [2, 4]
