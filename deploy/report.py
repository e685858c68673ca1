"""What ``demo`` and ``launch`` write and print after a run: truth, summary and plot.

In the output directory: ``truth.jsonl`` (the simulated target of the deployment's paper 004
scenario and seed, when this host ran fedtrack's simulated sensors), ``summary.json`` (scans,
fused RMS position error against truth, maneuver events, latency, rejected messages, every
service's final Health counters, exit codes) and ``tracks.png`` (truth, measurements, fused
track and its error), next to the recorder's ``measurements.jsonl`` and ``tracks.jsonl``.
"""

from __future__ import annotations

import bisect
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.deploy.settings import Settings
from fedtrack.jsonl import output_file, write_jsonl
from fedtrack.sensors.scenarios import deployment_scenario, deployment_truth, paper004_scenario

REPLAY_ALGORITHM = {"federated": "fvdie", "decentralized": "dvdie"}
# summary.json's lists of what the live run produced that this host's recording lacks: any ends the run with exit 1
NOT_RECORDED = ("tracks_not_recorded", "scans_not_recorded", "pictures_not_recorded")
CLEAN_STOP_KILLED = "killed after a clean stop"  # the event of LaunchReport.killed_after_clean_stop


@dataclass
class LaunchReport:
    """What the launcher observed: per-scan latencies, tracks seen, final health counters."""

    scans_fused: int = 0
    pictures: int = 0  # multi-target pictures seen
    # multi-target, per picture period k (scans later than k period + picture_delay, up to the next): the first
    # scan (t, publish ns), the one that makes picture k due (note_scan); the first and last publish seen
    scan_slots: dict[int, tuple[float, int]] = field(default_factory=dict)
    scan_span_ns: tuple[int, int] | None = None
    picture_arrivals: list[tuple[float, int]] = field(default_factory=list)  # (picture T, arrival ns)
    picture_seqs: set[int] = field(default_factory=set)  # the numbers of the pictures seen (whole, no closing record)
    latencies_ms: list[float] = field(default_factory=list)
    measurements: dict[str, int] = field(default_factory=dict)
    track_arrivals_ns: dict[int, int] = field(default_factory=dict)  # seq -> wall-clock arrival
    # seq -> sensor -> its publish stamp (the first; only up to max_seq_jump beyond the newest fused track's seq)
    publish_stamps_ns: dict[int, dict[str, int]] = field(default_factory=dict)
    health: dict[str, dict[str, int]] = field(default_factory=dict)
    exit_codes: dict[str, int] = field(default_factory=dict)
    failed: list[str] = field(default_factory=list)
    restarts: dict[str, int] = field(default_factory=dict)  # service -> times the launcher restarted it
    processes: dict[str, dict[str, float]] = field(default_factory=dict)  # service -> peak RSS (MB), CPU (s)
    # (started | killed | stopped starting | killed after a clean stop, service, wall time)
    events: list[tuple[str, str, float]] = field(default_factory=list)
    # service -> the status of the last Health its running process sent (``stopped``: its final one, a clean stop)
    statuses: dict[str, str] = field(default_factory=dict)
    # failovers of a centre (``[multitarget] standby``): per primary lost, what the launcher saw (failovers.Failover)
    failovers: list[dict[str, Any]] = field(default_factory=list)
    # the launcher's link to its router lost and back (failovers.RouterOutage): no failover of the centres
    router_outages: list[dict[str, Any]] = field(default_factory=list)
    primary_tokens_ignored: int = 0  # primary tokens beyond CENTRE_TOKENS_KEPT of a scope, not followed
    wall_s: float = 0.0
    stopped: bool = False  # Ctrl-C or SIGTERM before the scenario's end: the sensors published only part of it
    monitor_rejected: int = 0  # messages the launcher's own session rejected (Launcher._monitored)

    @property
    def killed(self) -> set[str]:
        """Services the schedule killed (``[multitarget] kill_at``), the stop's SIGTERM met while a
        restart of theirs was not up yet, or a signal ended after their final Health said ``stopped``
        (:attr:`killed_after_clean_stop`): their signal is not a failure."""
        return {name for what, name, _ in self.events if what in ("killed", "stopped starting", CLEAN_STOP_KILLED)}

    @property
    def killed_after_clean_stop(self) -> list[str]:
        """Services ended by a signal (the stop grace's SIGKILL) in their interpreter's exit, after their
        final Health said ``stopped``: summary.json's ``killed_after_clean_stop``."""
        return sorted({name for what, name, _ in self.events if what == CLEAN_STOP_KILLED})

    def failed_exits(self) -> dict[str, int]:
        """The services whose last process ended with a non-zero code or a signal that is a failure (not
        in :attr:`killed`), with that code: what makes ``launch`` exit 1 (with ``failed``)."""
        killed = self.killed
        return {name: code for name, code in self.exit_codes.items() if code not in (0, None) and name not in killed}

    def latency_percentiles(self) -> tuple[float, float]:
        if not self.latencies_ms:
            return float("nan"), float("nan")
        p50, p99 = np.percentile(self.latencies_ms, [50, 99])
        return float(p50), float(p99)

    def note_scan(self, t: float, stamp_ns: int, period: float, delay: float, horizon: float) -> None:
        """A multi-target scan at ``t`` published at ``stamp_ns``: kept for the picture latency only if it
        is the first of its picture period (the pictures are at k ``period``; a scan later than
        k period + ``delay``, up to the next, makes picture k due) and within the scenario's 0 to
        ``horizon`` seconds (a period either side). Before 2026-11-27 every scan's stamp was kept, so a
        sensor flooding its own key grew the launcher by a stamp a scan; now by one a picture period of
        the scenario at most."""
        span = self.scan_span_ns
        self.scan_span_ns = (stamp_ns, stamp_ns) if span is None else (min(span[0], stamp_ns), max(span[1], stamp_ns))
        if not -period <= t <= horizon + period:
            return
        k = math.ceil((t - delay) / period) - 1
        if k not in self.scan_slots or (t, stamp_ns) < self.scan_slots[k]:
            self.scan_slots[k] = (t, stamp_ns)

    def picture_latencies_ms(self, period: float, delay: float) -> list[float]:
        """Per picture at ``T`` (k ``period``): its arrival minus the publish time of the first scan
        later than ``T + delay`` (the one that made it due), in ms (pictures published at the end, with
        no later scan, are left out)."""
        slots = sorted(self.scan_slots)
        out = []
        for T, arrival in self.picture_arrivals:
            i = bisect.bisect_left(slots, math.floor(T / period + 1e-9))
            while i < len(slots) and self.scan_slots[slots[i]][0] <= T + delay:
                i += 1
            if i < len(slots):  # the first later scan
                out.append((arrival - self.scan_slots[slots[i]][1]) / 1e6)
        return out

    def rejected(self) -> int:
        """What every service's final Health counted ``rejected``, and what the launcher's monitor rejected."""
        return sum(c.get("rejected", 0) for c in self.health.values()) + self.monitor_rejected


def unrecorded(summary: dict[str, Any]) -> bool:
    """Whether ``summary`` lists anything seen or due live that the recording lacks (:data:`NOT_RECORDED`)."""
    return any(summary.get(key) for key in NOT_RECORDED)


def _lines(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def write_truth(out: Path, settings: Settings) -> Path:
    """``truth.jsonl``: the target of the deployment's scenario and seed, one line per scan."""
    scenario = deployment_scenario(settings.deployment.scenario, settings.deployment.duration_s)
    truth = deployment_truth(scenario, settings.deployment.seed)
    path = out / "truth.jsonl"
    write_jsonl(path, [{"t": float(t), "x": float(s[0]), "vx": float(s[1]), "ax": float(s[2]),
                        "y": float(s[3]), "vy": float(s[4]), "ay": float(s[5])}
                       for t, s in zip(scenario.times, truth)])
    return path


def _position(track: dict[str, Any]) -> tuple[float, float]:
    return track["x"][0], track["x"][3 if track["model"] == "ca" else 2]


def unrecorded_tracks(tracks: list[dict[str, Any]], report: LaunchReport) -> list[int]:
    """The scans whose fused track the launcher saw live but the recording lacks (``tracks`` its export):
    at CI load 11 a lockstep run's recorder, stopped with a backlog, dropped 32 of 101 and the run
    ended with exit 0 (the recorder now drains its backlog; a track still lost is said, exit 1)."""
    return sorted(set(report.track_arrivals_ns) - {tr["seq"] for tr in tracks})


def summarize(out: Path, settings: Settings, report: LaunchReport, config_path: Path) -> dict[str, Any]:
    """The summary of a run: from the recorder's files in ``out`` (when this host recorded)
    and what the launcher saw; errors against truth only when ``truth.jsonl`` was written."""
    dep = settings.deployment
    tracks = _lines(out / "tracks.jsonl")
    truth = {p["t"]: p for p in _lines(out / "truth.jsonl")}
    pos_err = [np.hypot(x - truth[tr["t"]]["x"], y - truth[tr["t"]]["y"])
               for tr in tracks if tr["t"] in truth for x, y in [_position(tr)]]
    p50, p99 = report.latency_percentiles()
    events = [{"t": tr["t"], "event": tr["event"]} for tr in tracks if tr.get("event")]
    return {
        "scans": len(tracks) if tracks else report.scans_fused,
        "scans_expected": len(truth) or None,
        "degraded_scans": sum(bool(tr.get("degraded")) for tr in tracks),
        "tracks_not_recorded": unrecorded_tracks(tracks, report) if "recorder" in dep.services else [],
        "rms_position_error_m": float(np.sqrt(np.mean(np.square(pos_err)))) if pos_err else None,
        "maneuver_events": events,
        "maneuvers_detected_at": [e["t"] for e in events if e["event"] in ("onset", "new-ca")],
        "latency_ms": {"p50": p50, "p99": p99, "samples": len(report.latencies_ms)},
        "rejected_messages": report.rejected(),
        "monitor_rejected": report.monitor_rejected,
        "health": report.health,
        "exit_codes": report.exit_codes,
        "killed_after_clean_stop": report.killed_after_clean_stop,
        "restarts": report.restarts,
        "wall_time_s": report.wall_s,
        "mode": dep.mode,
        "sensors": [s.id for s in settings.sensor],
        "replay_command": (f"fedtrack replay --algorithm {REPLAY_ALGORITHM[dep.mode]} "
                           f"--config {config_path} --measurements {out / 'measurements.jsonl'} "
                           f"--out {out / 'replay.jsonl'}"),
    }


def print_summary(summary: dict[str, Any], title: str) -> None:
    rms = summary["rms_position_error_m"]
    expected = f" of {summary['scans_expected']}" if summary["scans_expected"] else ""
    rows = [
        ("mode", summary["mode"]),
        ("sensors", ", ".join(summary["sensors"])),
        ("scans fused", f"{summary['scans']}{expected} ({summary['degraded_scans']} degraded"
                        + (f", {len(summary['tracks_not_recorded'])} seen live but not recorded"
                           if summary["tracks_not_recorded"] else "") + ")"),
        ("fused RMS position error", f"{rms:.2f} m" if rms is not None else "n/a (no truth or no tracks here)"),
        ("maneuver events", ", ".join(f"{e['event']}@{e['t']:g}s" for e in summary["maneuver_events"]) or "none"),
        ("latency publish->track", f"p50 {summary['latency_ms']['p50']:.2f} ms, p99 {summary['latency_ms']['p99']:.2f} ms"),
        ("rejected messages", str(summary["rejected_messages"])),
        ("wall time", f"{summary['wall_time_s']:.1f} s"),
    ]
    width = max(len(k) for k, _ in rows)
    print(f"\n{title} summary")
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")


def plot(out: Path, settings: Settings, title: str) -> Path | None:
    """``tracks.png``; None when this host has no truth, measurements or tracks to draw."""
    if not all((out / f).is_file() and (out / f).stat().st_size for f in ("truth.jsonl", "measurements.jsonl", "tracks.jsonl")):
        return None
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
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8, frameon=False)
    ax.set_title("truth, measurements and fused track")

    truth_at = {p["t"]: (p["x"], p["y"]) for p in truth}
    t_tr = np.array([t["t"] for t in tracks])
    err = np.array([np.hypot(p[0] * 1e3 - truth_at[t][0], p[1] * 1e3 - truth_at[t][1]) for t, p in zip(t_tr, xy)])
    for sid in sorted({m["sensor"] for m in meas}):
        mm = [m for m in meas if m["sensor"] == sid]
        e = [np.hypot(m["z"][0] - truth_at[m["t"]][0], m["z"][1] - truth_at[m["t"]][1]) for m in mm]
        ax_err.plot([m["t"] for m in mm], e, ".", ms=3, alpha=0.4, label=f"sensor {sid} measurement error")
    ax_err.plot(t_tr, err, "r-", lw=1.5, label="fused position error")
    for k, seg in enumerate(paper004_scenario(settings.deployment.scenario).segments):
        ax_err.axvspan(seg.t_start, seg.t_end, color="0.85", zorder=0, label="" if k else "true maneuver")
    for k, t in enumerate([t for t in tracks if t.get("event") in ("onset", "new-ca")]):
        ax_err.axvline(t["t"], color="r", ls=":", lw=0.8, label="" if k else "maneuver detected")
    ax_err.set_xlabel("time [s]")
    ax_err.set_ylabel("position error [m]")
    ax_err.grid(True, alpha=0.3)
    ax_err.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8, frameon=False)
    ax_err.set_title("position error against truth")
    dep = settings.deployment
    fig.suptitle(f"{title}: {REPLAY_ALGORITHM[dep.mode].upper()} ({dep.mode}), scenario {dep.scenario}, "
                 f"{len(settings.sensor)} sensors: tracks.jsonl")
    path = out / "tracks.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def finish(out: Path, settings: Settings, report: LaunchReport, config_path: Path, title: str) -> dict[str, Any]:
    """Write truth (when this host simulated the sensors), summary and plot; print the summary."""
    files = [f for f in ("measurements.jsonl", "tracks.jsonl", "config.toml") if (out / f).is_file()]
    if "sensor" in settings.deployment.services:
        files.append(write_truth(out, settings).name)
    summary = summarize(out, settings, report, config_path)
    with output_file(out / "summary.json") as fh:
        fh.write(json.dumps(summary, indent=2))
    files.append("summary.json")
    png = plot(out, settings, title)
    if png is not None:
        files.append(png.name)
    print_summary(summary, title)
    print(f"\nwrote {out}/: {' '.join(files)}")
    if "tracks.jsonl" in files:
        print(f"reproduce the tracks with: {summary['replay_command']}")
    lost = summary["tracks_not_recorded"]
    if lost:
        print(f"{title}: {len(lost)} fused tracks seen live are not in the recording (scans "
              f"{', '.join(map(str, lost[:10]))}{', ...' if len(lost) > 10 else ''}; "
              f"see {out}/logs/recorder-recorder.log)",
              file=sys.stderr)
    return summary
