"""Smoke test of ``fedtrack bench --quick --sensors 2``: it runs and writes the expected JSON.

No timing assertions (the machine is shared); only structure, counts and the exact
agreement of the batched and looped Kalman filters.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fedtrack.benchmarks.kf_micro import make_data, run_batched, run_loop
from fedtrack.benchmarks.run import QUICK_SCANS, sensor_counts

REPO = Path(__file__).resolve().parents[1]


def test_bench_quick_writes_expected_json(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "bench", "--quick", "--sensors", "2",
                           "--json", str(out)], cwd=REPO, capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "lockstep scans/s" in proc.stdout
    result = json.loads(out.read_text())
    assert {"sensors", "quick", "deployments", "summary", "kf_micro", "versions", "wall_time_s"} <= set(result)
    assert result["sensors"] == [2] and result["quick"] is True
    assert sorted(r["pacing"] for r in result["deployments"]) == ["floor", "lockstep", "realtime", "realtime-tls"]
    floor = next(r for r in result["deployments"] if r["pacing"] == "floor")
    assert floor["steady_scans"] > 0 and 0 < floor["p50_ms"] <= floor["p99_ms"]
    assert set(floor["payload_bytes"]) == {"meas", "est", "track", "reset"}
    for run in (r for r in result["deployments"] if r["pacing"] != "floor"):
        assert {"router/router", "fusion-center/fusion", "local-filter/1", "sensor/1"} <= set(run["processes"])
        assert all(p["max_rss_mb"] > 0 and p["cpu_s"] >= 0 for p in run["processes"].values())
        assert run["scans_fused"] >= QUICK_SCANS
        # degraded scans depend on timing (a loaded machine, the early stop): reported, not asserted
        assert isinstance(run["degraded_scans"], int) and run["rejected_messages"] == 0
        assert run["latency_last_publish_ms"]["n"] > 0
        assert math.isfinite(run["latency_last_publish_ms"]["p99"]) and run["scans_per_s"] > 0
    row = result["summary"]["2"]
    assert {"latency_last_p50_ms", "latency_last_p99_ms", "latency_first_p50_ms", "latency_first_p99_ms",
            "lockstep_scans_per_s", "lockstep_rate_ratio", "latency_last_p50_ratio", "floor_p50_ms",
            "startup_latency_last_p99_ms", "p50_vs_floor", "max_rss_mb"} <= set(row)
    assert math.isfinite(row["floor_p50_ms"]) and row["max_rss_mb"] > 0
    assert row["lockstep_rate_ratio"] == 1.0 and row["latency_last_p50_ratio"] == 1.0
    tls = next(r for r in result["deployments"] if r["pacing"] == "realtime-tls")
    assert row["tls_latency_last_p50_ms"] == tls["latency_last_publish_ms"]["p50"] > 0
    assert row["tls_p50_cost_ms"] == row["tls_latency_last_p50_ms"] - row["latency_last_p50_ms"]
    assert "mutual TLS + access control, 2 sensors" in proc.stdout
    methods = result["kf_micro"]["methods"]
    assert {"batched", "loop", "filterpy"} <= set(methods)
    assert methods["loop"]["max_rel_diff_to_batched"] <= 1e-12
    assert methods["filterpy"] == "not installed" or methods["filterpy"]["max_rel_diff_to_batched"] < 1e-6


def test_batched_and_looped_kf_agree_exactly() -> None:
    model, R, data = make_data(runs=7, seed=3)
    batched, looped = run_batched(model, R, data), run_loop(model, R, data)
    np.testing.assert_allclose(looped.x, batched.x, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(looped.P, batched.P, rtol=1e-12, atol=1e-9)
    assert np.allclose(batched.P, np.swapaxes(batched.P, -1, -2))


@pytest.mark.parametrize("text", ["", "0", "2,2", "two", "33"])
def test_bad_sensor_counts_are_rejected(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="sensor counts|integers"):
        sensor_counts(text)


def test_bench_kernels_quick_reports_ratios_side_by_side(tmp_path: Path) -> None:
    out = tmp_path / "kernels.json"
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "bench", "kernels", "--quick", "--json", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(out.read_text())
    assert set(result["ratios"]) >= {"kf_vs_filterpy", "kf_vs_stonesoup", "ekf_vs_filterpy", "ekf_vs_stonesoup",
                                     "imm13_vs_filterpy", "aovsimm_vs_fsimm_cpu", "pda_vs_stonesoup"}
    assert set(result["batched_target_steps_per_s"]) == {"1", "100", "10000"}
    assert all(v > 0 for v in result["batched_target_steps_per_s"].values())
    times = result["kernels"]["seconds_per_step"]
    assert times["kf"]["fedtrack"] > 0 and times["kf"]["numpy_floor"] > 0
    for lib in ("filterpy", "stonesoup"):
        if lib in result["kernels"]["missing"]:
            assert result["ratios"][f"kf_vs_{lib}"] is None and lib in proc.stderr
        else:
            assert result["ratios"][f"kf_vs_{lib}"] == times["kf"]["fedtrack"] / times["kf"][lib]


def test_bench_without_its_extra_says_how_to_install_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """FilterPy and Stone Soup not importable (a fresh ``make install``): ``bench kernels --quick`` skips their
    columns and says how to install the extra from the checkout, as docs/bench.md does (tour59: it said
    ``pip install 'fedtrack[bench]'``, a package index's name, not this checkout)."""
    from fedtrack import cli

    for name in ("filterpy", "stonesoup"):
        monkeypatch.setitem(sys.modules, name, None)  # an import of it, or of a submodule, fails
    assert cli.main(["bench", "kernels", "--quick", "--json", str(tmp_path / "k.json")]) == 0
    assert ("fedtrack bench: filterpy, stonesoup not installed (the bench extra: .venv/bin/pip install -e '.[bench]' "
            "in the checkout): those comparisons are skipped") in capsys.readouterr().err


def test_bench_scale_quick_reports_every_region(tmp_path: Path) -> None:
    """``bench scale --quick --targets 100 --process-rounds 2`` (about 50 s, 32 replay processes): per
    region count, a CPU time and state size per region, hand-overs, GOSPA; one region's GOSPA is the
    reference of the others; the area and the clutter count scaled to keep the 1,000-target scenario's
    densities; each centre in its own process, two rounds: CPU seconds and RSS per region with their
    standard errors, the busiest's ratio to the one region's, issue 27's two CPU readings and its RSS bar."""
    from fedtrack.benchmarks.scale import load_model
    from fedtrack.sensors.multitarget import Scenario

    out = tmp_path / "scale.json"
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "bench", "scale", "--quick", "--targets", "100",
                           "--process-rounds", "2", "--json", str(out)], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    scale = json.loads(out.read_text())["scale"]
    assert scale["targets"] == 100 and scale["duration_s"] == 20.0
    assert scale["half_width_m"] == pytest.approx(Scenario.region * 0.1**0.5, rel=1e-12)  # 100 / (2 hw)^2 as at 1,000
    assert scale["clutter_per_scan"] == pytest.approx(Scenario.clutter / 10, rel=1e-12)
    runs = scale["runs"]
    assert sorted(runs, key=int) == ["1", "2", "4", "8"]
    for n, row in runs.items():
        assert len(row["cpu_s"]) == len(row["state_bytes"]) == len(row["tracks"]) == len(row["rows"]) == int(n)
        assert all(0 <= t <= r for t, r in zip(row["rows_taken"], row["rows"]))  # its own and its margin's
        assert all(c > 0 for c in row["cpu_s"]) and row["gospa"] > 0
        assert row["gospa_vs_one"] == pytest.approx(row["gospa"] / runs["1"]["gospa"] - 1.0)
    assert runs["1"]["rows_taken"] == runs["1"]["rows"] and 0 < runs["4"]["busiest_rows_vs_one"] < 1
    assert runs["1"]["hand_overs"] == 0 and runs["8"]["hand_overs"] > 0
    for row in runs.values():  # every hand-over moved its track: never in two centres or twice in a picture
        assert row["ids_twice_in_a_picture"] == 0 and row["ids_held_by_two_centres"] == 0
        assert row["id_switches"] >= 0 and row["id_switches_vs_one"] == row["id_switches"] - runs["1"]["id_switches"]
    own = scale["own_process"]
    assert own["rounds"] == 2 and sorted(own["runs"], key=int) == ["1", "2", "4", "8"]
    assert own["unsharded"]["cpu_s"] > 0 and own["unsharded"]["cpu_s_se"] >= 0
    for n, row in own["runs"].items():
        for key in ("cpu_s", "calls_cpu_s", "picture_cpu_s", "rss_before_mb", "rss_peak_mb", "own_rss_mb"):
            assert len(row[key]) == len(row[f"{key}_se"]) == int(n) and all(se >= 0 for se in row[f"{key}_se"])
        assert all(c > 0 for c in row["cpu_s"]) and all(0 <= m for m in row["own_rss_mb"])
        assert all(p >= b > 0 for p, b in zip(row["rss_peak_mb"], row["rss_before_mb"]))
        busiest = row["busiest"]
        assert row["cpu_s"][busiest] == max(row["cpu_s"]) and len(row["busiest_vs_one_rounds"]) == 2
        assert row["busiest_vs_one"] == pytest.approx(np.mean(row["busiest_vs_one_rounds"]))
        for key in ("busiest_vs_one", "busiest_calls_vs_one", "busiest_vs_unsharded", "largest_rss_vs_one",
                    "largest_own_rss_vs_one"):
            assert row[key] > 0 and row[f"{key}_se"] >= 0
    assert own["runs"]["1"]["busiest_vs_one"] == 1.0 and own["runs"]["1"]["busiest_vs_one_se"] == 0.0
    bar = scale["issue_27_load"]
    assert bar["cpu_bar_plus_0.15"] == 0.4 and bar["cpu_bar_times_1.15"] == pytest.approx(0.2875)
    assert bar["rss_bar"] == 0.5
    assert bar["in_process_busiest_vs_one"] == runs["4"]["max_cpu_vs_one"]
    assert bar["own_process_busiest_vs_one"] == own["runs"]["4"]["busiest_vs_one"]
    assert bar["cpu_met_plus_0.15"] == (bar["own_process_busiest_vs_one"] <= 0.4)
    assert bar["cpu_met_times_1.15"] == (bar["own_process_busiest_vs_one"] <= 0.2875)
    assert "own process" in proc.stdout and "in one process" in proc.stdout  # the printed table, both beside
    # the model: no margin share when the margin is nil, all of it when it spans the cell
    assert load_model(4, 100, 2, 1.0, 1000.0, 0.0, 10.0)["margin_share"] == 0.0
    assert load_model(4, 100, 2, 1.0, 1000.0, 500.0, 10.0)["margin_share"] == 1.0


def test_bench_scale_shows_progress_by_the_progress_rule(tmp_path: Path) -> None:
    """``bench scale``'s bars follow every command's rule (fedtrack.progress): none when stderr is no terminal
    (tour59: a run into a log file got each region's bar, carriage returns and all), one given
    ``FEDTRACK_PROGRESS=1``."""
    argv = [sys.executable, "-m", "fedtrack.cli", "bench", "scale", "--quick", "--targets", "10", "--duration", "4",
            "--process-rounds", "0", "--json", str(tmp_path / "s.json")]
    env = {k: v for k, v in os.environ.items() if k != "FEDTRACK_PROGRESS"}
    quiet = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=300, env=env)
    forced = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=300,
                            env={**env, "FEDTRACK_PROGRESS": "1"})
    assert quiet.returncode == forced.returncode == 0, quiet.stderr[-2000:] + forced.stderr[-2000:]
    assert "regions:" not in quiet.stderr and "%|" not in quiet.stderr
    assert "1 regions:" in forced.stderr and "picture" in forced.stderr


def test_ids_held_by_two_counts_each_extra_holder() -> None:
    """A track id live in two region centres counts once, in three twice; dead slots never."""
    from types import SimpleNamespace

    from fedtrack.benchmarks.scale import ids_held_by_two

    def region(ids: list[int], live: list[int]) -> SimpleNamespace:
        tracks = SimpleNamespace(ids=np.array(ids), live=lambda: np.array(live, dtype=np.int64))
        return SimpleNamespace(centre=SimpleNamespace(tracks=tracks))

    apart = SimpleNamespace(centres=[region([1, 2, 7], [0, 1]), region([7, 3], [1])])  # 7 dead in the first
    assert ids_held_by_two(apart) == 0
    copied = SimpleNamespace(centres=[region([1, 2], [0, 1]), region([2, 3], [0, 1]), region([2], [0])])
    assert ids_held_by_two(copied) == 2


@pytest.mark.parametrize(("argv", "said"), [
    (["soak", "--minutes", "0"], "fedtrack bench soak: error: --minutes: must be finite and > 0, got 0"),
    (["soak", "--sensors", "40"], "fedtrack bench soak: error: --sensors: must be between 1 and 32, got 40"),
    (["hpda-soak", "--minutes", "0.3"],
     "fedtrack bench hpda-soak: error: --minutes: must be finite and >= 1 (its numbers are per minute), got 0.3"),
    (["hpda-soak", "--rate", "inf"], "fedtrack bench hpda-soak: error: --rate: must be finite and > 0, got inf")])
def test_a_soak_refused_names_the_option_and_value(argv: list[str], said: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The soaks' bounds, one option and its value a line (tour59: one sentence for all options, no value)."""
    from fedtrack import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main(["bench", *argv])
    assert exit_.value.code == 2 and capsys.readouterr().err.splitlines()[-1] == said


def test_stone_soup_missing_is_said_once_a_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Without the ``bench`` extra each Stone Soup comparison is skipped, said in one line for the run (tour59:
    ``bench multitarget --quick`` said it four times, once per scenario)."""
    from fedtrack.benchmarks import suites

    monkeypatch.setitem(sys.modules, "stonesoup", None)
    suites.stonesoup_missing.cache_clear()
    try:
        assert suites.stonesoup_runs(tmp_path, tmp_path / "c.toml", ("s1",), {}) is None
        assert suites.stonesoup_associations(tmp_path, tmp_path / "c.toml", ("gnn", "jpda")) == {}
    finally:
        suites.stonesoup_missing.cache_clear()  # the next test's run looks again
    assert capsys.readouterr().err.count("stonesoup not installed") == 1


def test_bench_soak_shows_its_progress(tmp_path: Path) -> None:
    """``bench soak`` runs for ``--minutes`` (10 by default) with the launch's lines in its launch.log: a bar
    of the soak's seconds on a terminal (forced here; tour59: nothing on the screen until the end)."""
    env = {**os.environ, "FEDTRACK_PROGRESS": "1"}
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "bench", "soak", "--minutes", "0.1", "--sensors", "1",
                           "--json", str(tmp_path / "soak.json")], cwd=REPO, capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "soak:" in proc.stderr and "/6 [" in proc.stderr  # the bar: seconds done of 6
    result = json.loads((tmp_path / "soak.json").read_text())
    assert result["scans_fused"] > 0  # stopped by Ctrl-C (130) or at its end
    # the 6 s count from the sensors' start: the start-up (at a load of 16 it took the 6 s, 0 scans fused) not in them
    assert result["start_up_s"] > 0


def test_bench_montecarlo_names_each_reproduction_as_it_starts(monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``bench montecarlo`` runs three reproductions (hpda's 500 runs take minutes) with their output in a log:
    on a terminal (forced here) a bar names each as it starts (tour59: nothing until the end). The
    reproductions stand in for themselves here (a wall time of 1 s, vsimm's JSON)."""
    from fedtrack.benchmarks import suites

    def reproduce(cmd: list[str], cwd: Path | None = None) -> tuple[float, float]:
        if "vsimm" in cmd:
            filters = {"ao_vsimm": {"cpu_ratio_to_fsimm": 0.8, "mean_rms_acc": 1.0}, "fsimm": {"mean_rms_acc": 1.0}}
            Path(cmd[cmd.index("--json") + 1]).write_text(json.dumps({"scenarios": {"a": {"filters": filters}}}))
        return 1.0, 0.0

    monkeypatch.setattr(suites, "timed", reproduce)
    monkeypatch.setenv("FEDTRACK_PROGRESS", "1")
    assert suites.bench_montecarlo(quick=True) == {"fvdie_20": 1.0, "hpda_20": 1.0, "vsimm_20": 1.0,
                                                   "aovsimm_vs_fsimm_cpu": 0.8, "aovsimm_rmse_vs_fsimm": 1.0}
    err = capsys.readouterr().err
    assert all(f"montecarlo: reproduce {name} --runs 20" in err for name in ("fvdie", "hpda", "vsimm"))
    assert "3/3" in err
