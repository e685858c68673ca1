"""fedtrack demo: the whole deployment on this machine, then a summary.

Router, N sensors, their local filters, the fusion center and the recorder run as
separate processes over Zenoh on loopback (paper 004 scenario, lockstep pacing). The
output directory receives ``measurements.jsonl``, ``tracks.jsonl``, ``truth.jsonl``,
``summary.json``, ``config.toml`` (the effective configuration: ``fedtrack replay
--algorithm fvdie --config DIR/config.toml --measurements DIR/measurements.jsonl``
reproduces ``tracks.jsonl``), ``tracks.png`` and the services' logs under ``logs/``.

``--scenario multitarget``: the live multi-target deployment of :mod:`fedtrack.deploy.multitarget`
instead (20 targets, three position sensors with periods 1.0, 0.7 and 1.3 s, clutter, 60 s of
scenario at 5x real time); ``fedtrack replay --algorithm mtt-federated --config DIR/config.toml
--measurements DIR/measurements.jsonl`` reproduces its ``tracks.jsonl``.
"""

from __future__ import annotations

import argparse
import socket
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from fedtrack.config import to_toml
from fedtrack.deploy.launcher import (
    LaunchError,
    ServiceFailed,
    run_deployment,
)
from fedtrack.deploy.multitarget import finish_multitarget
from fedtrack.deploy.report import finish
from fedtrack.deploy.settings import MultitargetSettings, Settings
from fedtrack.deployment import MODES, DeploymentConfig, SensorConfig
from fedtrack.jsonl import output_folder
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.multitarget import Scenario, clutter_density, parse_spec
from fedtrack.sensors.scenarios import DEFAULT_R

MULTITARGET_SPEED = 5.0  # the live multi-target demo runs at 5x real time


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


def multitarget_settings(mode: str, seed: int, port: int, out: Path) -> Settings:
    """A live multi-target deployment of the default scenario (``mode`` federated or decentralized),
    with maneuver handling (maneuver events per central track)."""
    mt = MultitargetSettings(algorithm=f"mtt-{mode}")
    specs = parse_spec(mt.sensors)
    scenario = Scenario(targets=mt.targets, duration=mt.duration, pd=mt.pd, clutter=mt.clutter)
    return Settings(
        deployment=DeploymentConfig(name="demo", mode=mode, seed=seed, pacing="realtime", speed=MULTITARGET_SPEED,
                                    router_listen=f"tcp/127.0.0.1:{port}", out=str(out)),
        mtt=MttConfig(pd=mt.pd, clutter_density=clutter_density(specs[0], scenario),
                      sensors=tuple(s.id for s in specs), maneuver="vdie"),
        multitarget=mt)


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


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("fedtrack-out"),
                        help="output folder (created if missing; its own folder must exist; default: %(default)s)")
    parser.add_argument("--sensors", type=int, default=2, help="number of sensors (default 2)")
    parser.add_argument("--scenario", choices=("1", "2", "multitarget"), default="1",
                        help="paper 004 scenario 1 or 2, or the live multi-target deployment (default 1)")
    parser.add_argument("--mode", choices=MODES, default="federated",
                        help="federated (FVDIE, reset feedback) or decentralized (DVDIE; default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="seed of truth and noise (default: %(default)s)")
    parser.add_argument("--port", type=int, help="router port on 127.0.0.1 (default: a free one)")
    args = parser.parse_args(argv)
    if not 1 <= args.sensors <= 32:
        parser.error("--sensors must be between 1 and 32")
    out = output_folder(args.out).resolve()
    port = args.port or free_port()
    if args.scenario == "multitarget":
        settings = multitarget_settings(args.mode, args.seed, port, out)
        what = f"multitarget, {settings.multitarget.targets} targets, sensors {settings.multitarget.sensors}"  # type: ignore[union-attr]
    else:
        settings = demo_settings(args.sensors, int(args.scenario), args.mode, args.seed, port, out)
        what = f"{args.sensors} sensors, scenario {args.scenario}"
    write_config(settings, out / "config.toml")
    print(f"fedtrack demo: {what}, {args.mode}; output in {out}", file=sys.stderr)
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
    if settings.multitarget is not None:
        finish_multitarget(out, report, "fedtrack demo", settings)
    else:
        finish(out, settings, report, out / "config.toml", "fedtrack demo")
    if failure is not None:
        print(f"fedtrack demo: {failure}", file=sys.stderr)
        return 1
    return 0
