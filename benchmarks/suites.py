"""``fedtrack bench [kernels | montecarlo | multitarget | scale | pipeline | soak | hpda-soak | all] [--json PATH] [--quick]``.

* ``kernels``: CV KF and radar EKF steps against FilterPy, Stone Soup and a numpy floor;
  batched KF target-steps per second (:mod:`fedtrack.benchmarks.kernels`).
* ``montecarlo``: wall time of ``reproduce fvdie --runs 500`` and ``reproduce hpda --runs 500``, and
  AO-VSIMM's CPU time over FSIMM's (``aovsimm_vs_fsimm_cpu``) in ``reproduce vsimm --runs 200``.
* ``multitarget``: a 1,000-target, 4-sensor (1 Hz) scenario replayed by ``mtt-centralized``,
  ``mtt-federated`` and ``mtt-decentralized`` in three interleaved rounds (the fastest run's seconds
  per scan and speed against real time, every run's wall time, the peak RSS of the process),
  and mean GOSPA on the simulator's default scenario for every sensor's own tracker, the
  three fusions and Stone Soup's GNN tracker on each sensor's detections and on all of them
  (:mod:`fedtrack.benchmarks.stonesoup_mtt`, with the ``bench`` extra), every picture holding
  every scan up to its time (``picture_delay = max_lag``); then two live deployments
  (:func:`bench_live`): 200 targets and 4 sensors at real time (picture latency), and sensors
  joining and leaving (``deploy/join-leave.toml``'s script: the join's association delay, the
  kill's detection time, central tracks lost); and issue 25's association table
  (:func:`bench_association`): mean GOSPA and its parts on the default and the dense scenario for
  ``gnn``, ``jipda`` and ``mht`` in ``mtt-centralized``, ``mtt-federated`` and ``mtt-local`` (s1)
  and for Stone Soup's GNN and JPDA trackers on all detections, with ``jipda``'s and ``mht``'s
  1,000-target speed.
* ``scale``: the centre sharded by region, 1 / 2 / 4 / 8 regions at 1,000 targets, or ``--targets N``
  at the same densities (``--duration S``; :mod:`fedtrack.benchmarks.scale`; not part of ``all``).
* ``pipeline``: the deployment latency bench (:mod:`fedtrack.benchmarks.run`, its options).
* ``soak``: a long deployment at the lockstep rate (:mod:`fedtrack.benchmarks.soak`; 10 minutes
  by default, not part of ``all``).
* ``hpda-soak``: ``fedtrack serve hpda`` for 10 minutes in the paper's densest clutter
  (:mod:`fedtrack.benchmarks.hpda_soak`, its own options; not part of ``all``).
* ``all``: all of them, and the start-up costs (``fedtrack --help``, importing the fusion
  centre). The JSON carries the keys of issue 14; what this version does not measure is
  ``null`` and listed under ``not_measured``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.config import ConfigError
from fedtrack.jsonl import InputError, check_output, output_file
from fedtrack.progress import progress_bar

# fedtrack is installed from its checkout (make install), not from a package index: 'pip install fedtrack[bench]', as
# the bench said until the tour59 session, would look for a package of that name there
INSTALL_BENCH = "the bench extra: .venv/bin/pip install -e '.[bench]' in the checkout"
SUITES = ("kernels", "montecarlo", "multitarget", "scale", "pipeline", "soak", "hpda-soak", "all")
# what ``fedtrack bench SUITE --help`` says each suite does (plain text; the module docstring has the details)
ABOUT = {
    "kernels": "fedtrack bench kernels: CV KF and radar EKF steps against FilterPy, Stone Soup and a numpy floor, "
               "and batched KF target-steps per second.",
    "montecarlo": "fedtrack bench montecarlo: the wall time of reproduce fvdie and reproduce hpda at 500 runs, and "
                  "AO-VSIMM's CPU time over FSIMM's in reproduce vsimm at 200 runs.",
    "multitarget": "fedtrack bench multitarget: 1,000 targets replayed by mtt-centralized, mtt-federated and "
                   "mtt-decentralized; GOSPA beside Stone Soup's trackers; two live deployments (200 targets; sensors "
                   "joining and leaving); the association table of gnn, jipda and mht.",
    "scale": "fedtrack bench scale: the centre sharded by region, 1 / 2 / 4 / 8 regions at 1,000 targets or --targets "
             "N at the same densities, then every region centre replayed in its own process (not part of all).",
    "all": "fedtrack bench all: kernels, montecarlo, multitarget and pipeline, and the start-up costs (not scale, soak "
           "or hpda-soak).",
}
RATIO_KEYS = ("kf_vs_filterpy", "kf_vs_stonesoup", "ekf_vs_filterpy", "ekf_vs_stonesoup", "imm13_vs_filterpy",
              "aovsimm_vs_fsimm_cpu", "pda_vs_stonesoup")


def fedtrack_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "fedtrack.cli", *args]


class ChildRun(NamedTuple):
    """One child process: wall seconds, CPU seconds (user + system), peak RSS (MB), its stderr."""

    wall: float
    cpu: float
    rss_mb: float
    log: str


def timed(cmd: list[str], cwd: Path | None = None) -> tuple[float, float]:
    """Wall seconds and peak RSS (MB) of one child process; a failure is an error."""
    run = timed_with_log(cmd, cwd)
    return run.wall, run.rss_mb


def timed_with_log(cmd: list[str], cwd: Path | None = None) -> ChildRun:
    """:func:`timed`, the child's CPU time and its stderr."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=log)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        err = log.read().decode(errors="replace")
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[2:])} failed: {err.strip().splitlines()[-1:]}")
    return ChildRun(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, err)


def stages_of(log: str) -> dict[str, float]:
    """The ``seconds per input scan by stage`` line a multi-target replay prints."""
    for line in log.splitlines():
        if "seconds per input scan by stage:" in line:
            body = line.split("by stage:", 1)[1].rsplit("(", 1)[0]
            return {name.strip(): float(value) for name, value in
                    (part.strip().rsplit(" ", 1) for part in body.split(",") if part.strip())}
    return {}


def bench_montecarlo(quick: bool) -> dict[str, Any]:
    """Wall times of the reproductions; also ``aovsimm_vs_fsimm_cpu``, the larger over paper 000's
    two scenarios of AO-VSIMM's CPU time over FSIMM's in ``reproduce vsimm --runs 200``."""
    runs = "20" if quick else "500"
    out: dict[str, Any] = {}
    # a bar of the three reproductions, each named as it starts (their own bars go to a log: hpda's 500 runs
    # took minutes with nothing on the screen until the tour59 session)
    with tempfile.TemporaryDirectory() as tmp, progress_bar(3, "montecarlo", unit="reproduction") as bar:
        for name in ("fvdie", "hpda"):
            bar.set_description(f"montecarlo: reproduce {name} --runs {runs}")
            wall, _ = timed(fedtrack_cmd("reproduce", name, "--runs", runs, "--seed", "1", "--json",
                                         str(Path(tmp) / f"{name}.json")))
            out[f"{name}_{runs}"] = wall
            bar.update()
        vsimm_runs = "20" if quick else "200"
        path = Path(tmp) / "vsimm.json"
        bar.set_description(f"montecarlo: reproduce vsimm --runs {vsimm_runs}")
        out[f"vsimm_{vsimm_runs}"], _ = timed(fedtrack_cmd("reproduce", "vsimm", "--runs", vsimm_runs, "--seed", "1",
                                                           "--json", str(path)))
        bar.update()
        scenarios = json.loads(path.read_text())["scenarios"].values()
        out["aovsimm_vs_fsimm_cpu"] = max(sc["filters"]["ao_vsimm"]["cpu_ratio_to_fsimm"] for sc in scenarios)
        out["aovsimm_rmse_vs_fsimm"] = max(sc["filters"]["ao_vsimm"]["mean_rms_acc"] / sc["filters"]["fsimm"]["mean_rms_acc"]
                                           for sc in scenarios)
    return out


SCALE_ROUNDS = 3


def bench_multitarget(quick: bool) -> dict[str, Any]:
    targets, duration = (50, 20.0) if quick else (1000, 60.0)
    out: dict[str, Any] = {"scale": {"targets": targets, "sensors": 4, "period_s": 1.0, "duration_s": duration}}
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "scale"
        timed(fedtrack_cmd("simulate", "multitarget", "--targets", str(targets), "--duration", str(duration),
                           "--sensors", "pos:1.0,pos:1.0,pos:1.0,pos:1.0", "--seed", "2", "--out", str(sim)))
        scans = sum(1 for _ in (sim / "measurements.jsonl").open())
        # SCALE_ROUNDS interleaved rounds, each algorithm's fastest run reported: this shared
        # machine's speed changes by up to 1.7x within minutes, the fastest run is the least
        # disturbed (every run is kept in ``wall_s_runs``)
        algorithms = ("mtt-centralized", "mtt-federated", "mtt-decentralized")
        runs: dict[str, list[ChildRun]] = {a: [] for a in algorithms}
        # the central tracks' maneuver detector's cost (federated with [mtt] maneuver = "vdie") and
        # jipda's (centralized and federated with [mtt] associator = "jipda") and mht's
        # (centralized), in every round as the rest (jipda's is issue 25's speed bar)
        variants = {"mtt-federated:vdie": ("mtt-federated", 'maneuver = "vdie"'),
                    "mtt-centralized:jipda": ("mtt-centralized", 'associator = "jipda"'),
                    "mtt-federated:jipda": ("mtt-federated", 'associator = "jipda"'),
                    "mtt-centralized:mht": ("mtt-centralized", 'associator = "mht"')}
        configs = {a: sim / "config.toml" for a in algorithms}
        for name, (algorithm, line) in variants.items():
            configs[name] = with_mtt_lines(sim / "config.toml", sim / f"{name.replace(':', '-')}.toml", line)
            runs[name] = []
        for _ in range(1 if quick else SCALE_ROUNDS):
            for name, done in runs.items():
                done.append(timed_with_log(fedtrack_cmd(
                    "replay", "--algorithm", name.split(":")[0], "--config", str(configs[name]),
                    "--measurements", str(sim / "measurements.jsonl"), "--out", str(sim / "scale.jsonl"))))
        for algorithm, done in runs.items():
            fastest = min(done, key=lambda run: run.wall)
            cpu = min(run.cpu for run in done)  # the process's own seconds on its one core
            out["scale"][algorithm] = {"wall_s": fastest.wall, "s_per_scan": fastest.wall / scans,
                                       "x_real_time": duration / fastest.wall, "cpu_s": cpu,
                                       "x_real_time_cpu": duration / cpu,
                                       "max_rss_mb": max(run.rss_mb for run in done),
                                       "s_per_scan_by_stage": stages_of(fastest.log),
                                       "wall_s_runs": [run.wall for run in done], "cpu_s_runs": [run.cpu for run in done]}
        default = Path(tmp) / "default"
        args = ["--duration", "60"] if quick else []
        timed(fedtrack_cmd("simulate", "multitarget", "--seed", "1", "--out", str(default), *args))
        # every picture holds every scan up to its time (Stone Soup gets the scans time-sorted); our
        # trackers with their maneuver handling (VDIE per track), and also without it ("cv:" rows)
        config = with_mtt_lines(default / "config.toml", default / "complete.toml",
                                'picture_delay = 3.0\nmaneuver = "vdie"')
        cv_config = default / "complete-cv.toml"
        cv_config.write_text(config.read_text().replace('maneuver = "vdie"\n', "", 1))
        sensors = ("s1", "s2", "s3")
        runs = [(a, []) for a in ("mtt-centralized", "mtt-federated", "mtt-decentralized")]
        runs += [(f"mtt-local:{s}", ["--sensor", s]) for s in sensors]
        tracks = {name: default / f"{name.replace(':', '-')}.jsonl" for name, _ in runs}
        out["replay_s"] = {}
        for name, extra in runs:
            for prefix, cfg_path in (("", config), ("cv:", cv_config)):
                tracks[prefix + name] = default / f"{prefix.strip(':')}{name.replace(':', '-')}.jsonl"
                out["replay_s"][prefix + name], _ = timed(fedtrack_cmd(
                    "replay", "--algorithm", name.split(":")[0], *extra, "--config", str(cfg_path),
                    "--measurements", str(default / "measurements.jsonl"), "--out", str(tracks[prefix + name])))
        out["stonesoup_gnn_s"] = stonesoup_runs(default, config, sensors, tracks)
        gospa: dict[str, float] = {}
        out["maneuver_flags"] = {}  # evaluate's maneuver section, where a tracker flags maneuvers
        for name, path in tracks.items():
            evaluation = evaluate(path, default / "truth.jsonl")
            gospa[name] = evaluation["mean"]["gospa"]
            if evaluation["maneuvers"]["onsets"]:
                out["maneuver_flags"][name] = evaluation["maneuvers"]
        best_local = min(v for k, v in gospa.items() if k.startswith("mtt-local"))
        cv = {k[3:]: v for k, v in gospa.items() if k.startswith("cv:")}
        out["gospa_default"] = gospa
        out["gospa_ratios"] = {"federated_vs_best_local": gospa["mtt-federated"] / best_local,
                               "decentralized_vs_best_local": gospa["mtt-decentralized"] / best_local,
                               "centralized_vs_best_local": gospa["mtt-centralized"] / best_local,
                               "federated_vs_centralized": gospa["mtt-federated"] / gospa["mtt-centralized"]}
        if "stonesoup:all" in gospa:
            out["gospa_ratios"]["centralized_vs_stonesoup"] = gospa["mtt-centralized"] / gospa["stonesoup:all"]
            out["gospa_ratios"]["cv_centralized_vs_stonesoup"] = cv["mtt-centralized"] / gospa["stonesoup:all"]
            for s in sensors:
                out["gospa_ratios"][f"local_{s}_vs_stonesoup"] = gospa[f"mtt-local:{s}"] / gospa[f"stonesoup:{s}"]
                out["gospa_ratios"][f"cv_local_{s}_vs_stonesoup"] = cv[f"mtt-local:{s}"] / gospa[f"stonesoup:{s}"]
    out["association"] = bench_association(quick)
    return out


def with_mtt_lines(config: Path, out: Path, lines: str) -> Path:
    """``config`` with ``lines`` added at the top of its ``[mtt]`` table, written to ``out``."""
    out.write_text(config.read_text().replace("[mtt]\n", f"[mtt]\n{lines}\n", 1))
    return out


def evaluate(tracks: Path, truth: Path, extra: list[str] | None = None) -> dict[str, Any]:
    """``fedtrack evaluate``'s JSON for ``tracks`` against ``truth`` (``extra``: its options)."""
    result = tracks.with_suffix(".eval.json")
    timed(fedtrack_cmd("evaluate", "--tracks", str(tracks), "--truth", str(truth), "--json", str(result),
                       *(extra or [])))
    return json.loads(result.read_text())


# issue 25's scenarios: (``simulate`` arguments, the same with --quick, the sensor of the mtt-local row,
# ``evaluate --horizontal``); the recorded one needs the repository's tests/data (an editable install)
TRAFFIC_SOURCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "traffic_paris.csv.gz"
ASSOCIATION_SCENARIOS: dict[str, tuple[list[str], list[str], str, bool]] = {
    "default": (["multitarget", "--seed", "1"], ["multitarget", "--seed", "1", "--targets", "15", "--duration", "30"], "s1", False),
    "dense": (["multitarget", "--scenario", "dense", "--seed", "1"],
              ["multitarget", "--scenario", "dense", "--seed", "1", "--targets", "15", "--duration", "30"], "s1", False),
    "traffic": (["traffic", "--source", str(TRAFFIC_SOURCE), "--origin", "48.86,2.40", "--sensors",
                 "radar:4@49.2/2.0/100,radar:5@48.6/2.9/100,pos:2", "--seed", "1", "--start", "60", "--box", "150",
                 "--duration", "600"],
                ["traffic", "--source", str(TRAFFIC_SOURCE), "--origin", "48.86,2.40", "--sensors",
                 "radar:4@49.2/2.0/100,radar:5@48.6/2.9/100,pos:2", "--seed", "1", "--start", "60", "--box", "150",
                 "--duration", "60"], "s3", True),
}


def bench_association(quick: bool) -> dict[str, Any]:
    """Mean GOSPA and its parts (``evaluate``'s means) per scenario, algorithm and associator: the
    scenario's own config with only ``associator`` changed and every picture holding every scan up
    to its time (``picture_delay = max_lag``); Stone Soup's GNN and JPDA trackers on all detections,
    time-sorted (:mod:`fedtrack.benchmarks.stonesoup_mtt`); the bars' ratios. The recorded-traffic
    scenario (Paris, docs/geodetic.md) is scored on x, y (``--horizontal``)."""
    import tomllib

    out: dict[str, Any] = {"gospa": {}, "replay_s": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for scenario, (full, small, own, horizontal) in ASSOCIATION_SCENARIOS.items():
            if scenario == "traffic" and not TRAFFIC_SOURCE.exists():
                print(f"fedtrack bench: {TRAFFIC_SOURCE} not found: the traffic scenario is skipped", file=sys.stderr)
                continue
            folder = Path(tmp) / scenario
            timed(fedtrack_cmd("simulate", *(small if quick else full), "--out", str(folder)))
            max_lag = tomllib.loads((folder / "config.toml").read_text())["mtt"]["max_lag"]
            truth, extra_eval = folder / "truth.jsonl", ["--horizontal"] if horizontal else []
            table: dict[str, dict[str, Any]] = {}
            for associator in ("gnn", "jipda", "mht"):
                config = with_mtt_lines(folder / "config.toml", folder / f"{associator}.toml",
                                        f'picture_delay = {max_lag}\nassociator = "{associator}"')
                for name, extra in (("mtt-centralized", []), ("mtt-federated", []),
                                    (f"mtt-local:{own}", ["--sensor", own])):
                    path = folder / f"{associator}-{name.replace(':', '-')}.jsonl"
                    out["replay_s"][f"{scenario}:{name}:{associator}"], _ = timed(fedtrack_cmd(
                        "replay", "--algorithm", name.split(":")[0], *extra, "--config", str(config),
                        "--measurements", str(folder / "measurements.jsonl"), "--out", str(path)))
                    table.setdefault(name, {})[associator] = evaluate(path, truth, extra_eval)["mean"]
            for association, wall in stonesoup_associations(folder, folder / "gnn.toml", ("gnn", "jpda")).items():
                path = folder / f"stonesoup-{association}.jsonl"
                table.setdefault("stonesoup:all", {})[association] = evaluate(path, truth, extra_eval)["mean"]
                out["replay_s"][f"{scenario}:stonesoup:{association}"] = wall
            out["gospa"][scenario] = table
    for associator in ("jipda", "mht"):
        out[f"{associator}_vs_gnn"] = {f"{scenario}:{name}": row[associator]["gospa"] / row["gnn"]["gospa"]
                                       for scenario, table in out["gospa"].items() for name, row in table.items()
                                       if associator in row}
    ratios = out["jipda_vs_gnn"]
    out["dense_seeds"] = dense_over_seeds(quick)
    # issue 25: the better of jipda / mht (mtt-centralized) against the better Stone Soup tracker, per scenario
    out["best_vs_stonesoup"] = {
        scenario: min(table["mtt-centralized"][a]["gospa"] for a in ("jipda", "mht"))
        / min(m["gospa"] for m in table["stonesoup:all"].values())
        for scenario, table in out["gospa"].items() if "stonesoup:all" in table}
    out["bars"] = {"best_vs_stonesoup_le_0.95": all(r <= 0.95 for r in out["best_vs_stonesoup"].values()),"dense_centralized_jipda_vs_gnn_le_0.85": out["dense_seeds"]["jipda_vs_gnn"]["mean"] <= 0.85,
                   "dense_centralized_mht_vs_gnn_le_0.85": out["dense_seeds"]["mht_vs_gnn"]["mean"] <= 0.85,
                   "jipda_never_2pct_worse": max(ratios.values()) <= 1.02}
    print_association(out["gospa"])
    return out


DENSE_SEEDS = range(1, 9)  # issue 25's dense bars: mht / gnn per seed spreads by about 0.026 (SE 0.009 over 8)


def dense_over_seeds(quick: bool) -> dict[str, Any]:
    """The dense bars over seeds: ``mtt-centralized`` mean GOSPA of ``gnn``, ``jipda`` and ``mht`` on
    ``simulate multitarget --scenario dense --seed N`` for each of :data:`DENSE_SEEDS` (two with
    ``--quick``, at its small size), each seed's config with ``picture_delay = max_lag`` and the
    associator, and the per-seed ratios to ``gnn``: their mean and its standard error. One seed's
    ratio moves by several hundredths from seed to seed, as much as a bar's margin."""
    import tomllib

    seeds = list(DENSE_SEEDS)[:2] if quick else list(DENSE_SEEDS)
    size = ["--targets", "15", "--duration", "30"] if quick else []
    gospa: dict[str, list[float]] = {a: [] for a in ("gnn", "jipda", "mht")}
    with tempfile.TemporaryDirectory() as tmp, progress_bar(len(seeds), "dense seeds", unit="seed") as progress:
        for seed in seeds:
            folder = Path(tmp) / f"dense-{seed}"
            timed(fedtrack_cmd("simulate", "multitarget", "--scenario", "dense", "--seed", str(seed), *size,
                               "--out", str(folder)))
            max_lag = tomllib.loads((folder / "config.toml").read_text())["mtt"]["max_lag"]
            for associator in gospa:
                config = with_mtt_lines(folder / "config.toml", folder / f"{associator}.toml",
                                        f'picture_delay = {max_lag}\nassociator = "{associator}"')
                path = folder / f"{associator}.jsonl"
                timed(fedtrack_cmd("replay", "--algorithm", "mtt-centralized", "--config", str(config),
                                   "--measurements", str(folder / "measurements.jsonl"), "--out", str(path)))
                gospa[associator].append(evaluate(path, folder / "truth.jsonl")["mean"]["gospa"])
            progress.update()
    out: dict[str, Any] = {"seeds": seeds, "gospa": gospa}
    for associator in ("jipda", "mht"):
        r = np.array(gospa[associator]) / np.array(gospa["gnn"])
        se = float(r.std(ddof=1) / np.sqrt(r.size)) if r.size > 1 else float("nan")
        out[f"{associator}_vs_gnn"] = {"per_seed": r.tolist(), "mean": float(r.mean()), "se": se}
        print(f"  dense mtt-centralized {associator} / gnn over seeds {seeds[0]}-{seeds[-1]}: "
              f"{r.mean():.3f} +- {se:.3f} ({', '.join(f'{v:.3f}' for v in r)})", file=sys.stderr)
    return out


def print_association(gospa: dict[str, dict[str, dict[str, Any]]]) -> None:
    """The association table on stderr: mean GOSPA (localisation / missed / false parts)."""
    print("mean GOSPA (localisation / missed / false, p-th power parts)", file=sys.stderr)
    for scenario, table in gospa.items():
        for name, row in table.items():
            cells = [f"{a} {m['gospa']:.2f} ({m['localisation']:.0f} / {m['missed']:.0f} / {m['false']:.0f})"
                     for a, m in row.items()]
            print(f"  {scenario:8s} {name:16s} " + "  ".join(cells), file=sys.stderr)


LIVE_CONFIG = """
[deployment]
name = "bench-{name}"
seed = 1
pacing = "realtime"
speed = {speed}
router_listen = "tcp/127.0.0.1:{port}"
ready_timeout_s = 60.0

[multitarget]
algorithm = "mtt-federated"
targets = {targets}
sensors = "{sensors}"
duration = {duration}
{schedule}

[mtt]
clutter_density = 1e-7
sensors = "any"
associator = "{associator}"
"""


def bench_live(quick: bool) -> dict[str, Any]:
    """Two live deployments through ``fedtrack launch`` (separate processes, loopback router):
    ``keep_up``, 200 targets and 4 sensors (periods 1.0 / 0.7 / 1.3 / 0.9 s) for 60 s at real
    time (picture latency from a sensor's publish), and the same with ``[mtt] associator = "jipda"``
    (``keep_up_jipda``); ``join_leave``, 60 targets, s1 and s2 from
    the start, s3 joining at 30 s and s1 killed at 60 s of 90 s (the script of
    ``deploy/join-leave.toml``; ``summary.json``'s ``membership``)."""
    from fedtrack.deploy.demo import free_port

    keep_up = {"targets": 200 if not quick else 20, "sensors": "pos:1.0,pos:0.7,pos:1.3,pos:0.9",
               "duration": 60.0 if not quick else 15.0, "speed": 1.0 if not quick else 3.0, "schedule": ""}
    runs = {"keep_up": {**keep_up, "associator": "gnn"}, "keep_up_jipda": {**keep_up, "associator": "jipda"},
            "join_leave": {"targets": 60 if not quick else 10, "sensors": "pos:1.0,pos:0.7,pos:1.3",
                           "duration": 90.0 if not quick else 24.0, "speed": 1.0 if not quick else 3.0,
                           "schedule": "join_at = { s3 = 30.0 }\nkill_at = { s1 = 60.0 }" if not quick
                           else "join_at = { s3 = 8.0 }\nkill_at = { s1 = 16.0 }", "associator": "gnn"}}
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, run in runs.items():
            config = Path(tmp) / f"{name}.toml"
            config.write_text(LIVE_CONFIG.format(name=name.replace("_", "-"), port=free_port(), **run))
            folder = Path(tmp) / name
            wall, _ = timed(fedtrack_cmd("launch", str(config), "--out", str(folder)))
            summary = json.loads((folder / "summary.json").read_text())
            out[name] = {"wall_s": wall, **{k: summary.get(k) for k in (
                "pictures", "picture_latency_ms", "mean", "exit_codes", "restarts", "rejected", "membership")}}
    return out


@functools.cache
def stonesoup_missing() -> bool:
    """Whether Stone Soup (the ``bench`` extra) is not installed; said once a run (``bench multitarget --quick``
    said it four times, once per scenario, until the tour59 session)."""
    try:
        import stonesoup  # noqa: F401
    except ImportError:
        print(f"fedtrack bench: stonesoup not installed ({INSTALL_BENCH}): the multi-target "
              "comparisons with Stone Soup are skipped", file=sys.stderr)
        return True
    return False


def stonesoup_config(config: Path) -> Any | None:
    """``config``'s ``[mtt]`` for Stone Soup's trackers, or None without the ``bench`` extra."""
    if stonesoup_missing():
        return None
    from fedtrack.config import load_tables
    from fedtrack.local_filters.mtt.config import MttSettings

    return load_tables(config, MttSettings).mtt


def stonesoup_runs(default: Path, config: Path, sensors: tuple[str, ...], tracks: dict[str, Path]
                   ) -> dict[str, float] | None:
    """Stone Soup's GNN tracker on each sensor's detections and on all of them (adds to ``tracks``);
    wall seconds per run, or None without the ``bench`` extra."""
    cfg = stonesoup_config(config)
    if cfg is None:
        return None
    from fedtrack.benchmarks.stonesoup_mtt import read_scans, stonesoup_tracker

    wall = {}
    for name, only in [("stonesoup:all", None)] + [(f"stonesoup:{s}", {s}) for s in sensors]:
        tracks[name] = default / f"{name.replace(':', '-')}.jsonl"
        t0 = time.perf_counter()
        stonesoup_tracker(read_scans(default / "measurements.jsonl", only), cfg, tracks[name])
        wall[name] = time.perf_counter() - t0
    return wall


def stonesoup_associations(folder: Path, config: Path, associations: tuple[str, ...]) -> dict[str, float]:
    """Stone Soup's trackers (``"gnn"``, ``"jpda"``) on all of ``folder``'s detections, written to
    ``stonesoup-<association>.jsonl``; wall seconds per run (none without the ``bench`` extra)."""
    cfg = stonesoup_config(config)
    if cfg is None:
        return {}
    from fedtrack.benchmarks.stonesoup_mtt import read_scans, stonesoup_tracker

    scans, wall = read_scans(folder / "measurements.jsonl", None), {}
    for association in associations:
        t0 = time.perf_counter()
        stonesoup_tracker(scans, cfg, folder / f"stonesoup-{association}.jsonl", association)
        wall[association] = time.perf_counter() - t0
    return wall


def bench_startup() -> dict[str, float]:
    help_s, _ = timed([sys.executable, "-m", "fedtrack.cli", "--help"])
    import_s, _ = timed([sys.executable, "-c", "import fedtrack.fusion_center.service"])
    return {"help_s": help_s, "import_fusion_center_s": import_s}


def main(argv: list[str]) -> int:
    if argv and not argv[0].startswith("-") and argv[0] not in SUITES:
        raise ConfigError(f"bench: unknown suite {argv[0]!r} (choose from {', '.join(SUITES)})")
    suite = argv[0] if argv and argv[0] in SUITES else "pipeline"
    if suite == "soak":  # 10 minutes by default: not part of "all"
        from fedtrack.benchmarks.soak import main as soak_main
        return soak_main(argv[1:])
    if suite == "hpda-soak":  # 10 minutes by default: not part of "all"
        from fedtrack.benchmarks.hpda_soak import main as hpda_soak_main
        return hpda_soak_main(argv[1:])
    if suite == "pipeline":  # the deployment bench and its own options (the default suite)
        from fedtrack.benchmarks.run import main as pipeline_main
        return pipeline_main(argv[1:] if argv and argv[0] == "pipeline" else argv)
    parser = argparse.ArgumentParser(prog=f"fedtrack bench {suite}", description=ABOUT[suite])
    parser.add_argument("--json", type=Path, default=Path("bench.json"), help="output JSON (default bench.json)")
    parser.add_argument("--quick", action="store_true", help="small sizes (a smoke test; the numbers mean little)")
    if suite == "scale":
        parser.add_argument("--targets", type=int, metavar="N",
                            help="targets (default: 1000; --quick: 50 over the default area); the area and the "
                                 "clutter count grow with N so that both densities stay the 1,000-target scenario's: "
                                 "a square of side 10 km x sqrt(N / 1000)")
        parser.add_argument("--duration", type=float, metavar="S", help="seconds of scenario (default: 60; --quick: 20)")
        parser.add_argument("--gospa-every", type=int, default=1, metavar="K",
                            help="mean GOSPA over the pictures of every K-th second only (default: %(default)s, all; "
                                 "evaluate's assignment is dense, about 10 s a picture at 10,000 targets)")
        parser.add_argument("--process-rounds", type=int, metavar="K",
                            help="rounds of the replay of every region centre in its own process (default: 5; --quick: "
                                 "1; 0: none): CPU seconds and RSS per centre as a deployment runs it")
    args = parser.parse_args(argv[1:])
    args.suite = suite
    rest: list[str] = []
    check_output(args.json)
    result: dict[str, Any] = {"suite": args.suite, "quick": args.quick, "ratios": dict.fromkeys(RATIO_KEYS),
                              "not_measured": []}
    if args.suite in ("kernels", "all"):
        from fedtrack.benchmarks.kernels import bench_kernels
        kernels = bench_kernels(args.quick)
        result["kernels"] = kernels
        result["ratios"].update({k: v for k, v in kernels["ratios"].items() if k in RATIO_KEYS})
        result["batched_target_steps_per_s"] = kernels["batched_target_steps_per_s"]
        if kernels["missing"]:
            print(f"fedtrack bench: {', '.join(kernels['missing'])} not installed ({INSTALL_BENCH}): "
                  "those comparisons are skipped", file=sys.stderr)
    if args.suite in ("montecarlo", "all"):
        montecarlo = bench_montecarlo(args.quick)
        result["ratios"]["aovsimm_vs_fsimm_cpu"] = montecarlo.pop("aovsimm_vs_fsimm_cpu")
        result["aovsimm_rmse_vs_fsimm"] = montecarlo.pop("aovsimm_rmse_vs_fsimm")
        result["montecarlo_s"] = montecarlo
    if args.suite in ("multitarget", "all"):
        result["multitarget"] = bench_multitarget(args.quick)
        result["multitarget"]["live"] = bench_live(args.quick)
    if args.suite == "scale":  # minutes: not part of "all"
        from fedtrack.benchmarks.scale import bench_scale
        for name, value in (("targets", args.targets), ("duration", args.duration), ("gospa-every", args.gospa_every)):
            if value is not None and not 0 < value < float("inf"):
                raise InputError(f"--{name}: must be finite and > 0, got {value:g}")
        if args.process_rounds is not None and args.process_rounds < 0:
            raise InputError(f"--process-rounds: must be >= 0, got {args.process_rounds}")
        result["scale"] = bench_scale(args.quick, args.targets, args.duration, args.gospa_every, args.process_rounds)
    if args.suite == "all":
        result["import_s"] = bench_startup()
        with tempfile.TemporaryDirectory() as tmp:
            pipeline_json = Path(tmp) / "pipeline.json"
            from fedtrack.benchmarks.run import main as pipeline_main
            pipeline_main(["--json", str(pipeline_json)] + (["--quick"] if args.quick else []) + rest)
            result["pipeline_bench"] = json.loads(pipeline_json.read_text())
        result["pipeline"] = {n: {"p50_ms": row["latency_last_p50_ms"], "p99_ms": row["latency_last_p99_ms"],
                                  "floor_p50_ms": row["floor_p50_ms"], "scans_per_s": row["lockstep_scans_per_s"],
                                  "max_rss_mb": row["max_rss_mb"]}
                              for n, row in result["pipeline_bench"].get("summary", {}).items()}
    result["not_measured"] = sorted(k for k, v in result["ratios"].items() if v is None)
    with output_file(args.json) as fh:
        fh.write(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k not in ("kernels", "pipeline_bench")}, indent=1))
    print(f"wrote {args.json}")
    return 0
