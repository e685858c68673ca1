"""fedtrack demo: the whole deployment on this machine, then a summary.

Router, N sensors, their local filters, the fusion center and the recorder run as
separate processes over Zenoh on loopback (paper 004 scenario, lockstep pacing). The
output directory receives ``measurements.jsonl``, ``tracks.jsonl``, ``truth.jsonl``,
``summary.json``, ``config.toml`` (the effective configuration: ``fedtrack replay
--algorithm fvdie --config DIR/config.toml --measurements DIR/measurements.jsonl``
reproduces ``tracks.jsonl``), ``tracks.png`` and the services' logs under ``logs/``.

``--scenario traffic [--source FILE]``: the same live deployment on recorded air traffic (600 s of
the committed Paris extract at 10x real time, two radars and a position sensor, docs/geodetic.md);
``tracks.png`` is then a longitude / latitude map, ``gospa.png`` GOSPA over time, and
``tracks.geojson`` the tracks and truth as GeoJSON.

Every link is mutual TLS with the router's access control (:mod:`fedtrack.deploy.security`;
certificates made on first use in ``OUT/certs/``, the per-service Zenoh files in ``OUT/zenoh/``),
every scenario; ``--insecure``: plain TCP, as before this default.

``--scenario multitarget``: the live multi-target deployment of :mod:`fedtrack.deploy.multitarget`
instead (20 targets, three position sensors with periods 1.0, 0.7 and 1.3 s, clutter, 60 s of
scenario at 5x real time); ``fedtrack replay --algorithm mtt-federated --config DIR/config.toml
--measurements DIR/measurements.jsonl`` reproduces its ``tracks.jsonl``.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from fedtrack.config import ConfigError, load_toml, parse_dataclass, seed_number, to_toml
from fedtrack.deploy.launcher import (
    LaunchError,
    ServiceFailed,
    Stopped,
    run_deployment,
)
from fedtrack.deploy.multitarget import SCENARIO_DIR, finish_multitarget, prepare
from fedtrack.deploy.report import finish, unrecorded
from fedtrack.deploy.security import ZenohSettings
from fedtrack.deploy.settings import MultitargetSettings, Settings
from fedtrack.deployment import MODES, DeploymentConfig, SensorConfig, port_in_use
from fedtrack.geodetic import FrameConfig
from fedtrack.jsonl import InputError, check_output_folder, output_folder
from fedtrack.local_filters.mtt.config import MttConfig, SensorOverride
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.sensors.multitarget import Scenario, clutter_density, parse_spec
from fedtrack.sensors.scenarios import DEFAULT_R
from fedtrack.sensors.state_vectors import UNITS, read_recording
from fedtrack.sensors.traffic import window_origin

MULTITARGET_SPEED = 5.0  # the live multi-target demo runs at 5x real time
# the live recorded-traffic demo: 600 s of the committed Paris extract at 10x real time (docs/geodetic.md)
TRAFFIC_EXTRACT = Path(__file__).resolve().parents[1] / "tests" / "data" / "traffic_paris.csv.gz"
TRAFFIC_SENSORS = "radar:4@49.2/2.0/100,radar:5@48.6/2.9/100,pos:2"
TRAFFIC_SPEED, TRAFFIC_DURATION, TRAFFIC_BOX, TRAFFIC_START = 10.0, 600.0, 150.0, 60.0
CERTS = "certs"  # the demo's certificates, in its output directory (made on first use)


def free_port() -> int:
    """A free TCP port on loopback (bind to port 0 and read it back)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def transport(port: int, tls_dir: Path | None) -> tuple[str, ZenohSettings]:
    """The router endpoint on loopback and the ``[zenoh]`` table: mutual TLS and access control with
    the certificates in ``tls_dir`` (made on first use), or plain TCP when ``tls_dir`` is None."""
    if tls_dir is None:
        return f"tcp/127.0.0.1:{port}", ZenohSettings()
    return f"tls/127.0.0.1:{port}", ZenohSettings(tls_dir=str(tls_dir))


def demo_settings(n_sensors: int, scenario: int, mode: str, seed: int, port: int, out: Path,
                  tls_dir: Path | None = None) -> Settings:
    """The paper 004 deployment of ``fedtrack demo`` (``tls_dir``: see :func:`transport`)."""
    ids = tuple(str(i + 1) for i in range(n_sensors))
    r = tuple(tuple(row) for row in DEFAULT_R.tolist())
    endpoint, zenoh = transport(port, tls_dir)
    return Settings(
        fusion=FusionConfig(sensors=ids),
        deployment=DeploymentConfig(name="demo", mode=mode, scenario=scenario, seed=seed, pacing="lockstep",
                                    router_listen=endpoint, out=str(out)),
        sensor=tuple(SensorConfig(id=i, R=r) for i in ids),  # type: ignore[arg-type]
        zenoh=zenoh,
    )


def multitarget_settings(mode: str, seed: int, port: int, out: Path, tls_dir: Path | None = None) -> Settings:
    """A live multi-target deployment of the default scenario (``mode`` federated or decentralized),
    with maneuver handling (maneuver events per central track; ``tls_dir``: see :func:`transport`) and each
    sensor's noise floor as ``simulate multitarget`` declares it (simulated here first, as the launch does
    again into ``OUT/scenario``)."""
    mt = MultitargetSettings(algorithm=f"mtt-{mode}")
    specs = parse_spec(mt.sensors)
    scenario = Scenario(targets=mt.targets, duration=mt.duration, pd=mt.pd, clutter=mt.clutter)
    prepare(Settings(deployment=DeploymentConfig(seed=seed), multitarget=mt), out, say=False)
    declared = load_toml(out / SCENARIO_DIR / "config.toml")["mtt"].get("sensor", {})
    endpoint, zenoh = transport(port, tls_dir)
    return Settings(
        deployment=DeploymentConfig(name="demo", mode=mode, seed=seed, pacing="realtime", speed=MULTITARGET_SPEED,
                                    router_listen=endpoint, out=str(out)),
        mtt=MttConfig(pd=mt.pd, clutter_density=clutter_density(specs[0], scenario),
                      sensors=tuple(s.id for s in specs), maneuver="vdie",
                      sensor={sid: parse_dataclass(SensorOverride, table, f"mtt.sensor.{sid}")
                              for sid, table in declared.items()}),
        multitarget=mt, zenoh=zenoh)


def traffic_settings(source: Path | None, mode: str, seed: int, port: int, out: Path,
                     tls_dir: Path | None = None, units: str = "si") -> Settings:
    """A live deployment on recorded air traffic: without ``source``, the committed Paris extract with
    two radars and a position sensor (docs/geodetic.md); with it, the median position of the recording's
    airborne samples in the demo's window as the origin (:func:`~fedtrack.sensors.traffic.window_origin`) and radars
    on the box's edge. The tracker keys are the ones ``simulate traffic`` derives,
    simulated here first (the launch simulates the same again into ``OUT/scenario``; ``tls_dir``: see
    :func:`transport`)."""
    if source is None:
        source, origin, sensors = TRAFFIC_EXTRACT, (48.86, 2.40, 0.0), TRAFFIC_SENSORS
        if not source.is_file():
            raise InputError(f"{source}: the committed extract is not here (a source checkout has it under "
                             "tests/data/); give --source FILE")
    else:
        rec = read_recording(source, units)
        origin = tuple(window_origin(rec, TRAFFIC_START, TRAFFIC_DURATION))
        sensors = "radar:4,radar:5,pos:2"
    mt = MultitargetSettings(algorithm=f"mtt-{mode}", sensors=sensors, duration=TRAFFIC_DURATION, source=str(source),
                             origin=origin, box=TRAFFIC_BOX, start=TRAFFIC_START, units=units)
    draft = Settings(deployment=DeploymentConfig(seed=seed), multitarget=mt)
    prepare(draft, out, say=False)  # the launch simulates it again and says what it left out
    table = load_toml(out / SCENARIO_DIR / "config.toml")
    endpoint, zenoh = transport(port, tls_dir)
    return Settings(
        deployment=DeploymentConfig(name="demo", mode=mode, seed=seed, pacing="realtime", speed=TRAFFIC_SPEED,
                                    router_listen=endpoint, out=str(out)),
        mtt=parse_dataclass(MttConfig, table["mtt"], "mtt"), multitarget=mt,
        frame=parse_dataclass(FrameConfig, table["frame"], "frame"), zenoh=zenoh)


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
    parser.add_argument("--sensors", type=int, help="scenario 1 or 2: number of sensors, 1-32 (default 2; the "
                        "multitarget and traffic scenarios have their own sensor sets)")
    parser.add_argument("--scenario", choices=("1", "2", "multitarget", "traffic"), default="1",
                        help="paper 004 scenario 1 or 2, the live multi-target deployment, or the live deployment "
                             "on recorded air traffic (default: %(default)s)")
    parser.add_argument("--source", type=Path, help="traffic: a recording (simulate traffic's input; default: the "
                        "committed Paris extract)")
    parser.add_argument("--units", choices=sorted(UNITS), default="si",
                        help="traffic: the units of --source, as simulate traffic --units (si: m, m/s; aviation: "
                             "ft, kt, ft/min, the traffic library's; default: %(default)s)")
    parser.add_argument("--mode", choices=MODES, default="federated",
                        help="federated (FVDIE, reset feedback; multitarget, traffic: mtt-federated) or "
                             "decentralized (DVDIE; mtt-decentralized; default: %(default)s)")
    parser.add_argument("--seed", type=seed_number, default=1, help="seed of truth and noise (default: %(default)s)")
    parser.add_argument("--port", type=int, help="router port on 127.0.0.1 (default: a free one)")
    parser.add_argument("--insecure", action="store_true",
                        help="plain TCP without authentication (default: mutual TLS and access control, "
                             f"certificates made on first use in OUT/{CERTS})")
    args = parser.parse_args(argv)
    if args.sensors is not None and args.scenario in ("multitarget", "traffic"):
        parser.error(f"--sensors applies to --scenario 1 or 2 only ({args.scenario} has its own sensor set)")
    args.sensors = 2 if args.sensors is None else args.sensors
    if not 1 <= args.sensors <= 32:
        parser.error(f"--sensors must be between 1 and 32, got {args.sensors}")
    if (args.source is not None or args.units != "si") and args.scenario != "traffic":
        parser.error("--source and --units apply to --scenario traffic only")
    if args.units != "si" and args.source is None:  # it would read the committed extract in the wrong units
        parser.error("--units applies to --source FILE only (the committed Paris extract is in si units)")
    if args.port is not None and not 1 <= args.port <= 65535:
        parser.error(f"--port must be in 1-65535, got {args.port}")
    if args.port is not None and port_in_use(f"tcp/127.0.0.1:{args.port}"):  # was named as OUT/config.toml's
        parser.error(f"--port: {args.port} is already in use")  # router_listen, with that file left behind
    made = not check_output_folder(args.out).is_dir()
    out = output_folder(args.out).resolve()
    port = args.port or free_port()
    tls_dir = None if args.insecure else Path(CERTS)  # relative to OUT/config.toml
    if args.scenario == "traffic":
        try:
            settings = traffic_settings(args.source, args.mode, args.seed, port, out, tls_dir, args.units)
        except (InputError, ConfigError):
            if made:  # a recording that cannot be read leaves nothing behind
                shutil.rmtree(out)
            raise
        what = f"recorded traffic from {settings.multitarget.source}, sensors {settings.multitarget.sensors}"  # type: ignore[union-attr]
    elif args.scenario == "multitarget":
        settings = multitarget_settings(args.mode, args.seed, port, out, tls_dir)
        what = f"multitarget, {settings.multitarget.targets} targets, sensors {settings.multitarget.sensors}"  # type: ignore[union-attr]
    else:
        settings = demo_settings(args.sensors, int(args.scenario), args.mode, args.seed, port, out, tls_dir)
        what = f"{args.sensors} sensors, scenario {args.scenario}"
    what += ", plain TCP (--insecure)" if args.insecure else ", mutual TLS and access control"
    write_config(settings, out / "config.toml")
    print(f"fedtrack demo: {what}, {args.mode}, router {settings.deployment.router_listen} (deployment "
          f"{settings.deployment.name}); output in {out}", file=sys.stderr)
    failure, code = None, None
    try:
        report = run_deployment(settings, out / "config.toml", out, title="fedtrack demo")
    except KeyboardInterrupt as exc:
        print("fedtrack demo: stopped; every service was shut down", file=sys.stderr)
        if not isinstance(exc, Stopped):  # before any service started (the scenario being simulated)
            return 130
        report, code = exc.report, 130  # as launch: the summary of what ran (before the tour60 session, none)
    except ServiceFailed as exc:  # the scenario ran to its end without some service
        report, failure = exc.report, str(exc)
    except LaunchError as exc:
        print(f"fedtrack demo: {exc}", file=sys.stderr)
        return 1
    if settings.multitarget is not None:
        summary = finish_multitarget(out, report, "fedtrack demo", settings)
    else:
        summary = finish(out, settings, report, out / "config.toml", "fedtrack demo")
    if code is not None:
        return code
    if unrecorded(summary):
        failure = failure or "what the live run produced is not all in the recording"
    if failure is not None:
        print(f"fedtrack demo: {failure}", file=sys.stderr)
        return 1
    return 0
