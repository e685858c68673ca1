"""The tracker split into roles (issue 25 item 1): ``gnn`` pictures identical to main 886cab1.

``data/mtt_reference`` holds two seeded scenarios of ``fedtrack simulate multitarget`` (three
position sensors; a radar and a position sensor), their configs, and a fingerprint of the
pictures main 886cab1 (the tracker before the split) wrote for them with each algorithm, with
``maneuver = "none"`` and ``"vdie"``: per track its id, status, sensors, model, and ``x . w``,
``w' P w`` and the maneuver numbers (``w = 1, 2, ...``), to compare to 1e-12.
"""

from __future__ import annotations

import gzip
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.replay import replay_mtt

DATA = Path(__file__).parent / "data" / "mtt_reference"
REFERENCE = DATA / "gnn-886cab1.json.gz"
CASES = [(scenario, maneuver, algorithm) for scenario in ("pos", "radar") for maneuver in ("none", "vdie")
         for algorithm in ("mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized")]
LOCAL_SENSOR = {"pos": "s2", "radar": "r1"}


def fingerprint(path: Path) -> list:
    """Per picture its time and per track ``[id, x . w, w' P w, maneuver numbers . w, digest of the
    rest]``."""
    out = []
    for line in path.read_text().splitlines():
        picture = json.loads(line)
        rows = []
        for track in picture["tracks"]:
            x, P = np.array(track["x"]), np.array(track["P"])
            w = np.arange(1.0, x.size + 1.0)
            man = track.get("maneuver")
            m = 0.0 if man is None else man["onset"] + 2.0 * man["accel"][0] + 3.0 * man["accel"][1] + 4.0 * man["statistic"]
            rest = json.dumps([track["status"], track["sensors"], track["model"], man is None])
            rows.append([track["id"], float(x @ w), float(w @ P @ w), m, hashlib.sha1(rest.encode()).hexdigest()[:8]])
        out.append([picture["t"], rows])
    return out


def replay_case(tmp_path: Path, scenario: str, maneuver: str, algorithm: str) -> Path:
    cfg = tmp_path / f"{scenario}-{maneuver}.toml"
    cfg.write_text((DATA / f"{scenario}.toml").read_text().replace("[mtt]\n", f'[mtt]\nmaneuver = "{maneuver}"\n', 1))
    out = tmp_path / f"{scenario}-{maneuver}-{algorithm}.jsonl"
    replay_mtt(algorithm, DATA / f"{scenario}-scans.jsonl", cfg, out,
               sensor=LOCAL_SENSOR[scenario] if algorithm == "mtt-local" else None)
    return out


@pytest.mark.parametrize("scenario, maneuver, algorithm", CASES)
def test_gnn_pictures_equal_main_886cab1(tmp_path: Path, scenario: str, maneuver: str, algorithm: str) -> None:
    expected = json.loads(gzip.decompress(REFERENCE.read_bytes()))[f"{scenario}-{maneuver}-{algorithm}"]
    got = fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm))
    assert [t for t, _ in got] == [t for t, _ in expected]
    for (t, rows), (_, want) in zip(got, expected):
        assert [r[0] for r in rows] == [r[0] for r in want], f"track ids at t = {t}"
        assert [r[4] for r in rows] == [r[4] for r in want], f"status, sensors or model at t = {t}"
        np.testing.assert_allclose(np.array([r[1:4] for r in rows]).reshape(-1, 3),
                                   np.array([r[1:4] for r in want]).reshape(-1, 3), rtol=1e-12, atol=1e-9,
                                   err_msg=f"t = {t}")


def test_associator_key_selects_gnn_and_refuses_the_ones_to_come(tmp_path: Path) -> None:
    from fedtrack.config import ConfigError, load_tables
    from fedtrack.local_filters.mtt.config import ASSOCIATORS, NOT_YET, MttSettings
    from fedtrack.local_filters.mtt.tracker import ASSOCIATORS as IMPLEMENTED
    from fedtrack.local_filters.mtt.tracker import track_params

    assert set(IMPLEMENTED) == set(ASSOCIATORS) - set(NOT_YET)
    path = tmp_path / "c.toml"
    path.write_text('[mtt]\nassociator = "gnn"\n')
    assert track_params(load_tables(path, MttSettings).mtt, "s1", 4).associator.name == "gnn"
    for name in NOT_YET:
        path.write_text(f'[mtt]\nassociator = "{name}"\n')
        with pytest.raises(ConfigError, match=f"associator: '{name}' is not implemented yet"):
            load_tables(path, MttSettings)
    path.write_text('[mtt]\nassociator = "pda"\n')
    with pytest.raises(ConfigError, match="associator: must be one of gnn, jipda, mht"):
        load_tables(path, MttSettings)
