"""``fedtrack simulate multitarget`` and ``fedtrack evaluate`` (GOSPA, OSPA, id switches, NEES)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fedtrack.cli import main as cli
from fedtrack.config import load_tables
from fedtrack.fusion_center.mtt.evaluation import evaluate, id_changes, nees_line, set_distance
from fedtrack.jsonl import InputError
from fedtrack.local_filters.mtt.config import MttSettings


def test_gospa_and_ospa_on_hand_computed_sets() -> None:
    truth = np.array([[0.0, 0.0], [10.0, 0.0]])
    d = set_distance(truth, np.array([[0.0, 3.0]]), c=100.0, p=2.0)
    assert (d.localisation, d.missed, d.false) == (9.0, 5000.0, 0.0)
    assert d.gospa == pytest.approx(math.sqrt(5009.0))
    assert d.ospa == pytest.approx(math.sqrt((9.0 + 100.0**2) / 2))
    far = set_distance(truth, np.array([[0.0, 3.0], [500.0, 500.0]]), c=100.0, p=2.0)
    assert (far.localisation, far.missed, far.false) == (9.0, 5000.0, 5000.0)
    assert far.gospa**2 == pytest.approx(far.localisation + far.missed + far.false)
    empty = set_distance(np.zeros((0, 2)), np.zeros((0, 2)), 100.0, 2.0)
    assert empty.gospa == 0.0 and empty.ospa == 0.0
    assert set_distance(truth, np.zeros((0, 2)), 100.0, 1.0).gospa == pytest.approx(100.0)


def test_id_switches_and_fragmentations() -> None:
    assert id_changes([1, 1, None, 1, 2, 2, None, None, 2]) == (1, 2)
    assert id_changes([None, 3, 3, 3]) == (0, 0)


def test_evaluate_counts_a_swap_and_nees(tmp_path: Path) -> None:
    truth, tracks = [], []
    P = np.diag([4.0, 1.0, 4.0, 1.0]).tolist()
    for k in range(6):
        a, b = [10.0 * k, 1.0, 0.0, 0.0], [10.0 * k, 1.0, 500.0, 0.0]
        truth.append({"t": float(k), "targets": [{"id": 0, "x": a}, {"id": 1, "x": b}]})
        ids = (5, 6) if k < 3 else (6, 5)  # the tracks swap targets at k = 3
        tracks.append({"t": float(k), "tracks": [{"id": ids[0], "x": a, "P": P, "status": "confirmed"},
                                                  {"id": ids[1], "x": b, "P": P, "status": "confirmed"}]})
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    res = evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")
    assert res["id_switches"] == 2 and res["fragmentations"] == 0
    assert res["mean"]["gospa"] == 0.0 and res["position_rmse"] == 0.0
    assert [(r["part"], r["dof"], r["pairs"], r["mean"]) for r in res["nees"]] == [("state", 4, 12, 0.0),
                                                                                  ("position", 2, 12, 0.0)]


def test_evaluate_scores_an_altitude_nobody_measured_on_x_y(tmp_path: Path) -> None:
    """A track marked ``"alt_measured": false`` (its altitude more the prior's than measured: replay on the Earth
    marks it, docs/geodetic.md) is scored on x, y in the 3-D GOSPA and the RMSE and left out of the altitude
    error; a measured one 3 km off is scored in 3-D (missed and false at c = 100 m). Before 2026-11-28 both were
    missed and false, the unmeasured altitude (the prior's centre) scored as if a sensor had said it."""
    P = np.eye(6).tolist()
    truth = [{"t": float(k), "targets": [{"id": 0, "x": [0.0, 1.0, 0.0, 0.0, 3000.0, 0.0]},
                                         {"id": 1, "x": [5000.0, 1.0, 0.0, 0.0, 3000.0, 0.0]}]} for k in range(4)]
    tracks = [{"t": float(k), "tracks": [
        {"id": 5, "x": [3.0, 1.0, 4.0, 0.0, 0.0, 0.0], "P": P, "status": "confirmed", "alt_measured": False},
        {"id": 6, "x": [5000.0, 1.0, 0.0, 0.0, 0.0, 0.0], "P": P, "status": "confirmed"}]} for k in range(4)]
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    res = evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")
    assert res["mean"]["localisation"] == pytest.approx(25.0)  # 3-4-5 on x, y: the unmeasured z left out
    assert res["mean"]["missed"] == res["mean"]["false"] == pytest.approx(100.0**2 / 2)  # the measured one, 3 km off
    assert res["position_rmse"] == pytest.approx(5.0) and res["altitude_rmse"] is None
    assert res["altitude_unmeasured_pairs"] == 4
    tracks[2]["tracks"][0]["alt_measured"] = "no"
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    with pytest.raises(InputError, match=r"t.jsonl:3: tracks\[0\].alt_measured must be true or false"):
        evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")


def test_evaluate_nees_leaves_an_altitude_nobody_measured_out(tmp_path: Path) -> None:
    """The NEES of a track marked ``"alt_measured": false`` is that of its ``[x, vx, y, vy]`` and their block of
    ``P`` (4 and 2 dof), as its GOSPA is on x, y; a measured 3-D track keeps its 6 and 3. Before (untuned61), the
    unmeasured z and vz, under the prior's variance, were counted as 2 dof that hold nearly no error: a
    consistent horizontal state read 2.0 of 6 (traffic `featured/elal747`: 1.51 of 6, 44 % inside the band)."""
    P = np.eye(6)
    P[4, 4] = P[5, 5] = 1e8  # the prior's z, vz: nobody measured them
    truth = [{"t": float(k), "targets": [{"id": 0, "x": [0.0, 1.0, 0.0, 0.0, 3000.0, 0.0]},
                                         {"id": 1, "x": [5000.0, 1.0, 0.0, 0.0, 3000.0, 0.0]}]} for k in range(4)]
    tracks = [{"t": float(k), "tracks": [
        {"id": 5, "x": [1.0, 1.0, 1.0, 0.0, 0.0, 0.0], "P": P.tolist(), "status": "confirmed", "alt_measured": False},
        {"id": 6, "x": [5001.0, 1.0, 1.0, 0.0, 3000.0, 0.0], "P": np.eye(6).tolist(), "status": "confirmed"}]}
        for k in range(4)]
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    res = evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")
    got = [(r["part"], r["dof"], r["pairs"], pytest.approx(r["mean"])) for r in res["nees"]]
    assert got == [("state", 4, 4, 2.0), ("position", 2, 4, 2.0), ("state", 6, 4, 2.0), ("position", 3, 4, 2.0)]


def test_evaluate_shows_its_progress_over_the_pictures(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``evaluate`` shows a bar over the pictures on a terminal (forced here: ``FEDTRACK_PROGRESS=1``), as the
    other long commands do: GOSPA's assignment takes about 10 s a picture at 10,000 targets (docs/bench.md), and
    before (tour57) it said nothing until its result."""
    truth = [{"t": float(k), "targets": [{"id": 0, "x": [float(k), 1.0, 0.0, 0.0]}]} for k in range(7)]
    tracks = [{"t": float(k), "tracks": [{"id": 3, "x": [float(k), 1.0, 0.0, 0.0], "status": "confirmed"}]}
              for k in range(7)]
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    monkeypatch.setenv("FEDTRACK_PROGRESS", "1")
    assert cli(["evaluate", "--tracks", str(tmp_path / "t.jsonl"), "--truth", str(tmp_path / "u.jsonl")]) == 0
    out, err = capsys.readouterr()
    assert "evaluate: pictures: 100%" in err and "7/7" in err
    assert "mean GOSPA 0.00 m" in out and "evaluate: pictures" not in out


def test_evaluate_nees_per_part_dof_and_band(tmp_path: Path) -> None:
    """Each pair's NEES by hand under P = diag(4, 1, 4, 1): errors (2, 1, 0, 0), (0.1, 0, 0, 0),
    (8, 0, 0, 3) give 2, 0.0025, 25 for the state (4 dof) and 1, 0.0025, 16 for the position
    (2 dof): one of three inside each band, the chi-square 2.5% and 97.5% quantiles of its dof, one
    below it (P too large) and one above; the text line says both sides."""
    P = np.diag([4.0, 1.0, 4.0, 1.0]).tolist()
    errors = [[2.0, 1.0, 0.0, 0.0], [0.1, 0.0, 0.0, 0.0], [8.0, 0.0, 0.0, 3.0]]  # NEES 2, 0.0025, 25
    truth = [{"t": float(k), "targets": [{"id": 0, "x": [100.0, 1.0, 0.0, 0.0]}]} for k in range(3)]
    tracks = [{"t": float(k), "tracks": [{"id": 1, "x": (np.array([100.0, 1.0, 0.0, 0.0]) - e).tolist(), "P": P}]}
              for k, e in enumerate(errors)]
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    state, position = evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")["nees"]
    assert state["dof"] == 4 and position["dof"] == 2
    assert state["mean"] == pytest.approx((2.0 + 0.0025 + 25.0) / 3, abs=1e-12)
    assert position["mean"] == pytest.approx((1.0 + 0.0025 + 16.0) / 3, abs=1e-12)
    assert state["band_95"] == pytest.approx([0.484419, 11.143287], abs=1e-6)
    assert position["band_95"] == pytest.approx([0.050636, 7.377759], abs=1e-6)
    assert state["inside_95"] == pytest.approx(1 / 3) and position["inside_95"] == pytest.approx(1 / 3)
    assert state["below_95"] == pytest.approx(1 / 3) and position["below_95"] == pytest.approx(1 / 3)
    assert "below it 33.3%: P too large, above 33.3%: P too small" in nees_line(state)


def test_simulate_replay_evaluate(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "sim"
    assert cli(["simulate", "multitarget", "--targets", "6", "--duration", "40", "--sensors",
                "pos:1.0,pos:0.7,radar:1.3", "--seed", "3", "--out", str(out)]) == 0
    lines = [json.loads(x) for x in (out / "measurements.jsonl").read_text().splitlines()]
    assert any(b["t"] < a["t"] for a, b in zip(lines, lines[1:])), "out-of-sequence lines"
    for sensor in ("s1", "s2", "r3"):
        times = [x["t"] for x in lines if x["sensor"] == sensor]
        assert times == sorted(times) and len(times) >= 30  # a sensor's link is FIFO
    assert all("sensor_position" in x for x in lines if x["sensor"] == "r3")
    cfg = load_tables(out / "config.toml", MttSettings).mtt
    assert cfg.sensors == ("s1", "s2", "r3") and cfg.sensor["r3"].clutter_density > 0
    truth = [json.loads(x) for x in (out / "truth.jsonl").read_text().splitlines()]
    assert len(truth) == 41 and len(truth[0]["targets"][0]["x"]) == 6
    assert cli(["replay", "--algorithm", "mtt-federated", "--config", str(out / "config.toml"),
                "--measurements", str(out / "measurements.jsonl"), "--out", str(tmp_path / "t.jsonl")]) == 0
    assert cli(["evaluate", "--tracks", str(tmp_path / "t.jsonl"), "--truth", str(out / "truth.jsonl"),
                "--json", str(tmp_path / "e.json"), "--plot", str(tmp_path / "e.png")]) == 0
    res = json.loads((tmp_path / "e.json").read_text())
    assert res["pictures"] >= 38 and res["mean"]["gospa"] < 100.0
    assert (tmp_path / "e.png").stat().st_size > 10_000
    assert "mean GOSPA" in capsys.readouterr().out


def test_dense_scenario_flies_formations(tmp_path: Path) -> None:
    """``--scenario dense``: its presets (P_D 0.8, 50 false detections, 120 s) unless given; groups of
    three side by side 20-40 m apart (within 2 sigma of the coarsest position sensor), holding formation."""
    out = tmp_path / "dense"
    assert cli(["simulate", "multitarget", "--scenario", "dense", "--targets", "9", "--duration", "30",
                "--seed", "2", "--out", str(out)]) == 0
    cfg = load_tables(out / "config.toml", MttSettings).mtt
    assert cfg.pd == 0.8 and math.isclose(cfg.clutter_density, 50.0 / 10_000.0**2)
    lines = [json.loads(x) for x in (out / "measurements.jsonl").read_text().splitlines()]
    assert 25 <= np.mean([len(x["detections"]) for x in lines]) - 9 * 0.8 <= 75  # Poisson(50) clutter
    truth = [json.loads(x) for x in (out / "truth.jsonl").read_text().splitlines()]
    assert len(truth) == 31
    for picture in (truth[0], truth[-1]):
        x = {tr["id"]: np.array(tr["x"]) for tr in picture["targets"]}
        for lead in (i for i in (0, 3, 6) if i in x):
            gaps = [np.hypot(*(x[lead + r][[0, 2]] - x[lead + r - 1][[0, 2]])) for r in (1, 2)]
            assert all(20.0 - 1e-9 <= g <= 40.0 + 1e-9 for g in gaps), gaps
            assert np.allclose(x[lead][[1, 3]], x[lead + 2][[1, 3]])  # one velocity: a formation
    assert cli(["simulate", "multitarget", "--scenario", "dense", "--pd", "0.9", "--targets", "3", "--duration",
                "5", "--out", str(tmp_path / "own")]) == 0
    assert load_tables(tmp_path / "own" / "config.toml", MttSettings).mtt.pd == 0.9


def test_simulate_with_a_radar_first_gives_the_position_sensors_their_density_per_m2(tmp_path: Path) -> None:
    """A radar's clutter density is per m rad^2 of its measurement space; with the radar listed
    first, the position sensor (no table of its own) still gets the per-m^2 density of a position
    sensor, the same as when a position sensor comes first."""
    densities = {}
    for spec in ("radar:1.0,pos:0.5", "pos:0.5,radar:1.0"):
        out = tmp_path / spec.replace(":", "_").replace(",", "_")
        assert cli(["simulate", "multitarget", "--targets", "2", "--duration", "5", "--sensors", spec,
                    "--clutter", "100", "--out", str(out)]) == 0
        cfg = load_tables(out / "config.toml", MttSettings).mtt
        pos = next(s for s in cfg.sensors if s.startswith("s"))
        radar = next(s for s in cfg.sensors if s.startswith("r"))
        densities[spec] = (cfg.clutter_of(pos), cfg.clutter_of(radar))
    (pos_a, radar_a), (pos_b, radar_b) = densities.values()
    assert pos_a == pos_b and radar_a == radar_b and radar_a > 100 * pos_a


def test_simulate_half_width_bounds_the_clutter_and_sets_its_density(tmp_path: Path) -> None:
    """``--half-width 2000``: every false detection within the 4 km square, the written density
    ``clutter / (2 half-width)^2``; at the default (5 km) some fall outside 2 km."""
    extents = {}
    for name, extra in (("small", ["--half-width", "2000"]), ("default", [])):
        out = tmp_path / name
        assert cli(["simulate", "multitarget", "--targets", "1", "--duration", "20", "--sensors", "pos:1.0",
                    "--clutter", "50", "--pd", "0.1", "--out", str(out), *extra]) == 0
        rows = [json.loads(line) for line in (out / "measurements.jsonl").read_text().splitlines()]
        extents[name] = max(abs(c) for row in rows for d in row["detections"] for c in d["z"])
        half = 2000.0 if extra else 5000.0
        assert load_tables(out / "config.toml", MttSettings).mtt.clutter_density == pytest.approx(
            50 / (2 * half) ** 2, rel=1e-12)
    assert extents["small"] <= 2000.0 + 100.0 < extents["default"]  # the one target's noise: under 100 m


def test_a_sensor_slower_than_the_scenario_still_scans_once() -> None:
    """A sensor whose period exceeds the scenario scans once, at a random time within it (before,
    its first scan came at a random phase within its period, so with chance 1 - duration / period it
    had none: `pos:1.0,pos:40` over 30 s left s2 without a scan for seeds 4, 6 and 8 of 1-8, and a
    `launch` of it failed at start, the sensor exiting 2: "no scan of sensor 's2'"). A period within
    the scenario draws its phase as before."""
    from fedtrack.sensors.multitarget import Scenario, SensorSpec, sensor_lines, simulate_truth

    sc = Scenario(targets=2, duration=30.0, late=0.0)
    first = []
    for seed in range(1, 9):
        rng = np.random.default_rng(seed)
        x, alive = simulate_truth(sc, False, rng)
        times = [line["t"] for _, line in sensor_lines(SensorSpec("s2", "pos", 40.0), sc, x, alive, False, rng)]
        assert len(times) == 1 and 0.0 <= times[0] <= sc.duration
        first.append(times[0])
    assert len(set(first)) == 8  # still a random time


def test_a_sensor_that_scans_once_does_not_set_the_process_noise_or_max_lag(tmp_path: Path) -> None:
    """`[mtt] q` and `max_lag` follow the sensors that scan again within the scenario: one slower than
    it scans once (no interval to predict across, never late). Before, `pos:1.0,pos:0.7,pos:1e9` over
    120 s wrote q = 2.5e9 and max_lag 2e9 s (mean GOSPA of mtt-federated 414 m; 32 m with these)."""
    from fedtrack.sensors.multitarget import parse_spec, process_noise

    out = tmp_path / "slow"
    assert cli(["simulate", "multitarget", "--sensors", "pos:1.0,pos:0.7,pos:1e9", "--targets", "2", "--duration",
                "30", "--out", str(out)]) == 0
    cfg = load_tables(out / "config.toml", MttSettings).mtt
    assert cfg.q == pytest.approx(math.pi**2 / 4 * 1.0, abs=1e-6) and cfg.max_lag == 3.0
    assert process_noise(parse_spec("pos:40,pos:50"), 30.0) == pytest.approx(math.pi**2 / 4 * 30.0, abs=1e-6)
    assert process_noise(parse_spec("pos:1.0,pos:20"), 30.0) == pytest.approx(math.pi**2 / 4 * 20.0, abs=1e-6)


def test_a_sensors_noise_in_its_spec(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--sensors pos:1.0/5,pos:0.7/500` gives s1 5 m and s2 500 m a axis (uncorrelated, as `simulate traffic`'s
    `/SIGMA`); the other draws stay as without it (the truth the same); a bad one is refused naming the item
    (exit 2). Before, the spec had no noise (every position sensor drawn in 10-20 m)."""
    out, plain = tmp_path / "noisy", tmp_path / "plain"
    args = ["simulate", "multitarget", "--targets", "2", "--duration", "5", "--out"]
    assert cli([*args, str(out), "--sensors", "pos:1.0/5,pos:0.7/500"]) == 0
    assert cli([*args, str(plain), "--sensors", "pos:1.0,pos:0.7"]) == 0
    R = {line["sensor"]: line["R"] for line in map(json.loads, (out / "measurements.jsonl").open())}
    np.testing.assert_array_equal(R["s1"], 25.0 * np.eye(2))
    np.testing.assert_array_equal(R["s2"], 250000.0 * np.eye(2))
    assert (out / "truth.jsonl").read_text() == (plain / "truth.jsonl").read_text()
    assert cli([*args, str(tmp_path / "bad"), "--sensors", "pos:1.0/0"]) == 2
    assert "'pos:1.0/0': the noise is pos:P/SIGMA (m), each > 0" in capsys.readouterr().err


def test_a_key_appended_to_simulates_config_lands_in_mtt(tmp_path: Path) -> None:
    """``simulate`` writes the sensors' noise floors as dotted keys inside ``[mtt]`` (``[mtt]`` last), so a
    key appended at the end of its ``config.toml`` is an ``[mtt]`` key (with ``[mtt.sensor.s1]`` headers
    it was the last sensor's, an unknown key there); the floors read back the same."""
    out = tmp_path / "sim"
    assert cli(["simulate", "multitarget", "--targets", "2", "--duration", "5", "--out", str(out)]) == 0
    path = out / "config.toml"
    floors = load_tables(path, MttSettings).mtt.sensor
    with path.open("a") as fh:
        fh.write('maneuver = "vdie"\n')
    cfg = load_tables(path, MttSettings).mtt
    assert cfg.maneuver == "vdie" and cfg.sensor == floors and set(floors) == {"s1", "s2", "s3"}


def test_a_scenario_too_large_for_memory_is_one_line_and_makes_nothing(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """`--duration 1e9` (or ten million targets) is refused before anything is made: exit 2, one line saying
    what to give, no folder (before, numpy's MemoryError and a traceback, the folder made empty)."""
    for extra in (["--duration", "1e9", "--targets", "1"], ["--targets", "10000000"]):
        out = tmp_path / "big"
        assert cli(["simulate", "multitarget", "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "the scenario is too large" in err[0] and "--duration" in err[0], err
        assert not out.exists()


def test_the_memory_a_scenario_needs_bounds_what_it_takes(tmp_path: Path) -> None:
    """:func:`memory_need` is above the peak tracemalloc measures for scenarios of many steps, many targets,
    formations and heavy clutter (so that the check refuses only what would not fit)."""
    import tracemalloc

    from fedtrack.sensors.multitarget import Scenario, memory_need, parse_spec, simulate

    cases = ((Scenario(targets=1, duration=500.0), "pos:100"), (Scenario(targets=200, duration=5.0), "pos:1.0"),
             (Scenario(targets=12, duration=20.0, formation=3), "pos:1.0,pos:0.7"),
             (Scenario(targets=2, duration=2.0, clutter=2000.0), "pos:0.1,radar:0.5"))
    for k, (sc, spec) in enumerate(cases):
        specs = parse_spec(spec)
        tracemalloc.start()
        try:
            simulate(sc, specs, 1, tmp_path / str(k))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < memory_need(sc, specs), (k, peak, memory_need(sc, specs))


def test_simulate_interrupted_leaves_the_earlier_scenario_whole(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while ``simulate multitarget`` writes into a folder that holds an earlier scenario (here while it
    writes the truth, after the measurements): the folder keeps the earlier measurements, truth and config, no mix
    of the two runs and no temporary file. Before the tour60 session the measurements were already renamed: this
    run's measurements beside the earlier run's truth and config."""
    import fedtrack.sensors.multitarget as mt

    out = tmp_path / "sim"
    args = ["simulate", "multitarget", "--targets", "2", "--duration", "5", "--out", str(out)]
    assert cli(args) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    real_dumps = json.dumps

    def ctrl_c_at_the_truth(obj: object) -> str:
        if isinstance(obj, dict) and "targets" in obj:
            raise KeyboardInterrupt
        return real_dumps(obj)

    monkeypatch.setattr(mt.json, "dumps", ctrl_c_at_the_truth)
    assert cli([*args, "--seed", "2"]) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
