"""Figures for ``fedtrack reproduce hpda --plots DIR`` (paper 001 Figs. 2-4)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fedtrack.local_filters.linear.kalman import predict  # noqa: E402
from fedtrack.local_filters.pda.association import PDAParams, associate, constants, gate, singer_model, two_point_init  # noqa: E402
from fedtrack.sensors.sonar import SonarConfig, sonar_scans  # noqa: E402

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
