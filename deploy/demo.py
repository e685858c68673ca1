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
from fedtrack.deploy.report import finish
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import MODES, DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.scenarios import DEFAULT_R


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
    finish(out, settings, report, out / "config.toml", "fedtrack demo")
    if failure is not None:
        print(f"fedtrack demo: {failure}", file=sys.stderr)
        return 1
    return 0
