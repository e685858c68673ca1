"""fedtrack bench: deployment latency and throughput, and the estimation core, side by side.

For each sensor count (``--sensors 2,4,8``) a whole federated deployment (router,
sensors, local filters, fusion center; no recorder) runs on loopback twice, interleaved
with the other counts so that the machine's load drifts over all of them alike:

* ``realtime`` pacing at ``speed = 10`` (paper 004 scenario, T = 1 s: 10 scans/s per
  sensor): latency from a sensor's publish to the fused track's arrival at the monitor,
  p50 and p99, measured from the FIRST sensor's publish of the scan (what
  ``fedtrack launch`` prints; it includes the sensors' clock skew, since realtime sensors
  are not phase-aligned) and from the LAST one (the pipeline's own latency, once every
  measurement of the scan is out);
* ``lockstep`` pacing: fused scans per second between the first and the last track;
* for the largest count, ``realtime-tls``: the realtime deployment again, right after the plain
  one, with mutual TLS and the router's access control (``fedtrack demo``'s default,
  :mod:`fedtrack.deploy.security`): the latency cost of authentication, side by side.

Latencies are the steady state: the scans of the first ``STARTUP_S`` seconds (sessions
warming up, first-scan initialisation) are reported apart as ``startup``. Beside each
realtime deployment the transport floor of the same hops, process count and payload sizes
runs with no estimation (:mod:`fedtrack.benchmarks.floor`). Every service's peak RSS and CPU
seconds come from the launcher's samples of ``/proc``.

Then the estimation-core micro-benchmark (:mod:`fedtrack.benchmarks.kf_micro`). Results are
printed as a table with ratios to the smallest sensor count, and written as JSON.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.benchmarks.floor import measure_floor
from fedtrack.benchmarks.kf_micro import bench_kf
from fedtrack.config import seed_number
from fedtrack.deploy.demo import demo_settings, free_port, write_config
from fedtrack.deploy.launcher import Launcher
from fedtrack.deploy.plan import apply_zenoh_settings, service_plan
from fedtrack.jsonl import check_output, output_file
from fedtrack.progress import progress_bar

REALTIME_SPEED = 10.0  # scenario T = 1 s -> 10 scans/s
BENCH_SERVICES = ("router", "sensor", "local-filter", "fusion-center")
QUICK_SCANS = 20
FULL_KF_RUNS, QUICK_KF_RUNS = 2000, 200
KF_LOOP_RUNS, KF_ROUNDS = 50, 5
STARTUP_S = 2.0  # seconds of scans at the start reported apart from the steady state
TLS = "realtime-tls"  # the realtime deployment with mutual TLS and access control (largest sensor count)


def percentiles(values: list[float]) -> dict[str, float]:
    """p50/p99 and the sample count (NaN when empty)."""
    if not values:
        return {"p50": float("nan"), "p99": float("nan"), "n": 0}
    p50, p99 = np.percentile(values, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "n": len(values)}


def summarize_run(launcher: Launcher, n_sensors: int, startup_scans: int) -> dict[str, Any]:
    """Steady-state latencies (first/last publish), start-up latency, sensor skew, scan rate,
    health and per-process peak RSS and CPU of one deployment."""
    arrivals = launcher.report.track_arrivals_ns
    first, last, skew, startup = [], [], [], []
    first_seq = min(arrivals, default=0)
    for seq, arrival in arrivals.items():
        stamps = list(launcher.report.publish_stamps_ns.get(seq, {}).values())
        if len(stamps) != n_sensors:  # some measurement of the scan was not seen by the monitor
            continue
        if seq - first_seq < startup_scans:
            startup.append((arrival - max(stamps)) / 1e6)
            continue
        first.append((arrival - min(stamps)) / 1e6)
        last.append((arrival - max(stamps)) / 1e6)
        skew.append((max(stamps) - min(stamps)) / 1e6)
    times = sorted(arrivals.values())
    rate = (len(times) - 1) / ((times[-1] - times[0]) / 1e9) if len(times) > 1 and times[-1] > times[0] else 0.0
    fusion = launcher.report.health.get("fusion-center/fusion", {})
    return {
        "scans_fused": len(arrivals),
        "latency_first_publish_ms": percentiles(first),
        "latency_last_publish_ms": percentiles(last),
        "startup_latency_last_publish_ms": percentiles(startup),
        "sensor_skew_ms": percentiles(skew),
        "scans_per_s": rate,
        "degraded_scans": int(fusion.get("degraded_scans", 0)),
        "rejected_messages": launcher.report.rejected(),
        "wall_s": launcher.report.wall_s,
        "processes": launcher.report.processes,
        "max_rss_mb": max((p["max_rss_mb"] for p in launcher.report.processes.values()), default=float("nan")),
    }


def run_one(n_sensors: int, pacing: str, max_scans: int | None, seed: int, startup_scans: int) -> dict[str, Any]:
    """One deployment on free loopback ports, in a temporary directory (``pacing`` ``realtime``,
    ``lockstep``, or ``realtime-tls``: realtime with mutual TLS, certificates made there)."""
    with tempfile.TemporaryDirectory(prefix="fedtrack-bench-") as tmp:
        out = Path(tmp)
        base = demo_settings(n_sensors, 1, "federated", seed, free_port(), out,
                             tls_dir=out / "certs" if pacing == TLS else None)
        realtime = pacing in ("realtime", TLS)
        settings = replace(base, deployment=replace(
            base.deployment, name="bench", pacing="realtime" if realtime else pacing,
            speed=REALTIME_SPEED if realtime else 1.0, services=BENCH_SERVICES))
        write_config(settings, out / "config.toml")
        plan = service_plan(settings, out / "config.toml", out, out / "logs")
        launcher = Launcher(settings, plan, quiet=True, max_scans=max_scans,
                            zenoh_config=apply_zenoh_settings(settings, out / "config.toml", out, plan))
        launcher.run()
        return {"sensors": n_sensors, "pacing": pacing, **summarize_run(launcher, n_sensors, startup_scans)}


def run_floor(n_sensors: int, scans: int, startup_scans: int) -> dict[str, Any]:
    """The transport floor of a realtime deployment of ``n_sensors`` (same rate, scans and start-up cut)."""
    return {"pacing": "floor", **measure_floor(n_sensors, f"tcp/127.0.0.1:{free_port()}", scans, REALTIME_SPEED,
                                                startup_scans, f"bench{os.getpid()}n{n_sensors}")}


def values_of(runs: list[dict[str, Any]], path: tuple[str, ...]) -> list[float]:
    """The value at ``path`` (nested keys) of every run."""
    values = []
    for r in runs:
        v: Any = r
        for key in path:
            v = v[key]
        values.append(float(v))
    return values


def median_of(runs: list[dict[str, Any]], path: tuple[str, ...]) -> float:
    values = values_of(runs, path)
    return float(np.median(values)) if values else float("nan")


def summarize(runs: list[dict[str, Any]], counts: list[int]) -> dict[str, dict[str, Any]]:
    """Per sensor count: medians over repeats (and the per-repeat values), ratios to the smallest count."""
    table: dict[str, dict[str, Any]] = {}
    for n in counts:
        rt = [r for r in runs if r["sensors"] == n and r["pacing"] == "realtime" and "error" not in r]
        ls = [r for r in runs if r["sensors"] == n and r["pacing"] == "lockstep" and "error" not in r]
        fl = [r for r in runs if r["sensors"] == n and r["pacing"] == "floor" and "error" not in r]
        tls = [r for r in runs if r["sensors"] == n and r["pacing"] == TLS and "error" not in r]
        table[str(n)] = {
            "latency_first_p50_ms": median_of(rt, ("latency_first_publish_ms", "p50")),
            "latency_first_p99_ms": median_of(rt, ("latency_first_publish_ms", "p99")),
            "latency_last_p50_ms": median_of(rt, ("latency_last_publish_ms", "p50")),
            "latency_last_p99_ms": median_of(rt, ("latency_last_publish_ms", "p99")),
            "startup_latency_last_p50_ms": median_of(rt, ("startup_latency_last_publish_ms", "p50")),
            "startup_latency_last_p99_ms": median_of(rt, ("startup_latency_last_publish_ms", "p99")),
            "floor_p50_ms": median_of(fl, ("p50_ms",)),
            "floor_p99_ms": median_of(fl, ("p99_ms",)),
            "max_rss_mb": max(values_of(rt + ls, ("max_rss_mb",)), default=float("nan")),
            "sensor_skew_p50_ms": median_of(rt, ("sensor_skew_ms", "p50")),
            "realtime_scans_per_s": median_of(rt, ("scans_per_s",)),
            "lockstep_scans_per_s": median_of(ls, ("scans_per_s",)),
            "repeats_latency_last_p50_ms": values_of(rt, ("latency_last_publish_ms", "p50")),
            "repeats_lockstep_scans_per_s": values_of(ls, ("scans_per_s",)),
        }
        if tls:
            row = table[str(n)]
            row["tls_latency_last_p50_ms"] = median_of(tls, ("latency_last_publish_ms", "p50"))
            row["tls_latency_last_p99_ms"] = median_of(tls, ("latency_last_publish_ms", "p99"))
            row["tls_latency_first_p50_ms"] = median_of(tls, ("latency_first_publish_ms", "p50"))
            row["tls_latency_first_p99_ms"] = median_of(tls, ("latency_first_publish_ms", "p99"))
            row["tls_p50_cost_ms"] = row["tls_latency_last_p50_ms"] - row["latency_last_p50_ms"]
            row["tls_p99_cost_ms"] = row["tls_latency_last_p99_ms"] - row["latency_last_p99_ms"]
            row["repeats_tls_latency_last_p50_ms"] = values_of(tls, ("latency_last_publish_ms", "p50"))
    ref = table[str(counts[0])]
    for row in table.values():
        row["latency_last_p50_ratio"] = row["latency_last_p50_ms"] / ref["latency_last_p50_ms"]
        row["lockstep_rate_ratio"] = row["lockstep_scans_per_s"] / ref["lockstep_scans_per_s"]
        row["p50_vs_floor"] = row["latency_last_p50_ms"] / row["floor_p50_ms"]
    return table


def print_table(table: dict[str, dict[str, Any]], kf: dict[str, Any], counts: list[int], startup_scans: int) -> None:
    print(f"\nfedtrack bench: federated, realtime at {REALTIME_SPEED:g} scans/s (latency) and lockstep (rate); "
          f"ratios to {counts[0]} sensors")
    print(f"steady state (the first {startup_scans} scans apart); floor: the same hops, processes and payload sizes "
          "with no estimation")
    head = (f"{'sensors':>7}  {'lat p50/p99 from last publish':>30}  {'ratio':>5}  {'floor p50/p99':>15}  "
            f"{'p50/floor':>9}  {'start-up p50/p99':>17}  {'from first publish':>19}  {'skew p50':>8}  "
            f"{'lockstep scans/s':>16}  {'ratio':>5}  {'max RSS':>8}")
    print(head)
    for n, row in table.items():
        print(f"{n:>7}  {row['latency_last_p50_ms']:>13.2f} / {row['latency_last_p99_ms']:<8.2f} ms    "
              f"{row['latency_last_p50_ratio']:>5.2f}  {row['floor_p50_ms']:>6.2f} / {row['floor_p99_ms']:<6.2f}  "
              f"{row['p50_vs_floor']:>9.2f}  {row['startup_latency_last_p50_ms']:>7.1f} / "
              f"{row['startup_latency_last_p99_ms']:<7.1f}  {row['latency_first_p50_ms']:>7.1f} / "
              f"{row['latency_first_p99_ms']:<8.1f}ms  {row['sensor_skew_p50_ms']:>6.1f}ms  "
              f"{row['lockstep_scans_per_s']:>16.1f}  {row['lockstep_rate_ratio']:>5.2f}  {row['max_rss_mb']:>5.0f} MB")
    for n, row in table.items():
        if "tls_latency_last_p50_ms" in row:
            print(f"\nmutual TLS + access control, {n} sensors, realtime (side by side with the plain run above): "
                  f"from last publish p50 / p99 {row['tls_latency_last_p50_ms']:.2f} / {row['tls_latency_last_p99_ms']:.2f} "
                  f"ms against {row['latency_last_p50_ms']:.2f} / {row['latency_last_p99_ms']:.2f} ms plain "
                  f"(cost {row['tls_p50_cost_ms']:+.2f} / {row['tls_p99_cost_ms']:+.2f} ms); from first publish "
                  f"{row['tls_latency_first_p50_ms']:.2f} / {row['tls_latency_first_p99_ms']:.2f} ms against "
                  f"{row['latency_first_p50_ms']:.2f} / {row['latency_first_p99_ms']:.2f} ms")
    print(f"\nestimation core, CV Kalman scan-update ({kf['runs_batched']} runs batched, "
          f"{kf['runs_loop']} in loops, {kf['rounds']} alternating rounds; ratio = time per update / batched)")
    for name, m in kf["methods"].items():
        if isinstance(m, str):
            print(f"  {name:<9} {m}")
        else:
            print(f"  {name:<9} {m['us_per_update_median']:9.2f} us/update  ratio {m['ratio_to_batched_median']:7.1f} "
                  f"(rounds {m['ratio_to_batched_min']:.1f}-{m['ratio_to_batched_max']:.1f})  "
                  f"max rel diff {m['max_rel_diff_to_batched']:.1e}")


def sensor_counts(text: str) -> list[int]:
    try:
        counts = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not counts or any(not 1 <= n <= 32 for n in counts) or len(set(counts)) != len(counts):
        raise argparse.ArgumentTypeError(f"need distinct sensor counts between 1 and 32, got {text!r}")
    return counts


def versions() -> dict[str, str]:
    return {"python": platform.python_version(), "numpy": np.__version__,
            "eclipse-zenoh": importlib.metadata.version("eclipse-zenoh"), "cpus": str(os.cpu_count())}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack bench [pipeline]", description=__doc__.splitlines()[0],
                                     epilog="Other suites: fedtrack bench kernels|montecarlo|multitarget|scale|all "
                                            "[--json PATH] [--quick], fedtrack bench soak|hpda-soak [--minutes M] "
                                            "[--json PATH] (no --quick: --minutes sets their length); each has its "
                                            "own --help (docs/bench.md).")
    parser.add_argument("--sensors", type=sensor_counts, default=[2, 4, 8], help="sensor counts (default 2,4,8)")
    parser.add_argument("--quick", action="store_true",
                        help=f"smoke test: {QUICK_SCANS} scans per deployment (the first {QUICK_SCANS // 4} "
                             f"counted as start-up), {QUICK_KF_RUNS} KF runs")
    parser.add_argument("--repeats", type=int, default=1, help="deployments per count and pacing (default 1)")
    parser.add_argument("--seed", type=seed_number, default=1, help="seed of the simulated sensors (default: %(default)s)")
    parser.add_argument("--json", type=Path, default=Path("bench.json"), help="output JSON (default bench.json)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    check_output(args.json)
    counts = sorted(args.sensors)
    max_scans = QUICK_SCANS if args.quick else None
    startup_scans = QUICK_SCANS // 4 if args.quick else int(STARTUP_S * REALTIME_SPEED)
    start = time.monotonic()
    runs: list[dict[str, Any]] = []
    with progress_bar(args.repeats * (len(counts) * 3 + 1) + KF_ROUNDS, "bench") as progress:
        for repeat in range(args.repeats):
            for n in counts:
                realtime = ["realtime", TLS] if n == counts[-1] else ["realtime"]
                if repeat % 2:  # alternate which of the two goes first
                    realtime.reverse()
                for pacing in (*realtime, "floor", "lockstep"):
                    try:
                        if pacing == "floor":
                            scans = max([r["scans_fused"] for r in runs if r["sensors"] == n
                                         and r["pacing"] == "realtime" and "error" not in r], default=QUICK_SCANS)
                            runs.append(run_floor(n, scans, startup_scans))
                        else:
                            runs.append(run_one(n, pacing, max_scans, args.seed, startup_scans))
                    except (RuntimeError, OSError, subprocess.SubprocessError) as exc:  # LaunchError, SessionError too
                        print(f"\nfedtrack bench: {n} sensors, {pacing}: {exc}", file=sys.stderr)
                        runs.append({"sensors": n, "pacing": pacing, "error": str(exc)})
                    progress.update()
        kf = bench_kf(QUICK_KF_RUNS if args.quick else FULL_KF_RUNS, KF_LOOP_RUNS, KF_ROUNDS, args.seed,
                      tick=progress.update)
    table = summarize(runs, counts)
    result = {
        "sensors": counts, "quick": args.quick, "repeats": args.repeats, "seed": args.seed,
        "mode": "federated", "realtime_speed": REALTIME_SPEED, "max_scans": max_scans, "startup_scans": startup_scans,
        "deployments": runs, "summary": table, "kf_micro": kf, "versions": versions(),
        "wall_time_s": time.monotonic() - start,
    }
    print_table(table, kf, counts, startup_scans)
    with output_file(args.json) as fh:
        fh.write(json.dumps(result, indent=2))
    print(f"\nwrote {args.json} ({result['wall_time_s']:.0f} s)")
    return 1 if any("error" in r for r in runs) else 0
