"""``fedtrack bench soak [--minutes 10] [--sensors 4] [--json PATH]``: a long deployment at the
maximum (lockstep) rate, outside CI (issue 13).

``fedtrack launch`` runs a federated deployment of ``--sensors`` position sensors whose scenario
lasts longer than the soak (``[deployment] duration_s``); ``--minutes`` after its sensors start (the start-up,
every other service ready, not counted: ``start_up_s``) the bench stops it
with SIGINT (the launcher's own Ctrl-C path: every service stops cleanly and the summary is
written). Every 5 s it samples the resident set size (``VmRSS``) of every process of the
deployment from ``/proc``. Reported: scans fused and their rate, scans lost (fused degraded,
i.e. without some sensor's estimate, or skipped), every process's RSS in the first and the last
minute (medians) and its growth, also from the minute after the publishers' history caches
(``CACHE_SAMPLES`` messages per key for these messages of a few kB: ``cache_depth``) have filled, the RSS series, and the launcher's
exit code.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from fedtrack.deploy.procstat import process_usage
from fedtrack.jsonl import check_output, output_file, output_folder
from fedtrack.progress import progress_bar
from fedtrack.services.publishing import CACHE_SAMPLES

SAMPLE_S = 5.0
MAX_RATE = 60.0  # scans per second the scenario is sized for (lockstep reaches ~20 here)


def deployment_processes(name: str) -> dict[int, str]:
    """``pid -> role/id`` of the live ``fedtrack serve`` processes of deployment ``name``."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        if "serve" in argv and name in argv:
            role = argv[argv.index("serve") + 1]
            ident = argv[argv.index("--id") + 1] if "--id" in argv else role
            out[int(entry.name)] = f"{role}/{ident}"
    return out


def rss_mb(pid: int) -> float | None:
    usage = process_usage(pid)
    return None if usage is None else usage.rss_mb


def median(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


def run_soak(minutes: float, sensors: int, out: Path) -> dict[str, Any]:
    from fedtrack.deploy.demo import demo_settings, free_port, write_config

    name = f"soak{os.getpid()}"
    settings = demo_settings(sensors, 1, "federated", 1, free_port(), out)
    duration = minutes * 60.0 * MAX_RATE
    settings = replace(settings, deployment=replace(settings.deployment, name=name, duration_s=duration))
    config = out / "config.toml"
    write_config(settings, config)
    log = (out / "launch.log").open("w")
    launch = subprocess.Popen([sys.executable, "-m", "fedtrack.cli", "launch", str(config), "--out", str(out)],
                              stdout=log, stderr=subprocess.STDOUT)
    samples: dict[str, list[tuple[float, float]]] = {}
    launched = time.monotonic()
    # the soak's minutes are the running deployment's: the launcher starts the sensors once every other service is
    # ready, so the clock starts when one is up (a soak of 6 s at a load of 16 was over before it, 0 scans fused)
    while launch.poll() is None and not any(w.startswith("sensor/") for w in deployment_processes(name).values()):
        time.sleep(0.2)
    t0 = time.monotonic()
    # the soak's seconds (a bar on a terminal: the launch's own lines go to launch.log; tour59 found 10 minutes
    # of nothing on the screen)
    bar = progress_bar(round(minutes * 60.0), "soak", unit="s")
    try:
        while time.monotonic() - t0 < minutes * 60.0 and launch.poll() is None:
            now = time.monotonic() - t0
            bar.update(round(now) - bar.n)
            for pid, who in deployment_processes(name).items():
                rss = rss_mb(pid)
                if rss is not None:
                    samples.setdefault(who, []).append((now, rss))
            time.sleep(min(SAMPLE_S, max(0.0, minutes * 60.0 - (time.monotonic() - t0))))
    finally:
        bar.close()
        if launch.poll() is None:
            launch.send_signal(signal.SIGINT)
        code = launch.wait(120)
        log.close()
    summary = json.loads((out / "summary.json").read_text())
    fusion = next((h for k, h in summary["health"].items() if k.startswith("fusion-center")), {})
    lost = summary["degraded_scans"] + fusion.get("skipped_scans", 0)
    # every publisher keeps its last CACHE_SAMPLES messages per key here (zenoh.ext history; cache_depth): that
    # bounded cache fills in CACHE_SAMPLES / rate seconds, so growth is also measured from then
    full_s = CACHE_SAMPLES / max(summary["scans"] / summary["wall_time_s"], 1e-9)
    processes = {}
    for who, series in sorted(samples.items()):
        first = [r for t, r in series if t <= 60.0]
        filled = [r for t, r in series if full_s <= t <= full_s + 60.0]
        last = [r for t, r in series if t >= series[-1][0] - 60.0]
        start, end = median(first), median(last)
        after = median(filled) if filled and full_s + 60.0 < series[-1][0] - 60.0 else None
        processes[who] = {"rss_first_minute_mb": start, "rss_last_minute_mb": end,
                          "growth_pct": 100.0 * (end - start) / start,
                          "rss_caches_full_mb": after,
                          "growth_after_caches_full_pct": None if after is None else 100.0 * (end - after) / after,
                          "series_mb": [[round(t, 1), round(r, 2)] for t, r in series]}
    return {"minutes": minutes, "sensors": sensors, "launch_exit_code": code, "wall_s": summary["wall_time_s"],
            "start_up_s": t0 - launched,
            "scans_fused": summary["scans"], "scans_per_s": summary["scans"] / summary["wall_time_s"],
            "degraded_scans": summary["degraded_scans"], "skipped_scans": fusion.get("skipped_scans", 0),
            "scans_lost": lost, "latency_ms": summary.get("latency_ms"), "processes": processes,
            "caches_full_after_s": full_s,
            "max_rss_growth_pct": max((p["growth_pct"] for p in processes.values()), default=None),
            "max_rss_growth_after_caches_full_pct": max((p["growth_after_caches_full_pct"] for p in processes.values()
                                                         if p["growth_after_caches_full_pct"] is not None), default=None)}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack bench soak", description=(
        "fedtrack bench soak: a federated deployment at the lockstep rate for --minutes, stopped as Ctrl-C stops it; "
        "scans fused and lost, and every process's resident memory in the first and last minute (issue 13)."))
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak (default 10)")
    parser.add_argument("--sensors", type=int, default=4, help="position sensors (default 4)")
    parser.add_argument("--json", type=Path, default=Path("soak.json"), help="output JSON (default soak.json)")
    parser.add_argument("--out", type=Path, help="keep the deployment's files here (default: a temporary folder)")
    args = parser.parse_args(argv)
    if not 0 < args.minutes < math.inf:
        parser.error(f"--minutes: must be finite and > 0, got {args.minutes:g}")
    if not 1 <= args.sensors <= 32:
        parser.error(f"--sensors: must be between 1 and 32, got {args.sensors}")
    check_output(args.json)
    if args.out is not None:
        output_folder(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        print(f"fedtrack bench soak: {args.sensors} sensors, {args.minutes:g} min at the lockstep rate", file=sys.stderr)
        result = run_soak(args.minutes, args.sensors, out)
    with output_file(args.json) as fh:
        fh.write(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "processes"}, indent=1))
    for who, p in result["processes"].items():
        after = p["growth_after_caches_full_pct"]
        print(f"  {who:24} RSS {p['rss_first_minute_mb']:7.1f} -> {p['rss_last_minute_mb']:7.1f} MB "
              f"({p['growth_pct']:+.1f} %; {'n/a' if after is None else f'{after:+.1f} %'} once the caches are full)")
    print(f"wrote {args.json}")
    return 0
