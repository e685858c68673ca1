"""``fedtrack reproduce hpda``: paper 001's Table 1 (track loss) and Table 2 (initiation).

Table 1: for every (P_D, lambda) cell, ``runs`` seeded Monte Carlo runs of the paper's
scenario, batched over runs (one Python loop over the 61 scans). PDA-AI and HPDA see the
*same* detections (common random numbers): clutter is drawn, at density lambda, in the
union of both trackers' gate boxes, which is equivalent for gated single-target trackers
to clutter over the whole region. Both tracks start by two-point differencing of the
target's first two (clutter-free) measurements. A track is lost when the true position is
outside its validation gate on 3 consecutive scans.

Table 2: the track-initiation experiment, one run at a time through the multi-track
manager (:mod:`fedtrack.local_filters.pda.tracks`): clutter over a square around the target, no
target detections on the first 5 scans, time from the first target detection opportunity
to the first confirmed track holding the true position in its gate.

False tracks (per Table 1 cell, beside the track loss): the same manager, run with initiation
over all 61 scans with clutter over the Table 2 square, on ``FALSE_TRACK_RUNS`` runs per cell
(fewer if ``runs`` is smaller); a confirmed track that does not hold the target is false. Reported per 100 scans.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from fedtrack.experiments.tables import announce, pm, print_table
from fedtrack.local_filters.linear.kalman import predict
from fedtrack.local_filters.pda.association import (
    PDAParams,
    associate,
    constants,
    gate,
    gate_box,
    singer_model,
    truth_d2,
    two_point_init,
)
from fedtrack.local_filters.pda.config import ExistenceConfig
from fedtrack.local_filters.pda.tracks import TrackSet, initial_manager, manager_step, tracker_spec
from fedtrack.progress import progress_bar
from fedtrack.sensors.sonar import (
    ScenarioConfig,
    SonarConfig,
    clutter_in_boxes,
    concat,
    scan,
    sonar_scans,
    target_detections,
    truth_states,
)

PDS = (0.8, 0.9, 0.95)
LAMBDAS = (1e-5, 2.5e-5, 5e-5, 1e-4, 1.5e-4)
TRACKERS = {"pda_ai": "pda-ai", "hpda": "hpda"}  # JSON key -> algorithm
LOSS_SCANS = 3
SIGMA_R = 15.0
SNR = 20.0
TRACK_LOSS_RULE = ("lost when the true target position lies outside the track's validation gate "
                   f"(predicted, gamma = 9.21) on {LOSS_SCANS} consecutive scans")

# Paper Table 1: (P_D, lambda) -> (PDA-AI loss %, cpu s, HPDA loss %, cpu s)
PAPER_TABLE1 = {
    (0.8, 1e-5): (3.8, 83.9, 2.8, 83.9), (0.8, 2.5e-5): (4.4, 92.1, 3.8, 88.9),
    (0.8, 5e-5): (3.8, 105.3, 6.0, 92.4), (0.8, 1e-4): (6.6, 131.8, 5.2, 116.6),
    (0.8, 1.5e-4): (6.0, 158.7, 7.6, 143.1),
    (0.9, 1e-5): (2.2, 84.0, 1.6, 86.6), (0.9, 2.5e-5): (2.8, 91.8, 2.6, 91.3),
    (0.9, 5e-5): (3.6, 105.2, 2.6, 101.3), (0.9, 1e-4): (4.6, 135.3, 3.0, 115.8),
    (0.9, 1.5e-4): (5.2, 163.3, 2.8, 149.4),
    (0.95, 1e-5): (0.6, 91.9, 0.2, 85.7), (0.95, 2.5e-5): (2.4, 95.9, 3.0, 92.5),
    (0.95, 5e-5): (3.4, 108.4, 1.6, 99.0), (0.95, 1e-4): (3.6, 136.9, 2.0, 118.0),
    (0.95, 1.5e-4): (4.0, 170.09, 1.6, 149.9),
}

BINS = ((0.0, 150.0), (150.0, 300.0), (300.0, 350.0), (350.0, 375.0), (375.0, 425.0))
PAPER_TABLE2 = {"ipda_ai": (414, 77, 5, 1, 3), "hpda": (337, 160, 2, 1, 0)}
INITIATION = {"ipda_ai": "pda-ai", "hpda": "hpda"}  # JSON key -> algorithm
TABLE2_PD = 0.9
TABLE2_LAMBDA = 2.5e-5
TABLE2_HALF_WIDTH = 500.0
BLACKOUT_SCANS = 5
TARGET_RADIUS = 4.0 * SIGMA_R  # a confirmed track "holds the target" within this distance
PAPER_RULE = ExistenceConfig(false_track_rate=0.0, one_track_per_detection=False, clutter_from_scans=False,
                             supported_streak=False, amplitude_existence=False)
FALSE_TRACK_RUNS = 4  # the manager runs one scan at a time: 244 scans per cell and tracker
FALSE_TRACK_RULE = ("confirmed tracks not holding the target (true position outside the gate or farther than "
                    f"{TARGET_RADIUS:g} m), per 100 scans, with initiation over all 61 scans, clutter over a "
                    f"{2 * TABLE2_HALF_WIDTH:g} m square, {FALSE_TRACK_RUNS} runs per cell")


def _params(pd: float, lam: float) -> PDAParams:
    return PDAParams(pd=pd, clutter_density=lam, snr=SNR)


def table1_cell(pd: float, lam: float, runs: int, rng: np.random.Generator) -> dict[str, Any]:
    """Track loss of PDA-AI and HPDA over ``runs`` batched runs of one (P_D, lambda) cell."""
    p = _params(pd, lam)
    c = constants(p)
    sc = ScenarioConfig()
    times, truth = truth_states(sc)
    model = singer_model(sc.T, p.sigma_a, p.tau_s)
    R = SIGMA_R**2 * np.eye(2)
    pos = truth[:, [0, 3]]
    z0 = pos[0] + SIGMA_R * rng.standard_normal((runs, 2))
    z1 = pos[1] + SIGMA_R * rng.standard_normal((runs, 2))
    start = two_point_init(z0, z1, sc.T, R, p.sigma_a)
    states = {k: start for k in TRACKERS}
    out_count = {k: np.zeros(runs, dtype=int) for k in TRACKERS}
    lost = {k: np.zeros(runs, dtype=bool) for k in TRACKERS}
    cpu = {k: 0.0 for k in TRACKERS}
    for k in range(2, len(times)):
        preds = {}
        lo = np.full((runs, 2), np.inf)
        hi = np.full((runs, 2), -np.inf)
        for name in TRACKERS:
            t0 = time.process_time()
            preds[name] = predict(states[name], model.F, model.Q)
            cpu[name] += time.process_time() - t0
            blo, bhi = gate_box(preds[name], model.H, R, c)
            act = ~lost[name][:, None]
            lo = np.where(act, np.minimum(lo, blo), lo)
            hi = np.where(act, np.maximum(hi, bhi), hi)
        none = ~np.isfinite(lo)
        lo, hi = np.where(none, pos[k], lo), np.where(none, pos[k], hi)
        dets = concat(target_detections(rng, np.broadcast_to(pos[k], (runs, 2)), pd, SNR, c.tau, SIGMA_R),
                      clutter_in_boxes(rng, lo, hi, lam, c.tau))
        for name, algorithm in TRACKERS.items():
            t0 = time.process_time()
            g = gate(preds[name], dets.z, dets.valid, model.H, R, c)
            post, _ = associate(algorithm, preds[name], g, dets.amplitude, c)
            cpu[name] += time.process_time() - t0
            outside = truth_d2(preds[name], g, pos[k], model.H) > c.gamma
            out_count[name] = np.where(outside, out_count[name] + 1, 0)
            lost[name] |= out_count[name] >= LOSS_SCANS
            states[name] = post
    paper = PAPER_TABLE1[(pd, lam)]
    row: dict[str, Any] = {"pd": pd, "lambda": lam}
    for name in TRACKERS:
        frac = float(np.mean(lost[name]))
        row[name] = {"track_loss_pct": 100.0 * frac,
                     "stderr_pct": 100.0 * float(np.sqrt(frac * (1.0 - frac) / runs)),
                     "cpu_s": cpu[name]}
    diff = lost["hpda"].astype(float) - lost["pda_ai"].astype(float)
    row["hpda_minus_pda_ai"] = {"pct": 100.0 * float(np.mean(diff)),
                                "paired_stderr_pct": 100.0 * float(np.std(diff, ddof=1) / np.sqrt(runs))
                                if runs > 1 else float("nan")}
    row["paper"] = {"pda_ai": {"track_loss_pct": paper[0], "cpu_s": paper[1]},
                    "hpda": {"track_loss_pct": paper[2], "cpu_s": paper[3]}}
    return row


def holds_target(tracks: TrackSet, x: np.ndarray, R: np.ndarray, gamma: float) -> np.ndarray:
    """Tracks with the true position in their gate and within ``TARGET_RADIUS`` of their estimate."""
    e = tracks.state.x[:, [0, 3]] - x[[0, 3]]
    S = tracks.state.P[:, [0, 3]][:, :, [0, 3]] + R
    d2 = np.einsum("ni,ni->n", e, np.linalg.solve(S, e[..., None])[..., 0])
    return (d2 <= gamma) & (np.linalg.norm(e, axis=-1) <= TARGET_RADIUS)


def false_track_run(algorithm: str, pd: float, lam: float, rng: np.random.Generator) -> np.ndarray:
    """Confirmed tracks not holding the target, per scan, over one run of the scenario with
    initiation (clutter over the Table 2 square)."""
    cfg = SonarConfig(pd=pd, clutter_density=lam, snr=SNR, sigma_r=SIGMA_R, region_half_width=TABLE2_HALF_WIDTH)
    spec = tracker_spec(algorithm, _params(pd, lam), ExistenceConfig())
    times, truth = truth_states(cfg.scenario)
    R = SIGMA_R**2 * np.eye(2)
    ms = initial_manager()
    false = np.zeros(len(times), dtype=int)
    for k, (t, x) in enumerate(zip(times, truth)):
        dets = scan(rng, cfg, k, x)
        ms, rep = manager_step(spec, ms, t, dets.z, dets.amplitude, R)
        conf = rep.tracks.take(rep.tracks.confirmed)
        false[k] = int(np.sum(~holds_target(conf, x, R, spec.c.gamma)))
    return false


def false_track_cell(pd: float, lam: float, runs: int, seed: int, cell: int) -> dict[str, Any]:
    """Confirmed false tracks per 100 scans (mean over runs, standard error) for both trackers."""
    out: dict[str, Any] = {"runs": runs}
    for name, algorithm in INITIATION.items():
        t0 = time.process_time()
        per_run = np.array([false_track_run(algorithm, pd, lam, np.random.default_rng([seed, 3, cell, r]))
                            for r in range(runs)])
        rate = 100.0 * per_run.mean(axis=1)
        out[name] = {"per_100_scans": float(rate.mean()),
                     "stderr": float(rate.std(ddof=1) / np.sqrt(runs)) if runs > 1 else float("nan"),
                     "max_in_a_scan": int(per_run.max()), "cpu_s": time.process_time() - t0}
    return out


def initiation_time(algorithm: str, seed: int, run: int, rule: ExistenceConfig) -> tuple[float, int]:
    """Seconds from the first target detection opportunity to the first confirmed track
    holding the target (true position in its gate and within ``TARGET_RADIUS`` of its
    estimate); ``inf`` if that never happens. Also returns the number of (false) tracks
    confirmed during the clutter-only blackout scans."""
    cfg = SonarConfig(pd=TABLE2_PD, clutter_density=TABLE2_LAMBDA, snr=SNR, sigma_r=SIGMA_R,
                      region_half_width=TABLE2_HALF_WIDTH, blackout_scans=BLACKOUT_SCANS)
    spec = tracker_spec(algorithm, _params(TABLE2_PD, TABLE2_LAMBDA), rule)
    rng = np.random.default_rng([seed, 2, run])
    times, truth = truth_states(cfg.scenario)
    R = SIGMA_R**2 * np.eye(2)
    t_first = times[BLACKOUT_SCANS]
    ms = initial_manager()
    false_tracks = 0
    for k, (t, x) in enumerate(zip(times, truth)):
        dets = scan(rng, cfg, k, x)
        ms, rep = manager_step(spec, ms, t, dets.z, dets.amplitude, R)
        conf = rep.tracks.confirmed
        if k < BLACKOUT_SCANS:
            false_tracks += int(np.sum(rep.newly_confirmed))
        if k >= BLACKOUT_SCANS and np.any(holds_target(rep.tracks.take(conf), x, R, spec.c.gamma)):
            return float(t - t_first), false_tracks
    return float("inf"), false_tracks


def initiation_counts(runs: int, seed: int, rule: ExistenceConfig, progress: tqdm) -> dict[str, Any]:
    """Initiation-time counts per bin for IPDA-AI and HPDA initiation under one confirmation rule."""
    out: dict[str, Any] = {}
    for name, algorithm in INITIATION.items():
        t0 = time.process_time()
        times = np.empty(runs)
        false_tracks = np.empty(runs)
        for r in range(runs):
            times[r], false_tracks[r] = initiation_time(algorithm, seed, r, rule)
            progress.update()
        counts = [int(np.sum((times >= lo) & (times < hi))) for lo, hi in BINS]
        finite = np.isfinite(times)
        out[name] = {"counts": counts, "later": int(np.sum(finite & (times >= BINS[-1][1]))),
                     "never": int(np.sum(~finite)),
                     "mean_s": float(np.mean(times[finite])) if np.any(finite) else None,
                     "false_confirmed_per_run_in_blackout": float(np.mean(false_tracks)),
                     "cpu_s": time.process_time() - t0,
                     "times_s": [float(t) if np.isfinite(t) else None for t in times]}
    return out


def table2(runs: int, seed: int, progress: tqdm) -> dict[str, Any]:
    """Table 2 under the paper's confirmation rule (``ipda_ai``, ``hpda``) and under fedtrack's default rule
    (``default_rule``: the false-track test, one track per detection, the supported streak and eq (9) existence)."""
    out: dict[str, Any] = {"bins_s": [list(b) for b in BINS], "pd": TABLE2_PD, "lambda": TABLE2_LAMBDA,
                           "region_half_width_m": TABLE2_HALF_WIDTH, "blackout_scans": BLACKOUT_SCANS,
                           "time_origin": "first scan with a target detection opportunity",
                           "paper": {k: list(v) for k, v in PAPER_TABLE2.items()}}
    out.update(initiation_counts(runs, seed, PAPER_RULE, progress))
    out["default_rule"] = initiation_counts(runs, seed, ExistenceConfig(), progress)
    return out


def reproduce_hpda(runs: int, seed: int, json_path: Path, plots_dir: Path | None) -> dict[str, Any]:
    """Both tables of paper 001; writes ``json_path`` (and PNGs to ``plots_dir``)."""
    cells = [(pd, lam) for pd in PDS for lam in LAMBDAS]
    announce(f"reproduce hpda: paper 001, Table 1 (PDA-AI vs HPDA track loss, {len(cells)} (P_D, lambda) cells) "
             f"and Table 2 (IPDA-AI vs HPDA initiation), {runs} Monte Carlo runs each, seed {seed}")
    wall0 = time.perf_counter()
    false_runs = min(runs, FALSE_TRACK_RUNS)
    result: dict[str, Any] = {"runs": runs, "seed": seed, "track_loss_rule": TRACK_LOSS_RULE,
                              "false_track_rule": FALSE_TRACK_RULE}
    with progress_bar(2 * len(cells) + 4 * runs, "reproduce hpda") as progress:
        rows = []
        for i, (pd, lam) in enumerate(cells):
            rows.append(table1_cell(pd, lam, runs, np.random.default_rng([seed, 1, i])))
            progress.update()
            rows[-1]["false_tracks"] = false_track_cell(pd, lam, false_runs, seed, i)
            progress.update()
        result["table1"] = rows
        result["table2"] = table2(runs, seed, progress)
    result["wall_time_s"] = time.perf_counter() - wall0
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=1))
    if plots_dir is not None:
        plot_all(result, seed, plots_dir)
    print_summary(result)
    return result


def print_summary(result: dict[str, Any]) -> None:
    """Table 1 (track loss per cell, paper beside ours) and Table 2 (initiation time bins)."""
    rows = [[f"{c['pd']:g}", f"{c['lambda']:g}",
             pm(c["pda_ai"]["track_loss_pct"], c["pda_ai"]["stderr_pct"], 1),
             f"{c['paper']['pda_ai']['track_loss_pct']:g}",
             pm(c["hpda"]["track_loss_pct"], c["hpda"]["stderr_pct"], 1),
             f"{c['paper']['hpda']['track_loss_pct']:g}",
             pm(c["hpda_minus_pda_ai"]["pct"], c["hpda_minus_pda_ai"]["paired_stderr_pct"], 1)]
            for c in result["table1"]]
    print_table(f"Table 1: track loss [%] (+- standard error), {result['runs']} runs per cell",
                ["P_D", "lambda", "PDA-AI", "paper", "HPDA", "paper", "HPDA - PDA-AI"], rows)
    rows = [[f"{c['pd']:g}", f"{c['lambda']:g}",
             *(f"{pm(c['false_tracks'][k]['per_100_scans'], c['false_tracks'][k]['stderr'], 2)} "
               f"(max {c['false_tracks'][k]['max_in_a_scan']})" for k in ("ipda_ai", "hpda"))]
            for c in result["table1"]]
    print_table(f"Confirmed false tracks per 100 scans (+- standard error; most in one scan), with initiation, "
                f"{result['table1'][0]['false_tracks']['runs']} runs of 61 scans per cell",
                ["P_D", "lambda", "IPDA-AI", "HPDA"], rows)
    t2 = result["table2"]
    bins = [f"{lo:g}-{hi:g} s" for lo, hi in t2["bins_s"]]
    rows = [[name, *(f"{n} ({p})" for n, p in zip(t2[key]["counts"], t2["paper"][key])), str(t2[key]["never"]),
             pm(t2[key]["mean_s"], None, 1), f"{t2[key]['false_confirmed_per_run_in_blackout']:.2f}"]
            for key, name in (("ipda_ai", "IPDA-AI"), ("hpda", "HPDA"))]
    rows += [[f"{name}, default rule", *(str(n) for n in t2["default_rule"][key]["counts"]),
              str(t2["default_rule"][key]["never"]), pm(t2["default_rule"][key]["mean_s"], None, 1),
              f"{t2['default_rule'][key]['false_confirmed_per_run_in_blackout']:.2f}"]
             for key, name in (("ipda_ai", "IPDA-AI"), ("hpda", "HPDA"))]
    print_table(f"Table 2: confirmation time, runs per bin (paper's count in brackets), P_D = {t2['pd']:g}, "
                f"lambda = {t2['lambda']:g}; the paper's confirmation rule, then fedtrack's default "
                "(false-track test, one track per detection, supported streak, eq (9) existence)",
                ["tracker", *bins, "never", "mean [s]", "false/run"], rows)


# Figures (paper 001 Figs. 2-4) for ``--plots DIR``.

FIG2_PD = 0.9
FIG2_LAMBDA = 1e-4
FIG2_HALF_WIDTH = 600.0


def single_run_tracks(seed: int) -> dict[str, Any]:
    """One run of both trackers over :func:`sonar_scans` lines (init from the truth's first
    two positions plus measurement noise, as in Table 1)."""
    cfg = SonarConfig(pd=FIG2_PD, clutter_density=FIG2_LAMBDA, region_half_width=FIG2_HALF_WIDTH)
    p = PDAParams(pd=cfg.pd, clutter_density=cfg.clutter_density, snr=cfg.snr)
    c = constants(p)
    model = singer_model(cfg.scenario.T, p.sigma_a, p.tau_s)
    lines = list(sonar_scans(cfg, seed))
    rng = np.random.default_rng([seed, 3])
    truth = np.array([ln["truth"] for ln in lines])[:, [0, 3]]
    R = np.asarray(lines[0]["R"])
    z0, z1 = truth[:2] + cfg.sigma_r * rng.standard_normal((2, 2))
    out: dict[str, Any] = {"truth": truth, "clutter": np.concatenate(
        [np.array([d["z"] for d in ln["detections"]]).reshape(-1, 2) for ln in lines])}
    for algorithm in ("pda-ai", "hpda"):
        state = two_point_init(z0, z1, cfg.scenario.T, R, p.sigma_a)
        est = [z0, z1]
        for ln in lines[2:]:
            z = np.array([d["z"] for d in ln["detections"]]).reshape(-1, 2)
            a = np.array([d["amplitude"] for d in ln["detections"]])
            pred = predict(state, model.F, model.Q)
            g = gate(pred, z, np.ones(len(a), dtype=bool), model.H, R, c)
            state, _ = associate(algorithm, pred, g, a, c)
            est.append(state.x[[0, 3]])
        out[algorithm] = np.array(est)
    return out


def plot_all(result: dict[str, Any], seed: int, plots_dir: Path) -> list[Path]:
    """Write ``hpda_tracks.png`` and ``hpda_initiation.png``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots_dir.mkdir(parents=True, exist_ok=True)
    run = single_run_tracks(seed)
    fig, ax = plt.subplots(figsize=(9, 6))
    ax.scatter(run["clutter"][:, 0], run["clutter"][:, 1], s=1, c="0.75", label="detections (all scans)")
    ax.plot(*run["truth"].T, "k-", lw=2, label="truth")
    ax.plot(*run["pda-ai"].T, "b.-", ms=4, lw=1, label="PDA-AI")
    ax.plot(*run["hpda"].T, "r.--", ms=4, lw=1, label="HPDA")
    ax.set(xlabel="x (m)", ylabel="y (m)", aspect="equal",
           title=f"One run, P_D = {FIG2_PD}, lambda = {FIG2_LAMBDA:g} /m^2, rho = 20 (seed {seed})")
    ax.legend(loc="best", fontsize=8)
    tracks_png = plots_dir / "hpda_tracks.png"
    fig.savefig(tracks_png, dpi=110, bbox_inches="tight")
    plt.close(fig)

    t2 = result["table2"]
    labels = [f"{lo:g}-{hi:g}" for lo, hi in t2["bins_s"]]
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(9, 5))
    ours, paper_runs = 100.0 / result["runs"], 100.0 / 500
    series = [(f"IPDA-AI (ours, {result['runs']} runs)", t2["ipda_ai"]["counts"], ours, "tab:blue", ""),
              ("IPDA-AI (paper, 500 runs)", t2["paper"]["ipda_ai"], paper_runs, "tab:blue", "//"),
              (f"HPDA (ours, {result['runs']} runs)", t2["hpda"]["counts"], ours, "tab:red", ""),
              ("HPDA (paper, 500 runs)", t2["paper"]["hpda"], paper_runs, "tab:red", "//")]
    w = 0.2
    for i, (name, counts, scale, colour, hatch) in enumerate(series):
        ax.bar(x + (i - 1.5) * w, np.asarray(counts) * scale, w, label=name, color=colour,
               hatch=hatch, alpha=0.5 if hatch else 0.9, edgecolor="k")
    ax.set_xticks(x, labels)
    ax.set(xlabel="time from the first target detection opportunity to confirmation (s)",
           ylabel="runs confirmed in the bin (%)",
           title=f"Track initiation, P_D = {t2['pd']}, lambda = {t2['lambda']:g} /m^2")
    ax.legend()
    hist_png = plots_dir / "hpda_initiation.png"
    fig.savefig(hist_png, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return [tracks_png, hist_png]
