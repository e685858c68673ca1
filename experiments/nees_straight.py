"""The state NEES a CV Kalman filter alone gives on a straight leg (docs/multitarget.md, "Straight
legs at 86 % whatever q"): a target at constant velocity (8-30 m/s, any heading) seen by the
simulator's default position sensors (periods 1.0 / 0.7 / 1.3 s at random phases, each with its
noise drawn as ``simulate multitarget`` draws it, P_D 0.9), tracked by the trackers' CV predict
(:func:`~fedtrack.local_filters.mtt.models.predict_batch`) and a Kalman update, no association,
clutter or track logic. Per ``q``: the fraction of the whole-second pictures' 4-dof NEES (after a
warm-up) inside the two-sided 95% band and below it, and the mean squared velocity error over the
mean velocity variance. Usage: ``python -m fedtrack.experiments.nees_straight [--runs N] [--seed S]``.
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import numpy as np
from scipy.special import chdtri

from fedtrack.experiments.tables import print_table
from fedtrack.local_filters.linear.kalman import GaussianState, nees, update
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.models import predict_batch
from fedtrack.sensors.multitarget import POS_SD_MAX, POS_SD_MIN, SPEED, parse_spec, process_noise

PERIODS = (1.0, 0.7, 1.3)  # s: simulate multitarget's default sensors
BATCH = 25  # runs at once
H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
#: q [m^2/s^3]: the simulator's derived value for its default sensors, then down to where the
#: steady state no longer comes within the run
QS = (process_noise(parse_spec(",".join(f"pos:{p}" for p in PERIODS))), 0.3, 0.03, 3e-3, 3e-4, 3e-6)


def straight_states(v: np.ndarray, t: float) -> np.ndarray:
    """States ``[x, vx, y, vy]`` at ``t`` of targets leaving the origin at time 0 with velocities ``v`` (n, 2)."""
    return np.column_stack([v[:, 0] * t, v[:, 0], v[:, 1] * t, v[:, 1]])


class StraightNees(NamedTuple):
    """One process noise ``q``'s NEES on straight legs (:func:`straight_nees`)."""

    q: float
    inside: float  # fraction of the pictures' NEES inside the two-sided 95% band (4 dof)
    inside_se: float  # its standard error over the batches (runs of one batch share their sensors)
    below: float  # fraction below the band (P larger than the error)
    velocity_ratio: float  # mean squared velocity error / mean velocity variance (1: consistent)


def straight_nees(q: float, runs: int = 400, duration: float = 200.0, warm: float = 30.0, pd: float = 0.9,
                  seed: int = 0) -> StraightNees:
    """The NEES of ``runs`` straight legs of ``duration`` seconds at whole-second pictures from ``warm`` on,
    in batches of ``BATCH`` run at once (a batch's runs share the sensors' phases and noise levels,
    each batch draws its own)."""
    rng = np.random.default_rng(seed)
    lo, hi = chdtri(4, 0.975), chdtri(4, 0.025)
    fractions, below, pairs, err_v, var_v = [], 0, 0, 0.0, 0.0
    for size in [BATCH] * (runs // BATCH) + ([runs % BATCH] if runs % BATCH else []):
        scans = []
        for period in PERIODS:
            sd = rng.uniform(POS_SD_MIN, POS_SD_MAX)
            R = sd**2 * np.array([[1.0, 0.3], [0.3, 1.0]])
            scans += [(t, R) for t in np.arange(rng.uniform(0, period), duration, period)]
        scans.sort(key=lambda s: s[0])
        speed, heading = rng.uniform(*SPEED, size), rng.uniform(-np.pi, np.pi, size)
        v = np.column_stack([speed * np.cos(heading), speed * np.sin(heading)])

        t, R = scans[0]
        z = straight_states(v, t) @ H.T + rng.multivariate_normal([0.0, 0.0], R, size)
        P0 = np.zeros((4, 4))
        P0[np.ix_([0, 2], [0, 2])] = R
        P0[1, 1] = P0[3, 3] = MttConfig().init_velocity_std ** 2
        x, P = z @ H, np.broadcast_to(P0, (size, 4, 4)).copy()  # a start: position from z, velocity 0
        inside, shown = np.zeros(size), 0
        picture = float(np.ceil(max(t, warm)))
        for t_next, R in scans[1:]:
            while picture <= t_next:
                xp, Pp = predict_batch(x, P, picture - t, q)
                e = straight_states(v, picture) - xp
                d = nees(e, Pp)
                inside += (d >= lo) & (d <= hi)
                below += int(np.sum(d < lo))
                err_v += float(np.sum(e[:, [1, 3]] ** 2))
                var_v += float(np.sum(Pp[:, 1, 1] + Pp[:, 3, 3]))
                picture, shown = picture + 1.0, shown + 1
            x, P = predict_batch(x, P, t_next - t, q)
            t = t_next
            z = straight_states(v, t) @ H.T + rng.multivariate_normal([0.0, 0.0], R, size)
            post, _ = update(GaussianState(x, P), z, H, R)
            seen = rng.uniform(size=size) < pd
            x, P = np.where(seen[:, None], post.x, x), np.where(seen[:, None, None], post.P, P)
        fractions.append(inside.mean() / shown)
        pairs += shown * size
    se = float(np.std(fractions, ddof=1) / np.sqrt(len(fractions))) if len(fractions) > 1 else float("nan")
    return StraightNees(q, float(np.mean(fractions)), se, below / pairs, err_v / var_v)


def main(argv: list[str] | None = None) -> int:
    """``python -m fedtrack.experiments.nees_straight``: the table of :data:`QS`."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=400, help="straight legs per q (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: %(default)s)")
    args = parser.parse_args(argv)
    rows = [straight_nees(q, args.runs, seed=args.seed) for q in QS]
    print_table(f"CV Kalman filter on straight legs: 4-dof NEES at whole-second pictures ({args.runs} runs of 200 s, "
                "after 30 s)", ["q [m^2/s^3]", "inside 95% band", "below", "E[e_v^2] / P_v"],
                [[f"{r.q:g}", f"{100 * r.inside:.1f} +- {100 * r.inside_se:.1f} %", f"{100 * r.below:.1f} %",
                  f"{r.velocity_ratio:.3f}"] for r in rows])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
