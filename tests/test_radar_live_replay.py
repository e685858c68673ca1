"""The radar local filter (``serve local-filter --filter ekf|ekf-ie|ekf-tsfuzzy``, in process) and
``replay --algorithm ekf|ekf-ie`` of the same measurements give the same estimates, bit for bit, and
count what they leave out under the same names."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_hostile_messages import KEYS, OPTIONS, Bus

from fedtrack.jsonl import write_jsonl
from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.radar.replay import replay_radar
from fedtrack.local_filters.service import RadarLocalFilterService
from fedtrack.sensors.radar import RadarConfig, radar_scans
from fedtrack.wire import LocalEstimate, Measurement, encode


def live(algorithm: str, lines: list[dict[str, Any]]) -> tuple[RadarLocalFilterService, list[tuple[Any, ...]]]:
    """The radar local filter fed ``lines`` as scans 0, 1, ... (sent as they are: the wire's receiver checks
    them); its counters and its estimates ``(t, x, P)``."""
    svc = RadarLocalFilterService("r1", make_radar_filter(algorithm), service_id="r1", options=OPTIONS,
                                  deployment=KEYS.deployment)
    bus = Bus([svc])
    for k, line in enumerate(lines):
        bus.put(KEYS.sensor_meas("r1"), encode(Measurement.unchecked(
            sensor="r1", seq=k, t=line["t"], kind="radar", z=np.array(line["z"]), R=np.array(line["R"]),
            sensor_position=np.array(line["sensor_position"]), stamp_ns=1, detections=(), part=0, parts=1)))
    return svc, [(e.t, e.x.tolist(), e.P.tolist()) for e in bus.of(LocalEstimate)]


def replayed(algorithm: str, lines: list[dict[str, Any]], tmp_path: Path) -> list[tuple[Any, ...]]:
    write_jsonl(tmp_path / "m.jsonl", lines)
    replay_radar(algorithm, tmp_path / "m.jsonl", None, tmp_path / "out.jsonl")
    return [(e["t"], e["x"], e["P"]) for e in map(json.loads, (tmp_path / "out.jsonl").read_text().splitlines())]


@pytest.mark.parametrize("algorithm", ["ekf", "ekf-ie"])
@pytest.mark.parametrize("fault", ["range 1e300", "pause 3000 s", "same time"])
def test_the_radar_replay_refuses_and_counts_what_the_live_filter_rejects(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], algorithm: str, fault: str) -> None:
    """A range of 1e300 m (which the wire refuses: the live filter never takes it) made the replay write
    9.5e299 m and then NaN on every later line; a pause of 3,000 s made it write the two estimates whose
    covariance the live filter refuses (``numerical``: it starts again on the second); a line at the time of
    the last one was ``rejected_input`` live. Now the replay leaves each out and counts it as live does."""
    lines = list(radar_scans(RadarConfig(), seed=3))[:60]
    for line in lines:
        del line["truth"]
    if fault == "range 1e300":
        lines[40]["z"] = [1e300, *lines[40]["z"][1:]]
    elif fault == "pause 3000 s":
        lines = lines[:40] + [{**line, "t": line["t"] + 3000.0} for line in lines[40:]]
    else:
        lines.insert(41, {**lines[40], "z": [lines[40]["z"][0] + 30.0, *lines[40]["z"][1:]]})
    svc, estimates = live(algorithm, lines)
    assert replayed(algorithm, lines, tmp_path) == estimates  # before: NaN, or estimates live refused
    err = capsys.readouterr().err
    counters = {k: v for k, v in svc.counters.items() if k.startswith(("rejected", "restarted")) and v}
    if fault == "range 1e300":
        assert len(estimates) == 58 and counters == {"rejected": 1}
        assert f"{algorithm}: 1 measurements the wire does not carry, left out (live: rejected)" in err
    elif fault == "pause 3000 s":
        assert len(estimates) == 57 and counters == {"rejected": 1, "rejected_numerical": 1, "restarted": 1}
        assert (f"{algorithm}: 1 measurements whose estimate came out non-finite or not positive definite, left out "
                "(live: rejected_numerical)") in err
    else:
        assert len(estimates) == 59 and counters == {"rejected": 1, "rejected_time_jump": 1}  # before: _input
        assert (f"{algorithm}: 1 measurements at the time of their sensor's last one taken, left out "
                "(live: rejected_time_jump)") in err
