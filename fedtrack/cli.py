"""fedtrack: distributed multi-sensor target tracking and fusion over Eclipse Zenoh.

Sub-commands dispatch to functions named in the registries below (``module:function``)
and are imported lazily, so ``fedtrack --help`` stays fast and one estimator's
dependencies never slow another's start-up.
"""

from __future__ import annotations

from fedtrack.process_tuning import tune_process

tune_process()  # before numpy is imported: one BLAS thread, malloc keeps its pages

import argparse
import atexit
import importlib
import os
import sys
import threading
from pathlib import Path
from typing import Any, Callable, NoReturn

from fedtrack.config import ConfigError, seed_number
from fedtrack.jsonl import InputError, check_output_folder, check_outputs

# name -> "module:function(runs, seed, json_path, plots_dir) -> dict"
REPRODUCERS: dict[str, str] = {
    "fvdie": "fedtrack.experiments.fvdie:reproduce_fvdie",
    "vsimm": "fedtrack.experiments.vsimm:reproduce_vsimm",
    "hpda": "fedtrack.experiments.hpda:reproduce_hpda",
    "input-estimation": "fedtrack.experiments.input_estimation:reproduce_input_estimation",
    "ts-fuzzy": "fedtrack.experiments.ts_fuzzy:reproduce_ts_fuzzy",
}

# algorithm -> "module:function(measurements, config, out) -> int (lines written)"
REPLAY_ALGORITHMS: dict[str, str] = {
    "kf": "fedtrack.fusion_center.replay:replay_fusion",
    "federated-kf": "fedtrack.fusion_center.replay:replay_fusion",
    "decentralized-kf": "fedtrack.fusion_center.replay:replay_fusion",
    "fvdie": "fedtrack.fusion_center.replay:replay_fusion",
    "dvdie": "fedtrack.fusion_center.replay:replay_fusion",
    "fsimm": "fedtrack.local_filters.imm.replay:replay_imm",
    "vsimm": "fedtrack.local_filters.imm.replay:replay_imm",
    "ao-vsimm": "fedtrack.local_filters.imm.replay:replay_imm",
    "pda-ai": "fedtrack.local_filters.pda.replay:replay_pda",
    "hpda": "fedtrack.local_filters.pda.replay:replay_pda",
    "ekf": "fedtrack.local_filters.radar.replay:replay_radar",
    "ekf-ie": "fedtrack.local_filters.radar.replay:replay_radar",
    "ekf-tsfuzzy": "fedtrack.local_filters.radar.replay:replay_radar",
    "mtt-local": "fedtrack.fusion_center.mtt.replay:replay_mtt",
    "mtt-centralized": "fedtrack.fusion_center.mtt.replay:replay_mtt",
    "mtt-federated": "fedtrack.fusion_center.mtt.replay:replay_mtt",
    "mtt-decentralized": "fedtrack.fusion_center.mtt.replay:replay_mtt",
}

# replay option -> the algorithms that take it
REPLAY_OPTIONS: dict[str, tuple[str, ...]] = {
    "period": ("mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized"),
    "sensor": ("mtt-local",),
    "regions": ("mtt-federated", "mtt-decentralized"),
    "status": ("pda-ai", "hpda"),
}

# role -> "module:function(argv) -> int"
SERVICES: dict[str, str] = {
    "router": "fedtrack.services.router:main",
    "sensor": "fedtrack.sensors.service:main",
    "local-filter": "fedtrack.local_filters.service:main",
    "fusion-center": "fedtrack.fusion_center.service:main",
    "recorder": "fedtrack.services.recorder:main",
    "imm": "fedtrack.local_filters.imm.service:main",
    "hpda": "fedtrack.local_filters.pda.service:main",
    "mtt-local": "fedtrack.local_filters.mtt.service:main",
    "mtt-centre": "fedtrack.fusion_center.mtt.service:main",
    "picture": "fedtrack.fusion_center.mtt.picture_merge:main",
}

# name -> "module:function(argv) -> int"
TRAINERS: dict[str, str] = {
    "ts-fuzzy": "fedtrack.experiments.ts_fuzzy:main",
}

# name -> "module:function(argv) -> int"
SIMULATORS: dict[str, str] = {
    "multitarget": "fedtrack.sensors.multitarget:main",
    "traffic": "fedtrack.sensors.traffic:main",
}

COMMANDS: dict[str, str] = {
    "evaluate": "fedtrack.fusion_center.mtt.evaluation.cli:main",
    "demo": "fedtrack.deploy.demo:main",
    "launch": "fedtrack.deploy.launcher:main",
    "bench": "fedtrack.benchmarks.suites:main",
    "export": "fedtrack.geojson:export_main",
}


def resolve(target: str) -> Callable[..., Any]:
    """Import ``module:function``; a missing module is a clear error, not a traceback."""
    module_name, func_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and module_name.startswith(exc.name):
            raise SystemExit(f"fedtrack: {module_name} is not available in this build") from exc
        raise
    return getattr(module, func_name)


def _cmd_reproduce(args: argparse.Namespace) -> int:
    check_outputs({"--json": args.json}, {"--model": args.model})  # before minutes of Monte Carlo
    if args.runs < 2:
        raise InputError(f"--runs: must be at least 2 (standard errors need two runs), got {args.runs}")
    if args.runs > sys.maxsize:  # numpy's largest array dimension (intp); fewer that do not fit in memory: MemoryError
        raise InputError(f"--runs: at most {sys.maxsize} (the largest array dimension), got {args.runs}")
    if args.plots:  # created by the reproduction as it plots, at its end: a Ctrl-C before left it empty (tour61)
        check_output_folder(args.plots)
    fn = resolve(REPRODUCERS[args.name])
    extra = {"model": Path(args.model)} if args.model else {}
    result = fn(runs=args.runs, seed=args.seed, json_path=Path(args.json),
                plots_dir=Path(args.plots) if args.plots else None, **extra)
    print(f"wrote {args.json} ({result.get('runs', args.runs)} runs, "
          f"{result.get('wall_time_s', float('nan')):.1f} s)")
    return 0


def check_config(path: str | Path | None) -> None:
    """Check every table of the configuration file, whichever command reads which tables, so
    that a typo anywhere fails the same way everywhere (``FILE: unknown config key imm.foo``)."""
    if path is not None:
        resolve("fedtrack.deploy.settings:load_settings")(Path(path))


def _config_arg(argv: list[str]) -> str | None:
    """The value of ``--config`` in a sub-command's own arguments (None if absent)."""
    for i, arg in enumerate(argv):
        if arg == "--config" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--config="):
            return arg.split("=", 1)[1]
    return None


def replay_unit(algorithm: str) -> str:
    """What one line of ``algorithm``'s replay output is: multi-target pictures, the sonar trackers'
    track lines, every other algorithm's estimates."""
    if algorithm.startswith("mtt-"):
        return "pictures"
    return "track lines" if algorithm in REPLAY_OPTIONS["status"] else "estimates"


def _cmd_replay(args: argparse.Namespace) -> int:
    check_outputs({"--out": args.out}, {"--measurements": args.measurements, "--config": args.config})
    check_config(args.config)
    fn = resolve(REPLAY_ALGORITHMS[args.algorithm])
    options = {k: v for k, v in (("period", args.period), ("sensor", args.sensor), ("status", args.status),
                                                   ("regions", args.regions))
               if v is not None}
    for key in options:
        if args.algorithm not in REPLAY_OPTIONS[key]:
            raise ConfigError(f"--{key} applies to {', '.join(REPLAY_OPTIONS[key])} only")
    n = fn(algorithm=args.algorithm, measurements=Path(args.measurements),
           config=Path(args.config) if args.config else None, out=Path(args.out), **options)
    print(f"wrote {n} {replay_unit(args.algorithm)} to {args.out}")
    return 0


def version() -> str:
    """``fedtrack X.Y.Z (zenoh A.B.C, Python D.E.F)``."""
    import importlib.metadata  # only here: 50 ms of start-up for every other command

    def of(dist: str) -> str:
        try:
            return importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return "not installed"
    return (f"fedtrack {of('fedtrack')} (eclipse-zenoh {of('eclipse-zenoh')}, "
            f"Python {sys.version.split()[0]})")


class _VersionAction(argparse.Action):
    """``--version``: prints :func:`version`, looked up only when asked for."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="show the versions of fedtrack, zenoh and Python, and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(version())
        sys.stdout.flush()  # a closed pipe is noticed in main, not at exit
        parser.exit()


def _registry_parser(sub: Any, name: str, help_text: str, key: str, registry: dict[str, str],
                     what: str) -> None:
    """``fedtrack NAME KEY ...``: the rest of the command line goes to the registered entry point.

    ``fedtrack NAME --help`` lists the choices; ``fedtrack NAME KEY --help`` is the entry's own help.
    """
    listing = "\n".join(f"  {entry}" for entry in sorted(registry))
    p = sub.add_parser(name, help=help_text, description=help_text, add_help=False,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=f"{what}s:\n{listing}\n\n'fedtrack {name} {key.upper()} --help' shows the "
                              f"options of one {what}.")
    p.add_argument(key, nargs="?", choices=sorted(registry), metavar=key.upper(), help=f"the {what} (listed below)")
    p.add_argument("-h", "--help", action="store_true", help="show this help message and exit")
    p.set_defaults(func=None, registry=registry, key=key, parser=p)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fedtrack", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    rep = sub.add_parser("reproduce", help="seeded Monte Carlo reproduction of a paper")
    rep.add_argument("name", choices=sorted(REPRODUCERS), metavar="NAME",
                     help=f"the paper's experiment: {', '.join(sorted(REPRODUCERS))}")
    rep.add_argument("--runs", type=int, default=500, help="Monte Carlo runs, at least 2 (default: %(default)s)")
    rep.add_argument("--seed", type=seed_number, default=1, help="random seed (default: %(default)s)")
    rep.add_argument("--json", required=True, metavar="PATH", help="output JSON file (its folder must exist)")
    rep.add_argument("--plots", metavar="DIR", help="folder for PNG figures (created if missing; its own folder "
                     "must exist; default: no figures)")
    rep.add_argument("--model", metavar="PATH", help="ts-fuzzy only: a trained model (fedtrack train ts-fuzzy --out "
                     "PATH) instead of training one, which takes minutes (default: $FEDTRACK_TS_FUZZY_MODEL, else "
                     "train one)")
    rep.set_defaults(func=_cmd_reproduce)

    rpl = sub.add_parser("replay", help="run an estimator over recorded measurements (JSON Lines)",
                         description="run an estimator over recorded measurements (JSON Lines in, JSON Lines out)")
    rpl.add_argument("--algorithm", required=True, choices=sorted(REPLAY_ALGORITHMS), metavar="NAME",
                     help=f"the estimator: {', '.join(REPLAY_ALGORITHMS)}")
    rpl.add_argument("--measurements", required=True, metavar="PATH",
                     help="measurements, one JSON object a line (formats: README, docs/)")
    rpl.add_argument("--config", metavar="TOML", help="configuration file (default: every table's defaults)")
    rpl.add_argument("--out", required=True, metavar="PATH",
                     help="output JSON Lines: estimates, track lines (pda-ai, hpda) or pictures (mtt-*); written "
                          "whole or not at all; its folder must exist")
    rpl.add_argument("--period", type=float, metavar="S",
                     help="mtt-*: seconds between track pictures (default: [mtt] period, 1.0)")
    rpl.add_argument("--sensor", metavar="ID", help="mtt-local (required there): the sensor whose tracker runs, "
                     "e.g. s1 or r3 as simulate multitarget names them (default: none)")
    rpl.add_argument("--regions", metavar="SPEC",
                     help="mtt-federated, mtt-decentralized: a centre per region, tracks handed over at the "
                          "borders; SPEC NXxNY (a grid over the detections' extent, e.g. 2x2) or config "
                          "(the config's [regions]; also the replay of a live region run's recording, each "
                          "centre in its recorded order); docs/multitarget.md#regions (default: one centre)")
    rpl.add_argument("--status", choices=("all", "confirmed"),
                     help="pda-ai, hpda: write every track or the confirmed ones only (default: all)")
    rpl.set_defaults(func=_cmd_replay)

    _registry_parser(sub, "serve", "run one service process", "role", SERVICES, "role")
    _registry_parser(sub, "train", "train a learned component", "name", TRAINERS, "trainer")
    _registry_parser(sub, "simulate", "simulate a scenario to replay", "scenario", SIMULATORS, "scenario")

    for name, help_text in (("demo", "the main job: a whole deployment on one machine"),
                            ("launch", "start every service of a deployment config"),
                            ("bench", "benchmarks (ratios measured side by side)"),
                            ("export", "a recording database's measurements as replay input; --geojson: tracks "
                                       "and truth on the Earth"),
                            ("evaluate", "GOSPA, OSPA, id switches, RMSE and NEES of track pictures against truth")):
        p = sub.add_parser(name, help=help_text, add_help=False)
        p.set_defaults(func=None, registry=COMMANDS, key=None)
    return parser


def _dispatch(parser: argparse.ArgumentParser, args: argparse.Namespace, rest: list[str]) -> int:
    """Run the sub-command ``args`` names with the rest of the command line."""
    if args.func is not None:
        if rest:
            parser.error(f"unrecognized arguments: {' '.join(rest)}")
        if getattr(args, "model", None) and args.name != "ts-fuzzy":
            parser.error("--model applies to reproduce ts-fuzzy only")
        return int(args.func(args) or 0)
    if args.key is None:
        return int(resolve(args.registry[args.command])(rest) or 0)
    choice = getattr(args, args.key)
    if choice is None:
        if args.help:
            args.parser.print_help()
            return 0
        args.parser.error(f"the following arguments are required: {args.key.upper()}")
    if args.help:
        rest = [*rest, "--help"]
    elif args.command == "serve":
        check_config(_config_arg(rest))
    return int(resolve(args.registry[choice])(rest) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    try:
        args, rest = parser.parse_known_args(argv)  # --version prints here
        code = _dispatch(parser, args, rest)
        sys.stdout.flush()  # here, so that a closed pipe is noticed below rather than at exit
        return code
    except (ConfigError, InputError) as exc:
        print(f"fedtrack: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return _closed_pipe()
    except OSError as exc:
        if exc.filename is None:
            raise
        # a file that cannot be opened, read or written
        print(f"fedtrack: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:  # options asking for more than the machine has: a traceback before the tour60 session
        print(f"fedtrack: error: out of memory: {exc or 'an allocation failed'} (ask for less: fewer --runs, "
              "--targets or seconds of data)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def _closed_pipe() -> int:
    """The reader of standard output went away (``fedtrack evaluate ... | head -2``): end quietly
    with 141 (128 + SIGPIPE, a shell's status for a command a closed pipe stopped). Standard output
    is pointed at /dev/null so that the interpreter's final flush does not complain again."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 141


def run() -> NoReturn:
    """The ``fedtrack`` command (the console script, ``python -m fedtrack.cli``): :func:`main`, then the
    process's exit. A ``serve`` process whose service has stopped (final Health sent, session closed,
    ``stopped`` logged) exits as Python would, but for the teardown of its modules: it waits for its
    non-daemon threads (zenoh-python runs Python callbacks on such threads, which end once their
    subscriber is gone), runs Python's exit handlers (``logging.shutdown`` among them), flushes the
    standard streams and ends with ``os._exit``. The teardown of numpy, scipy and the rest took about
    0.1 s of CPU a process, 1-3 s of wall time at load average 10-14, and outlived the launcher's stop
    grace under heavier load (docs/deploy.md, "Stopping")."""
    code = main()
    if sys.argv[1:2] != ["serve"]:
        sys.exit(code)
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or gone: nothing left to write
            pass
    os._exit(code)


if __name__ == "__main__":
    run()
