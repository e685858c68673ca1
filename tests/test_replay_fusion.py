"""`fedtrack replay` for the fusion algorithms: equalities, input validation, config errors."""

import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.cli import main
from fedtrack.jsonl import write_jsonl
from fedtrack.sensors.scenarios import measurement_lines, paper004_scenario, simulate_positions, simulate_truth


def read_out(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture
def recorded(tmp_path):
    """Scenario 1 (maneuvering), 3 sensors with unequal R; a few scans lack a sensor."""
    rng = np.random.default_rng(3)
    scenario = paper004_scenario(1)
    Rs = np.array([[[100.0, 5.0], [5.0, 100.0]], [[60.0, -10.0], [-10.0, 150.0]], [[220.0, 30.0], [30.0, 90.0]]])
    truth = simulate_truth(scenario, 1, rng)
    zs = simulate_positions(truth, Rs, rng)[0]
    lines = measurement_lines(scenario.times, zs, Rs, ["a", "b", "c"])
    lines = [ln for i, ln in enumerate(lines) if i not in (31, 95, 140)]
    path = tmp_path / "measurements.jsonl"
    write_jsonl(path, lines)
    cfg = tmp_path / "fusion.toml"
    cfg.write_text('[fusion]\nsensors = ["a", "b", "c"]\nsharing = [2.0, 4.0, 4.0]\nq = 0.25\n')
    return path, cfg


def test_replay_federated_and_decentralized_equal_kf(recorded, tmp_path):
    meas, cfg = recorded
    outs = {}
    for alg in ("kf", "federated-kf", "decentralized-kf"):
        out = tmp_path / f"{alg}.jsonl"
        assert main(["replay", "--algorithm", alg, "--measurements", str(meas), "--config", str(cfg),
                     "--out", str(out)]) == 0
        outs[alg] = read_out(out)
    assert len(outs["kf"]) == 101
    assert sum(r["degraded"] for r in outs["kf"]) == 3
    for alg in ("federated-kf", "decentralized-kf"):
        for a, b in zip(outs[alg], outs["kf"]):
            assert a["t"] == b["t"] and a["model"] == b["model"] == "cv"
            np.testing.assert_allclose(a["x"], b["x"], rtol=1e-9, atol=1e-9 * 1e4)
            np.testing.assert_allclose(a["P"], b["P"], rtol=1e-9, atol=1e-12)


def test_replay_fvdie_switches_model(recorded, tmp_path):
    meas, cfg = recorded
    out = tmp_path / "fvdie.jsonl"
    assert main(["replay", "--algorithm", "fvdie", "--measurements", str(meas), "--config", str(cfg),
                 "--out", str(out)]) == 0
    rows = read_out(out)
    assert {r["model"] for r in rows} == {"cv", "ca"}
    assert all(len(r["x"]) == (6 if r["model"] == "ca" else 4) for r in rows)
    assert any(r["event"] == "onset" and 30 < r["t"] <= 34 for r in rows)


@pytest.mark.parametrize("algorithm", ["kf", "fvdie", "dvdie"])
def test_a_measurement_at_the_time_of_its_sensors_last_is_left_out(recorded, tmp_path, capsys, algorithm):
    """A sensor's measurement repeated, moved, at the time of its last one (as one sent again under a
    new number is; its live local filter rejects it, ``time_jump``) was an error (``sensor 'a' appears
    twice in the scan``, exit 2) and the replay wrote nothing; now it is left out and counted: the
    estimates are those without it, byte for byte."""
    meas, cfg = recorded
    lines = [json.loads(line) for line in meas.read_text().splitlines()]
    again = []
    for i, ln in enumerate(lines):
        again.append(ln)
        if ln["sensor"] == "a" and i % 30 == 0:
            again.append({**ln, "z": [ln["z"][0] + 50.0, ln["z"][1]]})
    extra = len(again) - len(lines)
    assert extra >= 5
    write_jsonl(tmp_path / "again.jsonl", again)
    outs = {}
    for name, path in (("clean", meas), ("again", tmp_path / "again.jsonl")):
        outs[name] = tmp_path / f"{name}-out.jsonl"
        assert main(["replay", "--algorithm", algorithm, "--measurements", str(path), "--config", str(cfg),
                     "--out", str(outs[name])]) == 0
        err = capsys.readouterr().err
    assert (f"{algorithm}: {extra} measurements at the time of their sensor's last one taken, left out "
            "(live: rejected_time_jump)") in err
    assert outs["again"].read_bytes() == outs["clean"].read_bytes()


BAD_LINES = {
    "nan": ({"t": 1.0, "sensor": "a", "z": [float("nan"), 1.0], "R": [[1, 0], [0, 1]]}, "NaN"),
    "asym": ({"t": 1.0, "sensor": "a", "z": [0.0, 1.0], "R": [[1, 0.5], [0, 1]]}, "not symmetric"),
    "not_pd": ({"t": 1.0, "sensor": "a", "z": [0.0, 1.0], "R": [[1, 2], [2, 1]]}, "not positive definite"),
    "shape": ({"t": 1.0, "sensor": "a", "z": [0.0, 1.0, 2.0], "R": [[1, 0], [0, 1]]}, "a list of 2 numbers, got 3"),
    "backwards": ({"t": -1.0, "sensor": "a", "z": [0.0, 1.0], "R": [[1, 0], [0, 1]]}, "backwards"),
    "missing": ({"t": 1.0, "sensor": "a", "R": [[1, 0], [0, 1]]}, "missing field 'z'"),
}


@pytest.mark.parametrize("case", sorted(BAD_LINES))
def test_replay_rejects_bad_input_naming_the_line(tmp_path, capsys, case):
    bad, message = BAD_LINES[case]
    good = {"t": 0.0, "sensor": "a", "z": [0.0, 1.0], "R": [[1, 0], [0, 1]]}
    path = tmp_path / "m.jsonl"
    path.write_text(json.dumps(good) + "\n" + json.dumps(bad).replace("NaN", "NaN") + "\n")
    out = tmp_path / "o.jsonl"
    assert main(["replay", "--algorithm", "kf", "--measurements", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:2" in err and message in err


@pytest.mark.parametrize("toml,key", [
    ("[fusion]\nqq = 1.0\n", "fusion.qq"),
    ("[fusion]\nq = -1.0\n", "fusion.q"),
    ("[fusion]\nsharing = [2.0, 2.0, 2.0]\n", "fusion.sharing"),
    ("[fusion.vdie]\nwindow = 0\n", "fusion.vdie.window"),
    ("[nonsense]\na = 1\n", "nonsense"),
])
def test_bad_config_fails_naming_the_key(recorded, tmp_path, capsys, toml, key):
    meas, _ = recorded
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    assert main(["replay", "--algorithm", "fvdie", "--measurements", str(meas), "--config", str(cfg),
                 "--out", str(tmp_path / "o.jsonl")]) == 2
    assert key in capsys.readouterr().err


def test_reproduce_fvdie_writes_contract_json(tmp_path):
    out = tmp_path / "r.json"
    assert main(["reproduce", "fvdie", "--runs", "10", "--seed", "4", "--json", str(out),
                 "--plots", str(tmp_path / "plots")]) == 0
    r = json.loads(out.read_text())
    assert r["runs"] == 10 and r["seed"] == 4 and r["wall_time_s"] > 0
    for scen in ("1", "2"):
        s = r["scenarios"][scen]
        assert "false_detection_rule" in s
        for name in ("fvdie", "dvdie", "kf"):
            f = s["filters"][name]
            assert len(f["t"]) == len(f["rms_pos_x"]) == len(f["rms_vel_y"]) == 101
            assert set(f["table1"]) == {"30", "31", "32", "33", "34", "70", "71", "72", "73", "74"}
            assert len(f["detection_times"]) == 10
            assert f["false_detections_per_run"] >= 0
    assert len(list((tmp_path / "plots").glob("fig*.png"))) == 4
