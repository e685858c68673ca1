"""A live multi-target deployment: ``fedtrack launch deploy/multitarget.toml`` and ``fedtrack demo
--scenario multitarget``.

Before any process starts, the ``[multitarget]`` scenario is simulated into ``OUT/scenario/``
(:func:`fedtrack.sensors.multitarget.simulate`: truth and every sensor's scans). Then, as
separate processes: the router, the recorder, the centre (``serve mtt-centre``; with ``[regions]``
one ``serve mtt-centre --region RID`` per region and ``serve picture``), one local
tracker per sensor (``serve mtt-local``; none for ``mtt-centralized``) and one sensor per
sensor id publishing its own scans at their own times (``serve sensor --kind scan``, realtime
pacing, ``[deployment] speed`` times real time). After the run: ``measurements.jsonl`` (the
scans in the centre's processing order) and ``tracks.jsonl`` (one picture a line) from the
recorder, ``truth.jsonl``, ``summary.json`` (GOSPA and the rest of ``fedtrack evaluate``,
latency, counters, exit codes, every process's peak RSS and CPU seconds), ``tracks.png`` and
``config.toml`` (a copy of the launch config: ``replay --config OUT/config.toml`` of the
recording, ``--regions config`` with ``[regions]``).
"""

from __future__ import annotations

import collections
import datetime
import json
import re
import shutil
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, TypeVar

import numpy as np

from fedtrack.atomic import write_atomic
from fedtrack.config import ConfigError, did_you_mean, in_file, load_toml, parse_dataclass, to_toml
from fedtrack.deploy.membership import membership
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import MultitargetSettings, Settings
from fedtrack.fusion_center.mtt.earthmap import plot_map
from fedtrack.fusion_center.mtt.evaluation import evaluate, plot
from fedtrack.fusion_center.mtt.replay import read_scans, state_dim
from fedtrack.geodetic import Frame, FrameConfig, load_frame
from fedtrack.geojson import feature_collection
from fedtrack.jsonl import InputError, output_file, read_jsonl
from fedtrack.keys import AREA_CENTRE_ID, MERGER_ID
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.recording import Recording
from fedtrack.sensors.multitarget import Scenario, SensorSpec, check_room, parse_spec, simulate
from fedtrack.sensors.state_vectors import Recording as StateVectors
from fedtrack.sensors.state_vectors import read_recording
from fedtrack.sensors.traffic import Knobs, read_line, window_origin
from fedtrack.sensors.traffic import simulate as simulate_traffic
from fedtrack.sensors.traffic_sensors import parse_kinds

SCENARIO_DIR = "scenario"
T = TypeVar("T")


def sensor_specs(mt: MultitargetSettings) -> list[SensorSpec]:
    """The scenario's sensors (a recorded-traffic scenario's may have sites and ADS-B receivers)."""
    return parse_kinds(mt.sensors) if mt.source else parse_spec(mt.sensors)


UNPROCESSED = "unprocessed.jsonl"  # the export's: the recorded scans no picture lists (fedtrack.recording)


def sensor_ids(mt: MultitargetSettings) -> list[str]:
    return [s.id for s in sensor_specs(mt)]


def check_multitarget(settings: Settings, path: Path) -> Settings:
    """What a multi-target launch needs, checked before any process starts; returns ``settings``
    with realtime pacing when the file does not set ``deployment.pacing`` (the only pacing of a
    multi-target deployment: every sensor keeps its own period and phase)."""
    mt = settings.multitarget
    assert mt is not None
    with in_file(path):
        if settings.deployment.pacing != "realtime":
            if "pacing" in load_toml(path).get("deployment", {}):
                raise ConfigError("deployment.pacing: a multi-target deployment paces its sensors in real time "
                                  "(set pacing = \"realtime\", or leave it out)")
            settings = replace(settings, deployment=replace(settings.deployment, pacing="realtime"))
        try:
            ids = sensor_ids(mt)
        except InputError as exc:
            raise ConfigError(f"multitarget.sensors: {exc}") from None
        unknown = [s for s in ids if not settings.mtt.allows(s)]
        if unknown:
            raise ConfigError(f"mtt.sensors: does not allow the scenario's sensor {unknown[0]!r}")
        for key in ("join_at", "kill_at"):
            stray = [s for s in getattr(mt, key) if s not in ids]
            if stray:
                raise ConfigError(f"multitarget.{key}.{stray[0]}: not a sensor of the scenario ({', '.join(ids)})")
        check_scenario_sensors(settings, sensor_specs(mt))
        check_central_timeout(settings.mtt.central_timeout, sensor_specs(mt), mt.duration)
        if not mt.source:
            try:
                check_room(scenario(mt), sensor_specs(mt), "set a shorter duration, fewer targets, less clutter or "
                           "slower sensors")
            except InputError as exc:
                raise ConfigError(f"multitarget: {exc}") from None
        if mt.join_at and set(mt.join_at) >= set(ids):
            raise ConfigError("multitarget.join_at: at least one sensor must run from the start")
        if load_regions(path) is not None and mt.algorithm == "mtt-centralized":
            raise ConfigError("regions: region centres run mtt-federated or mtt-decentralized, not mtt-centralized")
    return settings


# the coordinates a sensor kind measures: a [mtt.sensor.<id>] noise_floor has one standard deviation each
FLOOR_SIZES = {"pos": 2, "radar": 3}


def check_scenario_sensors(settings: Settings, specs: list[SensorSpec]) -> None:
    """``[deployment] local_sensors`` and the ``[mtt.sensor.<id>]`` tables name the scenario's sensors, and a
    ``noise_floor`` has a value per coordinate its sensor measures (another size: every report refused by the
    centre, ``centre_floor_mismatch``)."""
    ids = [s.id for s in specs]
    for key, named in (("deployment.local_sensors", settings.deployment.local_sensors or ()),
                       ("mtt.sensor", tuple(settings.mtt.sensor))):
        stray = [sid for sid in named if sid not in ids]
        if stray:
            where = f"mtt.sensor.{stray[0]}" if key == "mtt.sensor" else key
            raise ConfigError(f"{where}: {stray[0]!r} is not a sensor of the scenario ({', '.join(ids)})"
                              + did_you_mean(stray[0], ids))
    for spec in specs:
        floor, size = settings.mtt.noise_floor_of(spec.id), FLOOR_SIZES.get(spec.kind)
        if floor is not None and size is not None and len(floor) != size:
            raise ConfigError(f"mtt.sensor.{spec.id}.noise_floor: {len(floor)} values for a {spec.kind} sensor, "
                              f"which measures {size} coordinates (2: m, m; 3: m, rad, rad)")


def check_central_timeout(timeout: float, specs: list[SensorSpec], duration: float) -> None:
    """``[mtt] central_timeout`` at least the period of every sensor that scans again within ``duration``
    (:func:`~fedtrack.sensors.multitarget.revisits`): a shorter one deletes every central track only that
    sensor supports between two of its scans, and counts the sensor silent between them (docs/deploy.md)."""
    slow = max((s for s in specs if s.period <= duration), key=lambda s: s.period, default=None)
    if slow is not None and timeout < slow.period:
        raise ConfigError(f"mtt.central_timeout: {timeout:g} s is shorter than sensor {slow.id}'s period "
                          f"{slow.period:g} s: a central track only {slow.id} supports would be deleted between its "
                          f"scans; set it to {slow.period:g} s or more")


# what a launch's recording without aircraft in the window advises: the [multitarget] keys, not simulate traffic's
# options
KEYS = Knobs("multitarget.origin", "multitarget.box", "multitarget.start / multitarget.duration", None)


def scenario(mt: MultitargetSettings) -> Scenario:
    """The simulated scenario of ``[multitarget]`` (no scan delivered late: the live links' own delays)."""
    return Scenario(targets=mt.targets, duration=mt.duration, region=mt.half_width, pd=mt.pd, clutter=mt.clutter,
                    late=0.0)


def prepare(settings: Settings, out: Path, say: bool = True) -> Path:
    """Simulate the scenario into ``out/scenario``; returns its measurements file. ``say``: print what a
    recording's simulation read and left out (stderr)."""
    mt = settings.multitarget
    assert mt is not None
    folder = out / SCENARIO_DIR
    if mt.source:
        rec = read_recording(Path(mt.source), mt.units)
        frame = scenario_frame(settings, rec)
        if say and mt.origin is None and settings.frame is None:
            print(f"scenario: origin {frame.lat:.6f},{frame.lon:.6f}: the median position of the window's airborne "
                  "samples (no [multitarget] or [frame] origin)",
                  file=sys.stderr)
        info = simulate_traffic(rec, frame, mt.sensors, settings.deployment.seed, folder, mt.start, mt.duration,
                                mt.box * 1e3, pd=mt.pd, clutter=mt.clutter, late=0.0, knobs=KEYS)
        if say:
            print(f"scenario: {read_line(Path(mt.source), info)}", file=sys.stderr)
        return folder / "measurements.jsonl"
    simulate(scenario(mt), parse_spec(mt.sensors), settings.deployment.seed, folder)
    return folder / "measurements.jsonl"


def derived_config(settings: Settings, config_path: Path, out: Path) -> tuple[Settings, Path, list[str]]:
    """A recorded-traffic launch's tracker keys: those ``simulate traffic`` wrote for the scenario in
    ``out/scenario/config.toml`` (``[mtt]``: :func:`~fedtrack.sensors.traffic.derived_tracker`, ``pd``, the clutter
    densities, the sensors and their ``noise_floor``; ``[frame]``: the origin it was simulated about and the radars'
    sites) for every key ``config_path`` does not set (its own win, key by key in ``[mtt.sensor.<id>]`` and
    ``[frame.sites]``), as ``replay --config`` of that scenario. Written with the file's other tables to
    ``out/config.toml``, the services' ``--config`` (and ``replay --config OUT/config.toml``'s); returns the
    settings, that file and the keys derived (``mtt.q``, ``frame.sites.r1``, ...). Before the launchtraffic62 session
    the services ran the file's own ``[mtt]`` (the defaults when absent) and ``[frame]`` (no radar sites)."""
    scene = load_toml(out / SCENARIO_DIR / "config.toml")
    own = load_toml(config_path)
    mine = {**own, "mtt": own.get("mtt", {}), "frame": own.get("frame", {})}  # a table left out: its keys named
    merged, derived = overlay(mine, {"mtt": scene["mtt"], "frame": scene["frame"]})
    path = out / "config.toml"
    write_atomic(path, to_toml(merged).encode())
    with in_file(config_path):
        updated = replace(settings, mtt=parse_dataclass(MttConfig, merged["mtt"], "mtt"),
                          frame=parse_dataclass(FrameConfig, merged["frame"], "frame"))
    return updated, path, derived


def overlay(mine: dict[str, Any], theirs: dict[str, Any], where: str = "") -> tuple[dict[str, Any], list[str]]:
    """``theirs`` with ``mine``'s keys over it, table by table; and the dotted names of those taken from ``theirs``
    (a table ``mine`` lacks as one name)."""
    merged, taken = {**theirs, **mine}, []
    for key, value in theirs.items():
        if key not in mine:
            taken.append(where + key)
        elif isinstance(value, dict) and isinstance(mine[key], dict):
            merged[key], more = overlay(mine[key], value, f"{where}{key}.")
            taken += more
    return merged, taken


def scenario_frame(settings: Settings, rec: StateVectors) -> Frame:
    """The frame a recording's scenario is simulated in: ``[multitarget] origin``, else ``[frame] origin`` (the
    tracks' own), else the median position of the window's airborne samples, as ``simulate traffic`` without
    ``--origin`` (:func:`~fedtrack.sensors.traffic.window_origin`; before the tour61 session ``launch`` refused a
    ``source`` without ``origin``)."""
    mt = settings.multitarget
    assert mt is not None
    if mt.origin is not None:
        return Frame(*mt.origin)
    if settings.frame is not None:
        return Frame(*settings.frame.origin)
    return window_origin(rec, mt.start, mt.duration)


def service_args(settings: Settings, measurements: Path, regions: Regions | None = None
                 ) -> list[tuple[str, str, list[str]]]:
    """``(role, id, role arguments)`` of the deployment's multi-target services, in start order
    (sensors last); the caller adds ``--config`` and the Zenoh options. With ``regions`` (the
    config's ``[regions]``): one centre per region (``serve mtt-centre --region RID``, id the
    region's) and the picture merger (``serve picture``) instead of the single centre."""
    mt = settings.multitarget
    assert mt is not None
    ids = sensor_ids(mt)
    dim = "6" if any(s.kind == "radar" for s in sensor_specs(mt)) else "4"
    if regions is None:
        plan = [("mtt-centre", AREA_CENTRE_ID, ["--algorithm", mt.algorithm, "--dim", dim])]
    else:
        plan = [("mtt-centre", rid, ["--algorithm", mt.algorithm, "--dim", dim, "--region", rid]) for rid in regions.ids]
        plan.append(("picture", MERGER_ID, ["--dim", dim]))
    if mt.algorithm != "mtt-centralized":
        mode = "federated" if mt.algorithm == "mtt-federated" else "decentralized"
        plan += [("mtt-local", s, ["--sensor", s, "--mode", mode]) for s in ids]
    plan += [("sensor", s, ["--kind", "scan", "--pacing", "realtime", "--measurements", str(measurements),
                            *(["--join-at", repr(mt.join_at[s])] if s in mt.join_at else [])]) for s in ids]
    return plan


DEPARTURE_LOG = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) .* sensor (\S+) left: dropped from fusion")


def departures_logged(log: Path) -> dict[str, float]:
    """Sensor -> wall-clock time at which the centre dropped it, from the centre's log."""
    out: dict[str, float] = {}
    if log.is_file():
        for line in log.read_text(errors="replace").splitlines():
            hit = DEPARTURE_LOG.match(line)
            if hit:
                stamp = datetime.datetime.strptime(hit.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp()
                out.setdefault(hit.group(2), stamp)
    return out


def membership_summary(out: Path, report: LaunchReport, settings: Settings) -> dict[str, Any]:
    """``[multitarget] join_at`` / ``kill_at`` as they happened: per joining sensor, how many of
    its own scans its local tracks took to share a central track with another sensor; per killed
    sensor, how long the centre took to drop it and the central tracks another sensor supported
    that were lost (:mod:`fedtrack.deploy.membership`, on the recording)."""
    mt = settings.multitarget
    assert mt is not None
    killed: dict[str, float] = {}  # sensor -> wall-clock time its first process was killed
    for what, name, when in report.events:
        if what == "killed":
            sensor = name.split("/", 1)[1]
            killed[sensor] = min(killed.get(sensor, when), when)
    logs = sorted((out / "logs").glob("mtt-centre-*.log"))  # the centre's, or every region centre's (the first)
    dropped = departures_logged(logs[0]) if logs else {}
    summary: dict[str, Any] = {"joined": {}, "left": {}}
    for sensor, when in killed.items():
        summary["left"][sensor] = {"killed_at": when, "dropped_after_s": dropped[sensor] - when if sensor in dropped else None}
    measurements = out / "measurements.jsonl"
    # a region run's recording lists a scan once per region it reached (replay --regions config), which the
    # one centre's replay here cannot take: it failed on the first line (unknown field 'region') and the launch
    # ended in a traceback without summary.json; its joins and losses are not measured
    if mt.algorithm == "mtt-centralized" or not measurements.is_file() or load_regions(out / "config.toml"):
        return summary
    scans = read_scans(measurements, settings.mtt)
    frame = load_frame(out / "config.toml")  # [frame.sites]: the centre's radars, as the live centre's
    joined, left = membership(scans, settings.mtt, state_dim(scans), mt.algorithm == "mtt-federated", set(mt.join_at),
                              {} if frame is None else frame.radar_sites())
    for j in joined:
        delays = j.scans_to_associate
        summary["joined"][j.sensor] = {
            "first_t": j.first_t, "tracks_associated": len(delays),
            "scans_to_associate": {"median": float(np.median(delays)) if delays else None,
                                   "max": max(delays, default=None),
                                   "within_3": sum(d <= 3 for d in delays) / len(delays) if delays else None},
            "never_associated_confirmed": j.never_associated}
    for lv in left:
        if lv.sensor not in killed:
            continue  # a clean stop at the end of the run
        row = summary["left"][lv.sensor]
        row.update({"t": lv.t, "supported_by_others": lv.supported, "lost": lv.lost})
    return summary


def print_membership(summary: dict[str, Any], title: str) -> None:
    for sensor, j in summary["joined"].items():
        d = j["scans_to_associate"]
        if j["tracks_associated"]:
            print(f"{title}: {sensor} joined at t = {j['first_t']:.1f} s: {j['tracks_associated']} of its tracks "
                  f"associated with another sensor's, {100 * d['within_3']:.0f} % within 3 of its scans (median "
                  f"{d['median']:g}, max {d['max']}); {j['never_associated_confirmed']} confirmed tracks never did",
                  file=sys.stderr)
    for sensor, lv in summary["left"].items():
        after = lv.get("dropped_after_s")
        said = "not dropped" if after is None else f"dropped {after:.2f} s after the kill"
        lost = f"; {len(lv['lost'])} of the {lv['supported_by_others']} central tracks others supported lost" \
            if "lost" in lv else ""
        print(f"{title}: {sensor} killed: {said}{lost}", file=sys.stderr)


def unrecorded_scans(out: Path, settings: Settings, seen: dict[str, int] | None = None) -> dict[str, int]:
    """Per sensor of this host that the schedule does not kill, the scans of the scenario it was to
    publish (a joining sensor's from its ``join_at`` on) that this host's recording lacks (sensors that
    lack none left out): a router frozen past its lease until the sensors' last scan lost what they
    published meanwhile (their caches went with them), and the summary said nothing of it but the number
    of pictures (11 of 39; its GOSPA, over those 11, lower than the run's without the fault). A restarted
    sensor's skipped scans count too, and a joining sensor's published before its tracker listened.
    ``seen``: a run stopped before the scenario's end, the scans the launcher saw live per sensor, the most
    the sensors can be held to (tour59: a Ctrl-C before the start said all 191 of the scenario were lost)."""
    mt, db = settings.multitarget, out / "recording.db"
    if mt is None or "recorder" not in settings.deployment.services:
        return {}
    local = settings.deployment.local_sensors
    ids = [s for s in sensor_ids(mt) if (local is None or s in local) and s not in mt.kill_at]
    scenario = out / SCENARIO_DIR / "measurements.jsonl"
    expected = collections.Counter(obj.get("sensor") for _, obj in read_jsonl(scenario)
                                   if obj.get("t", 0.0) >= mt.join_at.get(obj.get("sensor"), 0.0))
    if seen is not None:
        expected = collections.Counter({s: min(expected[s], seen.get(s, 0)) for s in ids})
    recorded = _read_recording(db, Recording.scans, {})
    return {s: expected[s] - recorded.get(s, 0) for s in ids if expected[s] > recorded.get(s, 0)}


def untracked_scans(out: Path) -> dict[str, int]:
    """Per sensor, the recorded scans no picture lists (``OUT/unprocessed.jsonl``, the export's): a tracker
    stopped with scans still queued (its drain deadline, 2 s: ``dropped``), or that took them as late. The
    launch said nothing of them (tour58); a run on an idle machine has none."""
    path = out / UNPROCESSED
    if not path.is_file():
        return {}
    return dict(collections.Counter(str(obj.get("sensor")) for _, obj in read_jsonl(path)))


def unrecorded_pictures(out: Path, settings: Settings, report: LaunchReport) -> list[int]:
    """The numbers of the pictures the launcher saw live that this host's recording lacks: a recorder whose
    commits (an fsync each) were slowed to 400 ms kept 11 of a run's pictures after its 15 s drain and the
    launch said nothing of the others (2026-11-28; the launcher now waits for it while it catches up)."""
    if "recorder" not in settings.deployment.services:
        return []
    return sorted(report.picture_seqs - _read_recording(out / "recording.db", Recording.pictures, set()))


def _read_recording(db: Path, read: Callable[[Recording], T], gone: T) -> T:
    """``read`` of the recording ``db`` (opened read-only), ``gone`` when the database is not there."""
    if not db.is_file():
        return gone
    recording = Recording(db, readonly=True)
    try:
        return read(recording)
    finally:
        recording.close()


def finish_multitarget(out: Path, report: LaunchReport, title: str, settings: Settings) -> dict[str, Any]:
    """Truth, summary (with GOSPA and the picture latency: from the publish of the scan that
    makes a picture due, delayed by ``[mtt] picture_delay``, to its arrival at the launcher;
    with ``join_at`` / ``kill_at``, what they did) and plot of a multi-target run; prints the
    summary."""
    delay, mt = settings.mtt.picture_delay, settings.multitarget
    truth = out / "truth.jsonl"
    with output_file(truth, "wb") as fh, (out / SCENARIO_DIR / "truth.jsonl").open("rb") as src:
        shutil.copyfileobj(src, fh)  # whole or not at all, the disk full named as this file
    tracks = out / "tracks.jsonl"
    summary: dict[str, Any] = {"pictures": 0, "exit_codes": report.exit_codes,
                               "killed_after_clean_stop": report.killed_after_clean_stop, "restarts": report.restarts,
                               "rejected": report.rejected(), "monitor_rejected": report.monitor_rejected,
                               "health": report.health, "wall_s": report.wall_s, "processes": report.processes}
    names = ["measurements.jsonl", "tracks.jsonl", "truth.jsonl", "summary.json", "tracks.png", "config.toml"]
    if tracks.is_file() and tracks.stat().st_size:
        result = evaluate(tracks, truth, horizontal=settings.frame is not None)
        png = out / "tracks.png"
        events = {} if mt is None else {**{f"{sid} joins": t for sid, t in mt.join_at.items()},
                                        **{f"{sid} killed": t for sid, t in mt.kill_at.items()}}
        label = None if mt is None else f"live {mt.algorithm}"
        regions = load_regions(out / "config.toml") if (out / "config.toml").is_file() else None
        if settings.frame is None:
            plot(result, tracks, truth, png, events, label=label, regions=regions)
        else:  # on the Earth: the map in tracks.png, GOSPA over time beside it, and GeoJSON
            plot(result, tracks, truth, out / "gospa.png", events, label=label, regions=regions)
            plot_map(tracks, truth, settings.frame, png, label=label)
            (out / "tracks.geojson").write_text(json.dumps(feature_collection(settings.frame, tracks, truth)))
            names += ["gospa.png", "tracks.geojson"]
        summary.update({k: v for k, v in result.items() if k != "series"})
        if mt is not None and summary.get("algorithm") is None:  # the recorder's pictures do not carry it
            summary["algorithm"] = mt.algorithm
    latencies = report.picture_latencies_ms(settings.mtt.period, delay)
    if latencies:
        summary["picture_latency_ms"] = {"p50": float(np.percentile(latencies, 50)),
                                         "p99": float(np.percentile(latencies, 99)), "pictures": len(latencies)}
    if mt is not None and (mt.join_at or mt.kill_at):
        summary["membership"] = membership_summary(out, report, settings)
    if report.failovers:
        summary["failovers"] = report.failovers
    if report.router_outages:
        summary["router_outages"] = report.router_outages
    if report.primary_tokens_ignored:
        summary["primary_tokens_ignored"] = report.primary_tokens_ignored
    try:
        lost = unrecorded_scans(out, settings, report.measurements if report.stopped else None)
        pictures_lost = unrecorded_pictures(out, settings, report)
    except InputError:  # a damaged recording: the export said so in one line
        lost, pictures_lost = {}, []
    if lost:
        summary["scans_not_recorded"] = lost
    untracked = untracked_scans(out)
    if untracked:
        summary["scans_not_tracked"] = untracked
    if pictures_lost:
        summary["pictures_not_recorded"] = pictures_lost
    with output_file(out / "summary.json") as fh:
        fh.write(json.dumps(summary, indent=2))
    mean = summary.get("mean")
    if mean:
        unit = summary["c"] ** summary["p"] / summary["alpha"]  # GOSPA^p per missed or false track
        print(f"{title}: {summary['pictures']} pictures; mean GOSPA {mean['gospa']:.1f} m (c = {summary['c']:g} m, "
              f"p = {summary['p']:g}): localisation {mean['localisation'] ** (1 / summary['p']):.1f} m, "
              f"{mean['missed'] / unit:.2f} missed targets and {mean['false'] / unit:.2f} false tracks a picture; "
              f"{summary['rejected']} messages rejected", file=sys.stderr)
    man = summary.get("maneuvers")
    if man and man["onsets"]:
        rate = {k: "-" if man[f"flagged_while_{k}"] is None else f"{100 * man[f'flagged_while_{k}']:.1f} %"
                for k in ("maneuvering", "straight")}
        print(f"{title}: {man['onsets']} maneuver onsets; flagged in {rate['maneuvering']} of the pictures of a target "
              f"accelerating >= {man['maneuver_accel']:g} m/s^2, {rate['straight']} of one moving straight for "
              f"{man['straight_for_s']:g} s",
              file=sys.stderr)
    if latencies:
        lat = summary["picture_latency_ms"]
        print(f"{title}: picture latency p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms (from the publish of the "
              "scan that makes a picture due)", file=sys.stderr)
    else:
        print(f"{title}: no picture was recorded (see {out}/logs/)", file=sys.stderr)
    if "membership" in summary:
        print_membership(summary["membership"], title)
    for f in report.failovers:
        said = {k: "-" if f[k] is None else f"{f[k]:.2f}" for k in ("t", "took_over_after_s", "covered_after_s", "scans")}
        print(f"{title}: failover of {f['scope']}: primary lost at t = {said['t']} s, standby took over after "
              f"{said['took_over_after_s']} s, next picture after {said['covered_after_s']} s ({said['scans']} scans "
              "of the slowest sensor)", file=sys.stderr)
    if lost:
        published = "seen live" if report.stopped else "the sensors were to publish"
        print(f"{title}: {sum(lost.values())} scans {published} are not in the recording "
              f"({', '.join(f'{s}: {n}' for s, n in sorted(lost.items()))}): lost, or skipped by a restarted sensor",
              file=sys.stderr)
    if untracked:
        print(f"{title}: {sum(untracked.values())} recorded scans are in no picture "
              f"({', '.join(f'{s}: {n}' for s, n in sorted(untracked.items()))}; {out / UNPROCESSED}): no tracker "
              "took them (see each mtt-local's counters dropped, late and queue_dropped in summary.json)",
              file=sys.stderr)
    if pictures_lost:
        print(f"{title}: {len(pictures_lost)} pictures seen live are not in the recording (pictures "
              f"{', '.join(map(str, pictures_lost[:10]))}{', ...' if len(pictures_lost) > 10 else ''}; see "
              f"{out}/logs/recorder-recorder.log)", file=sys.stderr)
    for o in report.router_outages:
        said = {k: "-" if o[k] is None else f"{o[k]:.2f}" for k in ("t", "back_after_s")}
        print(f"{title}: router outage at t = {said['t']} s, back after {said['back_after_s']} s (no failover: the "
              "centres' tokens went with the link)", file=sys.stderr)
    # the files there: a run stopped before its recorder stored anything has no measurements, tracks or plot (all
    # six were said written until tour58)
    print(f"wrote {out}/: {' '.join(n for n in names if (out / n).is_file())}")
    return summary
