"""IMM replay (JSON Lines in/out, validation naming file:line) and the vsimm reproducer's output."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.cli import main as cli_main
from fedtrack.config import ConfigError
from fedtrack.jsonl import InputError
from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.imm.filter import FSIMM, initial_state, step
from fedtrack.local_filters.imm.replay import replay_imm
from fedtrack.local_filters.linear.models import cv_model
from fedtrack.sensors.imm_scenarios import simulate

R = [[400.0, 0.0], [0.0, 400.0]]


def write_lines(path: Path, rows: list[dict]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def scenario_lines(steps: int = 80) -> tuple[list[dict], np.ndarray]:
    truth = simulate("S2", 1, np.random.default_rng(9), steps=steps)
    rows = [{"t": float(k + 1), "sensor": "radar-1", "z": truth.z[0, k].tolist(), "R": R} for k in range(steps)]
    return rows, truth.z[0]


@pytest.mark.parametrize("algorithm", ["fsimm", "vsimm", "ao-vsimm"])
def test_replay_writes_one_estimate_per_line(tmp_path: Path, algorithm: str):
    rows, _ = scenario_lines()
    meas = write_lines(tmp_path / "m.jsonl", rows)
    n = replay_imm(algorithm, meas, None, tmp_path / "out.jsonl")
    out = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert n == len(out) == len(rows)
    names = {m.name for m in IMMConfig().models}
    for o, r in zip(out, rows):
        assert o["t"] == r["t"] and len(o["x"]) == 4 and np.array(o["P"]).shape == (4, 4)
        assert set(o["mode_probabilities"]) == names
        assert sum(o["mode_probabilities"].values()) == pytest.approx(1.0, abs=1e-12)
        assert isinstance(o["active_group"], str)
    assert all(o["active_group"] == "all" for o in out) == (algorithm == "fsimm")
    # S2 turns to +y acceleration (0, 31) for k = 56..80: the estimate must follow
    assert out[-1]["acceleration"][1] > 15.0


def test_replay_matches_the_batched_filter(tmp_path: Path):
    """With x0/P0 in the config and unit steps, replay = the library step after an update-only start."""
    rows, z = scenario_lines(40)
    x0 = [float(z[0, 0]), 340.0, float(z[0, 1]), 340.0]
    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text(f"[imm]\nx0 = {x0}\nP0 = [[400.0, 0, 0, 0], [0, 900.0, 0, 0], [0, 0, 400.0, 0], [0, 0, 0, 900.0]]\n")
    replay_imm("fsimm", write_lines(tmp_path / "m.jsonl", rows), cfg_path, tmp_path / "o.jsonl")
    out = [json.loads(line) for line in (tmp_path / "o.jsonl").read_text().splitlines()]
    cfg = IMMConfig()
    bank = cfg.bank()
    s = initial_state(bank, FSIMM, 0, np.array([x0]), np.diag([400.0, 900.0, 400.0, 900.0])[None])
    s, o = step(bank, FSIMM, s, cv_model(0.0, cfg.q), z[:1], np.array(R), cfg.thresholds(), np.eye(bank.size))
    np.testing.assert_allclose(out[0]["x"], o.est.x[0], rtol=1e-12)
    for k in range(1, 40):
        s, o = step(bank, FSIMM, s, cv_model(1.0, cfg.q), z[k:k + 1], np.array(R), cfg.thresholds())
    np.testing.assert_allclose(out[-1]["x"], o.est.x[0], rtol=1e-12)


@pytest.mark.parametrize("bad,match", [
    ({"t": 3.0}, r"m.jsonl:3: t = 3.0 is earlier"),
    ({"z": [1.0]}, r"m.jsonl:4: z must be a list of 2 numbers, got 1"),
    ({"z": [1.0, float("nan")]}, r"m.jsonl:4: z\[1\] must be a finite number, got NaN"),
    ({"R": [[400.0, 1.0], [0.0, 400.0]]}, r"m.jsonl:4: R is not symmetric"),
    ({"R": [[1.0, 2.0], [2.0, 1.0]]}, r"m.jsonl:4: R is not positive definite"),
    ({"sensor": "other"}, r"m.jsonl:4: sensor 'other' differs"),
    ({"t": "soon"}, r"m.jsonl:4: t must be a finite number"),
])
def test_bad_measurements_name_the_line(tmp_path: Path, bad: dict, match: str):
    rows, _ = scenario_lines(6)
    rows[3] = {**rows[3], **bad}
    if "t" in bad and bad["t"] == 3.0:
        rows[2] = {**rows[2], "t": 3.0}
        rows[1] = {**rows[1], "t": 5.0}
    out = tmp_path / "o.jsonl"
    with pytest.raises(InputError, match=match):
        replay_imm("vsimm", write_lines(tmp_path / "m.jsonl", rows), None, out)
    assert not out.exists()  # nothing written for bad input


def test_missing_field_and_bad_config_through_the_cli(tmp_path: Path, capsys):
    rows, _ = scenario_lines(3)
    del rows[1]["R"]
    meas = write_lines(tmp_path / "m.jsonl", rows)
    assert cli_main(["replay", "--algorithm", "ao-vsimm", "--measurements", str(meas), "--out",
                     str(tmp_path / "o.jsonl")]) == 2
    assert "m.jsonl:2: missing field 'R'" in capsys.readouterr().err
    good = write_lines(tmp_path / "g.jsonl", scenario_lines(3)[0])
    cfg = tmp_path / "c.toml"
    cfg.write_text("[imm]\nactivation_treshold = 0.5\n")
    assert cli_main(["replay", "--algorithm", "vsimm", "--measurements", str(good), "--config", str(cfg),
                     "--out", str(tmp_path / "o.jsonl")]) == 2
    assert f"{cfg}: unknown config key imm.activation_treshold" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="x0"):
        cfg.write_text("[imm]\nx0 = [1.0, 2.0]\n")
        replay_imm("fsimm", good, cfg, tmp_path / "o.jsonl")


@pytest.mark.parametrize("algorithm", ["fsimm", "ao-vsimm"])
def test_a_measurement_at_the_time_of_the_last_is_left_out(tmp_path: Path, capsys, algorithm: str):
    """A measurement repeated, moved, at the time of the last one (as one sent again under a new number
    is; ``serve imm`` rejects it, ``time_jump``) was a second update (an estimate more, ``P`` shrunk);
    now it is left out and counted: the estimates are those without it, byte for byte."""
    rows, _ = scenario_lines(30)
    again = [r for k, row in enumerate(rows) for r in
             ([row, {**row, "z": [row["z"][0] + 50.0, row["z"][1]]}] if k % 7 == 3 else [row])]
    n_clean = replay_imm(algorithm, write_lines(tmp_path / "m.jsonl", rows), None, tmp_path / "clean.jsonl")
    capsys.readouterr()
    n = replay_imm(algorithm, write_lines(tmp_path / "a.jsonl", again), None, tmp_path / "again.jsonl")
    assert (f"{algorithm}: 4 measurements at the time of their sensor's last one taken, left out "
            "(live: rejected_time_jump)") in capsys.readouterr().err
    assert n == n_clean == 30 and len(again) == 34
    assert (tmp_path / "again.jsonl").read_bytes() == (tmp_path / "clean.jsonl").read_bytes()


def test_reproduce_json_shape_and_plots(tmp_path: Path):
    from fedtrack.experiments.vsimm import reproduce_vsimm

    res = reproduce_vsimm(runs=2, seed=3, json_path=tmp_path / "r.json", plots_dir=tmp_path / "plots")
    on_disk = json.loads((tmp_path / "r.json").read_text())
    assert on_disk["runs"] == 2 and on_disk["seed"] == 3 and on_disk["wall_time_s"] > 0
    assert set(on_disk["scenarios"]) == {"S1", "S2"}
    for scen in ("S1", "S2"):
        f = on_disk["scenarios"][scen]["filters"]
        assert {"fsimm", "vsimm", "ao_vsimm"} <= set(f)
        for entry in f.values():
            assert len(entry["t"]) == len(entry["rms_acc_x"]) == len(entry["rms_pos"]) == 200
            assert entry["cpu_s"] > 0 and np.isfinite(entry["mean_rms_acc"])
        assert f["fsimm"]["cpu_ratio_to_fsimm"] == 1.0 and f["fsimm"]["models_run_per_step"] == 13.0
        assert 5.0 <= f["ao_vsimm"]["models_run_per_step"] < 13.0
        assert len(on_disk["scenarios"][scen]["active_groups_run0"]["vsimm"]) == 200
    assert "deadlock" in on_disk["scenarios"]["S2"]["filters"]["vsimm"]
    assert res["scenarios"]["S1"]["filters"]["vsimm"]["mean_rms_acc"] == on_disk["scenarios"]["S1"]["filters"]["vsimm"]["mean_rms_acc"]
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == [
        "vsimm_S1_acc_rmse.png", "vsimm_S1_active_groups_run0.png",
        "vsimm_S2_acc_rmse.png", "vsimm_S2_active_groups_run0.png"]


@pytest.mark.parametrize("at", [0, 5])
def test_a_line_whose_estimate_overflows_is_left_out_as_live(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              at: int) -> None:
    """A valid line with z = 1e200 m overflowed the likelihoods: replay wrote NaN (not JSON) on it and
    every later line, where ``serve imm`` rejects it (rejected_numerical) and keeps its track. Now it
    is left out and counted, and the rest equals the replay without it (also as the first line)."""
    rows, _ = scenario_lines(20)
    bad = {**rows[at], "t": rows[at]["t"] - 0.5 if at else 0.5, "z": [1e200, -1e200]}
    with_bad = write_lines(tmp_path / "bad.jsonl", rows[:at] + [bad] + rows[at:])
    without = write_lines(tmp_path / "m.jsonl", rows)
    assert replay_imm("vsimm", with_bad, None, tmp_path / "a.jsonl") == len(rows)
    assert "vsimm: 1 measurements whose estimate came out non-finite" in capsys.readouterr().err
    replay_imm("vsimm", without, None, tmp_path / "b.jsonl")
    assert (tmp_path / "a.jsonl").read_text() == (tmp_path / "b.jsonl").read_text()
