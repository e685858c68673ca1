"""fedtrack demo: the whole deployment on this machine, then a summary.

Router, N sensors, their local filters, the fusion center and the recorder run as
separate processes over Zenoh on loopback (paper 004 scenario, lockstep pacing). The
output directory receives ``measurements.jsonl``, ``tracks.jsonl``, ``truth.jsonl``,
``summary.json``, ``config.toml`` (the effective configuration: ``fedtrack replay
--algorithm fvdie --config DIR/config.toml --measurements DIR/measurements.jsonl``
reproduces ``tracks.jsonl``), ``tracks.png`` and the services' logs under ``logs/``.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import to_toml
from fedtrack.deploy.launcher import (
    LaunchError,
    LaunchReport,
    ServiceFailed,
    run_deployment,
)
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import MODES, DeploymentConfig, SensorConfig
from fedtrack.jsonl import write_jsonl
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.scenarios import DEFAULT_R, deployment_truth, paper004_scenario

REPLAY_ALGORITHM = {"federated": "fvdie", "decentralized": "dvdie"}


def free_port() -> int:
    """A free TCP port on loopback (bind to port 0 and read it back)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def demo_settings(n_sensors: int, scenario: int, mode: str, seed: int, port: int, out: Path) -> Settings:
    ids = tuple(str(i + 1) for i in range(n_sensors))
    r = tuple(tuple(row) for row in DEFAULT_R.tolist())
    return Settings(
        fusion=FusionConfig(sensors=ids),
        deployment=DeploymentConfig(name="demo", mode=mode, scenario=scenario, seed=seed, pacing="lockstep",
                                    router_listen=f"tcp/127.0.0.1:{port}", out=str(out)),
        sensor=tuple(SensorConfig(id=i, R=r) for i in ids),  # type: ignore[arg-type]
    )


def settings_table(settings: Settings) -> dict[str, Any]:
    """The effective configuration as a TOML-ready dict (None values left out)."""
    def clean(obj: Any) -> Any:
        if isinstance(obj, dict):
            return {k: clean(v) for k, v in obj.items() if v is not None}
        if isinstance(obj, (list, tuple)):
            return [clean(v) for v in obj]
        return obj
    return clean(asdict(settings))


def write_config(settings: Settings, path: Path) -> None:
    path.write_text(to_toml(settings_table(settings)))


def summarize(out: Path, settings: Settings, report: LaunchReport) -> dict[str, Any]:
    scenario = paper004_scenario(settings.deployment.scenario)
    truth = deployment_truth(scenario, settings.deployment.seed)
    tracks = [json.loads(line) for line in (out / "tracks.jsonl").read_text().splitlines()]
    pos_err = []
    for tr in tracks:
        k = int(round(tr["t"] / scenario.T))
        pos = [tr["x"][0], tr["x"][3 if tr["model"] == "ca" else 2]]
        pos_err.append(np.hypot(pos[0] - truth[k, 0], pos[1] - truth[k, 3]))
    p50, p99 = report.latency_percentiles()
    events = [{"t": tr["t"], "event": tr["event"]} for tr in tracks if tr.get("event")]
    return {
        "scans": len(tracks),
        "scans_expected": len(scenario.times),
        "degraded_scans": sum(bool(tr.get("degraded")) for tr in tracks),
        "rms_position_error_m": float(np.sqrt(np.mean(np.square(pos_err)))) if pos_err else float("nan"),
        "maneuver_events": events,
        "maneuvers_detected_at": [e["t"] for e in events if e["event"] in ("onset", "new-ca")],
        "latency_ms": {"p50": p50, "p99": p99, "samples": len(report.latencies_ms)},
        "rejected_messages": report.rejected(),
        "health": report.health,
        "exit_codes": report.exit_codes,
        "wall_time_s": report.wall_s,
        "mode": settings.deployment.mode,
        "sensors": [s.id for s in settings.sensor],
        "replay_command": (f"fedtrack replay --algorithm {REPLAY_ALGORITHM[settings.deployment.mode]} "
                           f"--config {out / 'config.toml'} --measurements {out / 'measurements.jsonl'} "
                           f"--out {out / 'replay.jsonl'}"),
    }


def print_summary(summary: dict[str, Any]) -> None:
    rows = [
        ("mode", summary["mode"]),
        ("sensors", ", ".join(summary["sensors"])),
        ("scans fused", f"{summary['scans']} of {summary['scans_expected']} ({summary['degraded_scans']} degraded)"),
        ("fused RMS position error", f"{summary['rms_position_error_m']:.2f} m"),
        ("maneuver events", ", ".join(f"{e['event']}@{e['t']:g}s" for e in summary["maneuver_events"]) or "none"),
        ("latency publish->track", f"p50 {summary['latency_ms']['p50']:.2f} ms, p99 {summary['latency_ms']['p99']:.2f} ms"),
        ("rejected messages", str(summary["rejected_messages"])),
        ("wall time", f"{summary['wall_time_s']:.1f} s"),
    ]
    width = max(len(k) for k, _ in rows)
    print("\nfedtrack demo summary")
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")


def plot(out: Path, settings: Settings) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth = [json.loads(x) for x in (out / "truth.jsonl").read_text().splitlines()]
    meas = [json.loads(x) for x in (out / "measurements.jsonl").read_text().splitlines()]
    tracks = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
    fig, (ax, ax_err) = plt.subplots(1, 2, figsize=(14, 6), gridspec_kw={"width_ratios": [1.1, 1]})
    ax.plot([p["x"] / 1e3 for p in truth], [p["y"] / 1e3 for p in truth], "k-", lw=2, label="truth")
    for sid in sorted({m["sensor"] for m in meas}):
        pts = np.array([m["z"] for m in meas if m["sensor"] == sid]) / 1e3
        ax.plot(pts[:, 0], pts[:, 1], ".", ms=3, alpha=0.5, label=f"sensor {sid} measurements")
    xy = np.array([[t["x"][0], t["x"][3 if t["model"] == "ca" else 2]] for t in tracks]) / 1e3
    ax.plot(xy[:, 0], xy[:, 1], "r-", lw=1, label="fused track")
    ca = np.array([t["model"] == "ca" for t in tracks])
    ax.plot(xy[ca, 0], xy[ca, 1], "r^", ms=4, label="fused, CA model (maneuver)")
    for t, p in zip(tracks, xy):
        if t.get("event") == "onset":
            ax.annotate(f"onset {t['t']:g}s", p, textcoords="offset points", xytext=(8, 0), fontsize=8)
    ax.set_xlabel("x [km]")
    ax.set_ylabel("y [km]")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("truth, measurements and fused track")

    truth_at = {p["t"]: (p["x"], p["y"]) for p in truth}
    t_tr = np.array([t["t"] for t in tracks])
    err = np.array([np.hypot(p[0] * 1e3 - truth_at[t][0], p[1] * 1e3 - truth_at[t][1]) for t, p in zip(t_tr, xy)])
    for sid in sorted({m["sensor"] for m in meas}):
        mm = [m for m in meas if m["sensor"] == sid]
        e = [np.hypot(m["z"][0] - truth_at[m["t"]][0], m["z"][1] - truth_at[m["t"]][1]) for m in mm]
        ax_err.plot([m["t"] for m in mm], e, ".", ms=3, alpha=0.4, label=f"sensor {sid} measurement error")
    ax_err.plot(t_tr, err, "r-", lw=1.5, label="fused position error")
    for seg in paper004_scenario(settings.deployment.scenario).segments:
        ax_err.axvspan(seg.t_start, seg.t_end, color="0.85", zorder=0)
    for t in tracks:
        if t.get("event") in ("onset", "new-ca"):
            ax_err.axvline(t["t"], color="r", ls=":", lw=0.8)
    ax_err.set_xlabel("time [s] (grey: true maneuvers; dotted: detections)")
    ax_err.set_ylabel("position error [m]")
    ax_err.grid(True, alpha=0.3)
    ax_err.legend(loc="upper right", fontsize=8)
    ax_err.set_title("position error against truth")
    fig.suptitle(f"fedtrack demo: scenario {settings.deployment.scenario}, {settings.deployment.mode}, "
                 f"{len(settings.sensor)} sensors")
    path = out / "tracks.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("fedtrack-out"), help="output directory")
    parser.add_argument("--sensors", type=int, default=2, help="number of sensors (default 2)")
    parser.add_argument("--scenario", type=int, choices=(1, 2), default=1)
    parser.add_argument("--mode", choices=MODES, default="federated")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--port", type=int, help="router port on 127.0.0.1 (default: a free one)")
    args = parser.parse_args(argv)
    if not 1 <= args.sensors <= 32:
        parser.error("--sensors must be between 1 and 32")
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    settings = demo_settings(args.sensors, args.scenario, args.mode, args.seed, args.port or free_port(), out)
    write_config(settings, out / "config.toml")
    scenario = paper004_scenario(args.scenario)
    truth = deployment_truth(scenario, args.seed)
    write_jsonl(out / "truth.jsonl", [{"t": float(t), "x": float(s[0]), "vx": float(s[1]), "ax": float(s[2]),
                                       "y": float(s[3]), "vy": float(s[4]), "ay": float(s[5])}
                                      for t, s in zip(scenario.times, truth)])
    print(f"fedtrack demo: {args.sensors} sensors, scenario {args.scenario}, {args.mode}; output in {out}",
          file=sys.stderr)
    failure = None
    try:
        report = run_deployment(settings, out / "config.toml", out)
    except KeyboardInterrupt:
        print("fedtrack demo: stopped; every service was shut down", file=sys.stderr)
        return 130
    except ServiceFailed as exc:  # the scenario ran to its end without some service
        report, failure = exc.report, str(exc)
    except LaunchError as exc:
        print(f"fedtrack demo: {exc}", file=sys.stderr)
        return 1
    summary = summarize(out, settings, report)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    png = plot(out, settings)
    print_summary(summary)
    print(f"\nwrote {out}/: measurements.jsonl tracks.jsonl truth.jsonl summary.json config.toml {png.name}")
    print(f"reproduce the tracks with: {summary['replay_command']}")
    if failure is not None:
        print(f"fedtrack demo: {failure}", file=sys.stderr)
        return 1
    return 0
