"""``fedtrack evaluate``: the command line over :func:`~.scoring.evaluate`, its figure and its map."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from fedtrack.fusion_center.mtt.earthmap import plot_map
from fedtrack.fusion_center.mtt.evaluation.consistency import MANEUVER_ACCEL, STRAIGHT_ACCEL, STRAIGHT_FOR_S, nees_line
from fedtrack.fusion_center.mtt.evaluation.figures import check_figure_format, plot
from fedtrack.fusion_center.mtt.evaluation.metrics import MAX_POWER_EXPONENT
from fedtrack.fusion_center.mtt.evaluation.registration import registration_line
from fedtrack.fusion_center.mtt.evaluation.scoring import evaluate
from fedtrack.geodetic import load_frame
from fedtrack.jsonl import check_outputs, output_file
from fedtrack.local_filters.regions import load_regions


def main(argv: list[str]) -> int:
    """``fedtrack evaluate``: score a track picture file against truth (the package's docstring)."""
    parser = argparse.ArgumentParser(prog="fedtrack evaluate", description="GOSPA, OSPA, id switches, "
                                     "fragmentations, RMSE, NEES and maneuver flags of a track picture file against "
                                     "truth")
    parser.add_argument("--tracks", required=True, type=Path, metavar="T.jsonl",
                        help="track pictures ({\"t\", \"tracks\": [...]} a line, as replay --algorithm mtt-* writes)")
    parser.add_argument("--truth", required=True, type=Path, metavar="U.jsonl",
                        help="truth ({\"t\", \"targets\": [...]} a line, as simulate multitarget writes)")
    parser.add_argument("--c", type=float, default=100.0, help="cut-off distance [m] (default: %(default)s)")
    parser.add_argument("--p", type=float, default=2.0, help="order (default: %(default)s)")
    parser.add_argument("--alpha", type=float, default=2.0, help="GOSPA alpha; only 2 is supported "
                        "(default: %(default)s)")
    parser.add_argument("--all-tracks", action="store_true", help="evaluate tentative tracks too "
                        "(default: confirmed tracks only)")
    parser.add_argument("--horizontal", action="store_true", help="GOSPA, OSPA and RMSE on x, y only (the "
                        "altitude error is reported on its own either way; default: every axis the states share)")
    parser.add_argument("--json", type=Path, metavar="OUT.json",
                        help="write the full result (with the per-picture series; default: none)")
    parser.add_argument("--plot", type=Path, metavar="OUT.png",
                        help="PNG: tracks over truth and GOSPA over time (default: no plot)")
    parser.add_argument("--config", type=Path, metavar="C.toml", help="with --plot: a config whose [frame] puts the "
                        "tracks on the Earth; the map (longitude / latitude, sensor sites marked) goes to PLOT's "
                        "name + -map.png; whose [regions] draws the region borders and the tracks' hand-overs on "
                        "the plot (default: none, no map, no borders)")
    parser.add_argument("--label", help="the plot title's algorithm (default: the tracks file's \"algorithm\")")
    args = parser.parse_args(argv)
    if args.alpha != 2:
        parser.error("--alpha: only alpha = 2 (the decomposable GOSPA) is supported")
    if not (0 < args.c < math.inf and 1 <= args.p < math.inf):
        parser.error("--c must be finite and > 0, --p finite and >= 1")
    if args.p * math.log10(args.c) >= MAX_POWER_EXPONENT:
        parser.error(f"--c {args.c:g} --p {args.p:g}: c^p overflows (the p-th power parts are sums of up to c^p a "
                     f"target or track): need p log10(c) < {MAX_POWER_EXPONENT}")
    map_name = args.plot.with_name(args.plot.stem + "-map.png") if args.plot is not None and args.config else None
    check_outputs({"--json": args.json, "--plot": args.plot, "the map beside --plot": map_name},
                  {"--tracks": args.tracks, "--truth": args.truth, "--config": args.config})
    if args.plot is not None:
        check_figure_format(args.plot)
    if args.config is not None and args.plot is None:
        parser.error("--config applies with --plot (its [frame] draws the map beside the figure, its [regions] the "
                     "borders on it)")
    frame = load_frame(args.config)  # before the evaluation: a bad config fails at start
    regions = load_regions(args.config)
    result = evaluate(args.tracks, args.truth, args.c, args.p, args.all_tracks, args.horizontal)
    map_png = map_name if frame is not None else None
    if args.json:  # the files first: a reader that stops early (| head) does not cost them
        with output_file(args.json) as fh:
            fh.write(json.dumps(result))
    if args.plot:
        plot(result, args.tracks, args.truth, args.plot, label=args.label, regions=regions)
    if map_png is not None:
        plot_map(args.tracks, args.truth, frame, map_png, label=args.label or result["algorithm"])
    m = result["mean"]
    print(f"pictures {result['pictures']} (without truth: {result['pictures_without_truth']})"
          + (f" of {result['algorithm']}" if result["algorithm"] else ""))
    print(f"mean GOSPA {m['gospa']:.2f} m (c = {args.c:g}, p = {args.p:g}, alpha = 2"
          f"{', x-y' if args.horizontal else ''}): localisation "
          f"{m['localisation']:.1f}, missed {m['missed']:.1f}, false {m['false']:.1f} (p-th power parts)")
    print(f"mean OSPA {m['ospa']:.2f} m; id switches {result['id_switches']}; fragmentations "
          f"{result['fragmentations']}")
    rmse = result["position_rmse"]
    print(f"position RMSE {rmse:.2f} m" if rmse is not None else "position RMSE -")
    for row in result["nees"]:
        print(nees_line(row))
    if not result["nees"]:
        print("NEES -: no assigned pair with a covariance and the truth's state size")
    if result["altitude_rmse"] is not None:
        print(f"altitude error over the assigned pairs: RMSE {result['altitude_rmse']:.2f} m, mean "
              f"{result['altitude_bias']:+.2f} m (track - truth)")
    if result["altitude_unmeasured_pairs"]:
        print(f"altitude not measured (alt_measured false): {result['altitude_unmeasured_pairs']} assigned pairs "
              "scored on x, y only, left out of the altitude error")
    if result["registration"]:
        print("by supporting sensors: track pictures assigned and false; registration (track - truth = offset + "
              "time offset x velocity + rotation about the origin, least squares over the assigned pairs; "
              "docs/multitarget.md#registration-errors-untuned6-session):")
        for sensors, reg in result["registration"].items():
            print(registration_line(sensors, reg))
    man = result["maneuvers"]
    if not man["applicable"]:
        print("maneuver flags: not applicable (no maneuver detector ran: the pictures' detector is "
              f"{man['detector'] or 'not given and no track is flagged'})")
    else:
        rate = {k: "-" if man[f"flagged_while_{k}"] is None else f"{100 * man[f'flagged_while_{k}']:.1f}%"
                for k in ("maneuvering", "straight")}
        print(f"maneuver flags: {rate['maneuvering']} of {man['maneuvering_pairs']} assigned pairs while the target "
              f"accelerates (>= {MANEUVER_ACCEL:g} m/s^2), {rate['straight']} of {man['straight_pairs']} while it "
              f"moves straight (< {STRAIGHT_ACCEL:g} m/s^2 for {STRAIGHT_FOR_S:g} s); {man['onsets']} onsets")
    for path in (args.json, args.plot, map_png):
        if path is not None:
            print(f"wrote {path}")
    return 0
