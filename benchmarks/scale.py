"""``fedtrack bench scale``: the track-to-track centre sharded by region (issue 27 item 3).

The 1,000-target, 4-sensor (1 Hz) scenario of ``bench multitarget`` replayed by ``mtt-federated``
in one process with 1, 2, 4 and 8 regions (grids 1x1, 2x1, 2x2, 4x2 over the detections' extent:
:class:`ShardedCentre`, each region's centre run in turn). Per region: the CPU seconds spent in
its centre object (process time around its reports and its hand-overs out and in), its state
size (the bytes of its pickled centre: the tracks' arrays at their allocated capacity and the
mapping: a proxy for its RSS share, not a process's RSS), its tracks at the end, the rows of its
sub-reports and those it fused (the rest: the margin's rows of other regions' tracks); per run: the
hand-overs, mean GOSPA (c = 100 m, p = 2) with its missed and false parts, id switches and
fragmentations (each beside the one region's: a hand-over that lost a track, kept it twice or gave
it a new id shows there), ids twice in a picture and central tracks held by two centres at a
picture (both 0 when every hand-over moved its track), the routing CPU seconds (the local
trackers' part live).
One region is the unsharded centre (identical pictures, tests/test_mtt_shards.py).
All of these are measured in one process, each region's centre in turn. Then each centre is measured in
its own process (``own_process``, :mod:`.centre_replay`): its calls recorded in the run, replayed in a
fresh process built as ``serve mtt-centre`` builds the centre, in rounds; its CPU seconds, RSS before the
first call and peak, the busiest over the one region's per round (mean and SE), and issue 27's load
point at 4 regions under both readings of its CPU bar (``issue_27_load``, printed beside the in-process one).

``--targets N`` keeps the 1,000-target scenario's densities: the square's half side
``Scenario.region`` and the clutter count per scan are scaled by ``sqrt(N / 1000)`` and ``N /
1000`` (targets and false detections per m^2 as at 1,000; the margin unchanged), so that each of
the ``n`` regions holds ``N / n`` targets in a cell ``sqrt(N / 1000)`` times as wide.

The load model at 100 regions (:func:`load_model`): with tracks spread evenly over square cells
of side ``L`` and margin ``m``, the share of tracks within ``m`` of a border is
``1 - ((L - 2m) / L)^2``; a centre receives one report per scan of each sensor that sees its
region (rows: its tracks times ``1 + margin share``), and hands over ``4 N_r v_mean / (pi L)``
tracks a second (isotropic headings: the flux out of a square of ``N_r`` tracks).
"""

from __future__ import annotations

import math
import pickle
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.benchmarks.centre_replay import Recording, measure, regions_config
from fedtrack.config import load_tables
from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
from fedtrack.fusion_center.mtt.evaluation import evaluate
from fedtrack.fusion_center.mtt.replay import data_regions, pictures, read_scans, state_dim
from fedtrack.fusion_center.mtt.shards import ShardedCentre
from fedtrack.jsonl import output_file
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.local_filters.regions import Regions, distances, region_of
from fedtrack.progress import progress_bar
from fedtrack.sensors.multitarget import SPEED, Scenario, parse_spec, simulate

GRIDS = {1: "1x1", 2: "2x1", 4: "2x2", 8: "4x2"}
BASE_TARGETS = 1000  # the scenario whose densities every --targets keeps
MARGIN_M = 500.0  # docs/multitarget.md#regions: 30 m/s targets, 1 s scans, 10 m noise need ~ 75 m
PROCESS_ROUNDS = 5  # each centre's own-process replay, in rounds (.centre_replay)
# issue 27's load bar at 4 regions, both readings of "1/4 of the unsharded centre's CPU plus 15 %"; RSS at most 1/2
CPU_BAR_PLUS, CPU_BAR_TIMES, RSS_BAR = 0.25 + 0.15, 0.25 * 1.15, 0.5


def margin_share(regions: Regions, pos: np.ndarray) -> float:
    """The share of positions (N, 2) within the margin of a region other than their owner's."""
    d = distances(regions, pos)
    d[np.arange(len(pos)), region_of(regions, pos)] = np.inf
    return float(np.mean(d.min(axis=1) <= regions.margin)) if d.shape[1] > 1 else 0.0


def ids_held_by_two(centre: ShardedCentre) -> int:
    """Central tracks held by more than one region centre (a hand-over that copied a track
    instead of moving it), counted once per extra holder."""
    held = [c.centre.tracks.ids[c.centre.tracks.live()] for c in centre.centres]
    return sum(h.size for h in held) - np.unique(np.concatenate(held)).size


def load_model(regions: int, tracks: int, sensors: int, rate_hz: float, cell_m: float, margin_m: float,
               speed: float) -> dict[str, float]:
    """Per centre at ``regions`` square cells of side ``cell_m`` with ``tracks`` spread evenly,
    ``sensors`` seeing each region, scanning at ``rate_hz``, targets at ``speed`` [m/s]."""
    share = 1.0 - max(cell_m - 2 * margin_m, 0.0) ** 2 / cell_m**2
    per = tracks / regions
    return {"regions": regions, "tracks_per_centre": per, "margin_share": share,
            "reports_per_s": sensors * rate_hz, "rows_per_s": per * sensors * rate_hz * (1 + share),
            "hand_overs_per_s": 4 * per * speed / (math.pi * cell_m)}


def scaled_scenario(targets: int, duration: float) -> Scenario:
    """The 1,000-target scenario's target and clutter densities at ``targets`` (module docstring)."""
    share = targets / BASE_TARGETS
    return Scenario(targets=targets, duration=duration, region=Scenario.region * math.sqrt(share),
                    clutter=Scenario.clutter * share)


def thinned_truth(truth: Path, every: int, out: Path) -> Path:
    """``truth`` with every ``every``-th line (from the first): ``evaluate`` scores only the pictures
    that have a truth line at their time."""
    with truth.open() as src, output_file(out) as fh:
        fh.writelines(line for k, line in enumerate(src) if k % every == 0)
    return out


def bench_scale(quick: bool, targets: int | None = None, duration: float | None = None,
                gospa_every: int = 1, process_rounds: int | None = None) -> dict[str, Any]:
    """``targets`` (default 1,000; ``quick``: 50 over the default area) at the 1,000-target densities;
    GOSPA over every ``gospa_every``-th second's picture (``evaluate``'s assignment is dense: about
    10 s a picture at 10,000 targets); each centre replayed in its own process ``process_rounds`` times
    (default ``PROCESS_ROUNDS``, ``quick`` 1; 0: not at all; :mod:`.centre_replay`)."""
    if process_rounds is None:
        process_rounds = 1 if quick else PROCESS_ROUNDS
    if targets is None and quick:
        sc = Scenario(targets=50, duration=duration or 20.0)
    else:
        sc = scaled_scenario(targets or BASE_TARGETS, duration or (20.0 if quick else 60.0))
    targets, duration = sc.targets, sc.duration
    out: dict[str, Any] = {"targets": targets, "sensors": 4, "period_s": 1.0, "duration_s": duration,
                           "half_width_m": sc.region, "clutter_per_scan": sc.clutter, "gospa_every_s": gospa_every,
                           "margin_m": MARGIN_M, "state_size": "bytes of each region's pickled centre", "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp)
        start = time.perf_counter()
        simulate(sc, parse_spec("pos:1.0,pos:1.0,pos:1.0,pos:1.0"), 2, sim)
        print(f"bench scale: {targets} targets, {duration:g} s over a {2 * sc.region / 1e3:.1f} km square "
              f"simulated in {time.perf_counter() - start:.1f} s", flush=True)
        (sim / "regions.toml").write_text((sim / "config.toml").read_text()
                                          + f"\n[regions]\nmargin = {MARGIN_M}\n"
                                          + "grid = {origin = [0, 0], cell = [1, 1], nx = 1, ny = 1}\n")
        cfg = load_tables(sim / "config.toml", MttSettings).mtt
        truth = sim / "truth.jsonl" if gospa_every == 1 else thinned_truth(sim / "truth.jsonl", gospa_every,
                                                                              sim / "truth-thinned.jsonl")
        scans = read_scans(sim / "measurements.jsonl", cfg)
        dim = state_dim(scans)
        recorded: dict[int, tuple[Recording, Path, Regions]] = {}
        for n, spec in GRIDS.items():
            regions = data_regions(spec, scans, sim / "regions.toml")
            centre = ShardedCentre(cfg, dim, True, regions)
            engine = TrackToTrackEngine(cfg, dim, feedback=True, regions=regions, centre=centre)
            if process_rounds:
                recorded[n] = (Recording(sim / f"calls-{n}", centre), regions_config(
                    sim / "config.toml", regions, sim / f"regions-{n}.toml"), regions)
            path = sim / f"{n}.jsonl"
            start = time.perf_counter()
            twice = held_twice = 0
            with output_file(path) as fh, progress_bar(int(duration / cfg.period), f"{n} regions", unit="picture",
                                                       mininterval=5.0, leave=False) as bar:
                for T, tracks in pictures(engine, scans, cfg.period, cfg.picture_delay):
                    bar.update()
                    fh.write(tracks.line(T, {"algorithm": "mtt-federated"}) + "\n")
                    twice += len(tracks.ids) - len(set(tracks.ids))
                    held_twice += ids_held_by_two(centre)
                    if n in recorded:
                        mark = time.perf_counter()
                        recorded[n][0].picture(T, tracks)
                        start += time.perf_counter() - mark  # the recording's time is not the run's
            wall = time.perf_counter() - start
            if n in recorded:
                recorded[n][0].close()
            score = evaluate(path, truth)
            last = engine.picture(scans[-1].t)
            out["runs"][n] = {
                "grid": spec, "wall_s": wall, "routing_cpu_s": centre.routing_s, "hand_overs": centre.handed_over,
                "cpu_s": centre.cpu_s, "max_cpu_s": max(centre.cpu_s),
                "state_bytes": [len(pickle.dumps(c.centre)) for c in centre.centres],
                "tracks": [len(c.centre.tracks) for c in centre.centres],
                "rows": [c.rows for c in centre.centres], "rows_taken": [c.rows_taken for c in centre.centres],
                "margin_share": margin_share(regions, last.x[:, [0, 2]]) if last.ids else 0.0,
                "gospa": score["mean"]["gospa"], "missed": score["mean"]["missed"],
                "false": score["mean"]["false"], "id_switches": score["id_switches"],
                "fragmentations": score["fragmentations"], "ids_twice_in_a_picture": twice,
                "ids_held_by_two_centres": held_twice}
            print(f"bench scale: {n} regions: {wall:.1f} s, {centre.handed_over} hand-overs", flush=True)
        base = out["runs"][1]
        for row in out["runs"].values():
            row["max_cpu_vs_one"] = row["max_cpu_s"] / base["max_cpu_s"]
            row["max_state_vs_one"] = max(row["state_bytes"]) / base["state_bytes"][0]
            busiest = int(np.argmax(row["cpu_s"]))  # its share of the rows received and fused
            row["busiest_rows_vs_one"] = row["rows"][busiest] / base["rows"][0]
            row["busiest_rows_taken_vs_one"] = row["rows_taken"][busiest] / base["rows"][0]
            row["gospa_vs_one"] = row["gospa"] / base["gospa"] - 1.0
            for key in ("missed", "false", "id_switches", "fragmentations"):
                row[f"{key}_vs_one"] = row[key] - base[key]
        side = 2 * sc.region  # the simulated area's side [m]
        speed = float(np.mean(SPEED))
        out["model_100_regions"] = {
            "this_area": load_model(100, targets, 4, 1.0, side / 10, MARGIN_M, speed),
            # 1e5 air tracks over 1,000 km x 1,000 km, 8 radars of 12 s scans seeing each 100 km
            # cell, 250 m/s; margin 250 m/s x 12 s + 4.3 x 200 m ~ 4 km (docs/multitarget.md#regions)
            "national": load_model(100, 100_000, 8, 1 / 12, 1.0e5, 4_000.0, 250.0)}
        # the model checked against the measured grids (cells of this area)
        out["model_check"] = {n: {"margin_share_measured": row["margin_share"],
                                  "margin_share_model": load_model(n, targets, 4, 1.0, side / math.sqrt(n),
                                                                   MARGIN_M, speed)["margin_share"],
                                  "hand_overs_per_s_measured": row["hand_overs"] / duration / n,
                                  "hand_overs_per_s_model": load_model(n, targets, 4, 1.0, side / math.sqrt(n),
                                                                       MARGIN_M, speed)["hand_overs_per_s"]}
                              for n, row in out["runs"].items() if n in (4,)}
        if process_rounds:
            with progress_bar(process_rounds * (1 + sum(GRIDS)), "centres in their own processes", unit="process",
                              mininterval=5.0, leave=False) as progress:
                out["own_process"] = measure(recorded, dim, process_rounds, sim, progress)
            out["issue_27_load"] = load_bar(out)
            print_table(out)
    return out


def load_bar(out: dict[str, Any]) -> dict[str, Any]:
    """Issue 27's load point at 4 regions: the busiest centre's CPU over the one region's against
    1/4 + 0.15 and against the stricter 1/4 x 1.15, the largest centre's RSS over the one's against 1/2;
    in one process (``cpu_s``, the state-size proxy) and each centre in its own (mean and SE over the rounds)."""
    inproc, own = out["runs"][4], out["own_process"]["runs"][4]
    cpu, rss = own["busiest_vs_one"], own["largest_rss_vs_one"]
    return {"regions": 4, "cpu_bar_plus_0.15": CPU_BAR_PLUS, "cpu_bar_times_1.15": CPU_BAR_TIMES, "rss_bar": RSS_BAR,
            "in_process_busiest_vs_one": inproc["max_cpu_vs_one"],
            "own_process_busiest_vs_one": cpu, "own_process_busiest_vs_one_se": own["busiest_vs_one_se"],
            "own_process_busiest_vs_unsharded": own["busiest_vs_unsharded"],
            "own_process_busiest_vs_unsharded_se": own["busiest_vs_unsharded_se"],
            "cpu_met_plus_0.15": cpu <= CPU_BAR_PLUS, "cpu_met_times_1.15": cpu <= CPU_BAR_TIMES,
            "in_process_state_vs_one": inproc["max_state_vs_one"],
            "own_process_rss_vs_one": rss, "own_process_rss_vs_one_se": own["largest_rss_vs_one_se"],
            "own_process_own_rss_vs_one": own["largest_own_rss_vs_one"],
            "own_process_own_rss_vs_one_se": own["largest_own_rss_vs_one_se"],
            "rss_met": rss <= RSS_BAR, "own_rss_met": own["largest_own_rss_vs_one"] <= RSS_BAR}


def print_table(out: dict[str, Any]) -> None:
    """The busiest (largest) centre over the one region's, in one process and each in its own."""
    own = out["own_process"]

    def pm(row: dict[str, Any], key: str) -> str:
        se = row[f"{key}_se"]
        return f"{row[key]:.3f}" + ("" if se is None else f" +- {se:.3f}")

    print(f"\nbench scale: busiest (largest) centre / the one region's; own process: mean +- SE over {own['rounds']} "
          "rounds\n| regions | CPU, in one process | CPU, own process | own / unsharded | busiest CPU s, own "
          "| RSS peak, own | own memory (peak - before) | state bytes (proxy) |\n" + "| --- " * 8 + "|")
    for n, row in out["runs"].items():
        p = own["runs"][n]
        print(f"| {n} | {row['max_cpu_vs_one']:.3f} | {pm(p, 'busiest_vs_one')} | {pm(p, 'busiest_vs_unsharded')} "
              f"| {p['cpu_s'][p['busiest']]:.3f} | {pm(p, 'largest_rss_vs_one')} ({max(p['rss_peak_mb']):.1f} MB) "
              f"| {pm(p, 'largest_own_rss_vs_one')} ({max(p['own_rss_mb']):.1f} MB) | {row['max_state_vs_one']:.3f} |")
    bar = out["issue_27_load"]
    print(f"issue 27 at 4 regions: CPU {bar['own_process_busiest_vs_one']:.3f} (own process) against "
          f"{CPU_BAR_PLUS:g} (1/4 + 0.15: {'met' if bar['cpu_met_plus_0.15'] else 'not met'}) and "
          f"{CPU_BAR_TIMES:g} (1/4 x 1.15: {'met' if bar['cpu_met_times_1.15'] else 'not met'}); RSS "
          f"{bar['own_process_rss_vs_one']:.3f} (process), {bar['own_process_own_rss_vs_one']:.3f} (own memory) "
          f"against {RSS_BAR:g}", flush=True)
