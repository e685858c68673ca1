"""One configuration language: one file configures every service; errors name file, table, key;
unknown fields of every input format are errors naming ``file:line`` and the field."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from fedtrack.cli import main
from fedtrack.config import MAX_CONFIG_BYTES, ConfigError, in_file, load_tables
from fedtrack.deploy.settings import load_settings
from fedtrack.deployment import DeploymentConfig
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.local_filters.pda.config import load_config as load_pda_config
from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.radar.replay import RadarFilterSettings
from fedtrack.local_filters.regions import load_regions
from fedtrack.local_filters.vdie.config import PipelineSettings
from fedtrack.sensors.service import SensorSettings
from fedtrack.services.base import service_kwargs, service_parser

EVERY = Path(__file__).resolve().parents[1] / "deploy" / "every-service.toml"


def test_one_file_configures_every_service() -> None:
    launch = load_settings(EVERY)
    assert launch.deployment.name == "every" and [s.id for s in launch.sensor] == ["1", "2"]
    pipeline = load_tables(EVERY, PipelineSettings)  # fusion replay, local filter, fusion center
    assert pipeline.sensor_ids == ("1", "2") and pipeline.fusion.vdie.window == 6
    sensor = load_tables(EVERY, SensorSettings)
    assert sensor.sonar.pd == 0.9 and sensor.radar.rate_hz == 50.0
    assert load_imm_config(EVERY).q == 100.0
    pda = load_pda_config(EVERY)
    assert pda.tracker.pd == 0.9 and pda.existence.confirm_scans == 3
    table = load_tables(EVERY, RadarFilterSettings).radar_filter
    for algorithm in ("ekf", "ekf-ie"):
        assert make_radar_filter(algorithm, table).config.q == 1.0


def test_serve_config_sets_deployment_and_connect() -> None:
    parser = service_parser("fusion-center", "test")
    parser.add_argument("--config", type=Path)
    kwargs = service_kwargs(parser, parser.parse_args(["--config", str(EVERY)]))
    assert kwargs["deployment"] == "every" and kwargs["options"].connect == ("tcp/127.0.0.1:7447",)
    explicit = parser.parse_args(["--config", str(EVERY), "--deployment", "other", "--connect", "tcp/127.0.0.1:1"])
    kwargs = service_kwargs(parser, explicit)
    assert kwargs["deployment"] == "other" and kwargs["options"].connect == ("tcp/127.0.0.1:1",)
    # without --config, the name a [deployment] table defaults to and the examples use (was "default")
    assert service_kwargs(parser, parser.parse_args([]))["deployment"] == DeploymentConfig().name == "demo"


def _pipeline(path: Path) -> PipelineSettings:
    return load_tables(path, PipelineSettings)


def _mtt(path: Path) -> MttSettings:
    return load_tables(path, MttSettings)


def _sensor(path: Path) -> SensorSettings:
    return load_tables(path, SensorSettings)


def _radar_filter(path: Path) -> object:
    with in_file(path):
        return make_radar_filter("ekf-ie", load_tables(path, RadarFilterSettings).radar_filter)


@pytest.mark.parametrize("text, message, consumers, algorithm", [
    ("[imm]\nfoo = 1\n", "unknown config key imm.foo", (load_imm_config,), "fsimm"),
    ("[pda.existence]\nfoo = 1\n", "unknown config key pda.existence.foo", (load_pda_config,), "hpda"),
    ("[deployment]\nnmae = 'x'\n", "unknown config key deployment.nmae", (_pipeline,), "kf"),
    ("[fusoin]\nq = 1.0\n", "unknown config key fusoin", (_pipeline, load_imm_config, load_pda_config), "fvdie"),
    # [regions] was read only by its consumers (replay --regions config, the region services, launch of a multi-target
    # deployment): replay of any other algorithm and serve of another role took these files (before tour57)
    ("[regions]\nmargin = 100.0\ngridd = 1\n", "unknown config key regions.gridd: did you mean regions.grid",
     (load_regions,), "kf"),
    ("[regions]\nmargin = -1.0\ngrid = {origin = [0.0, 0.0], cell = [1.0, 1.0], nx = 2, ny = 1}\n",
     "regions.margin: must be >= 0", (load_regions,), "mtt-federated"),
    ("[regions]\nmargin = 1.0\n[[regions.polygon]]\nid = 'a'\nlat_lon = [[49.0, 2.0], [49.1, 2.0], [49.1, 2.1]]\n",
     "regions.polygon.a.lat_lon: needs ", (load_regions,), "fvdie"),
    # cross-field rules (validate58), each accepted before: delete_threshold 0.9 replayed 61 sonar scans to no
    # confirmed track, silently; a repeated or unlisted [mtt] sensor passed; picture_delay > max_lag was refused
    # by replay alone (serve mtt-centre and launch took it)
    ("[pda.existence]\ndelete_threshold = 0.9\n", "pda.existence.delete_threshold, initial_existence, "
     "confirm_threshold: must rise in that order",
     (load_pda_config,), "hpda"),
    ("[pda.existence]\ninitial_existence = 0.7\n", "pda.existence.delete_threshold, initial_existence, "
     "confirm_threshold: must rise", (load_pda_config,), "hpda"),
    ("[pda.existence]\ndelete_threshold = 0.2\n", "pda.existence.delete_threshold, initial_existence, "
     "confirm_threshold: must rise", (load_pda_config,), "hpda"),
    ('[mtt]\nsensors = ["s1", "s2", "s1"]\n', "mtt.sensors: sensor id 's1' listed twice", (_mtt,),
     "mtt-federated"),
    ('[mtt]\nsensors = ["s1", "s2"]\n[mtt.sensor.s3]\npd = 0.8\n',
     "mtt.sensor.s3: a table for a sensor that sensors = ", (_mtt,), "mtt-federated"),
    ("[mtt]\npicture_delay = 4.0\nmax_lag = 3.0\n", "mtt.picture_delay: must be <= max_lag", (_mtt,),
     "mtt-centralized"),
    # [radar_filter] was read only by the radar filters (replay ekf..., serve local-filter --filter ekf...): a typo
    # or a negative q passed every other command (tour60)
    ("[radar_filter]\nwindw = 3\n", "unknown config key radar_filter.windw: did you mean radar_filter.window",
     (_radar_filter,), "mtt-federated"),
    ("[radar_filter]\nq = -1.0\n", "radar_filter.q: must be > 0", (_radar_filter,), "fvdie"),
    # TOML's inf passed every range check: q, init_velocity_std and init_z_std made every covariance non-finite
    # (replay's traceback), picture_delay with max_lag inf an OverflowError, clutter_density made every detection
    # clutter (tour61)
    ("[mtt]\nq = inf\n", "mtt.q: must be a finite number, got inf", (_mtt,), "mtt-federated"),
    ("[mtt]\ninit_velocity_std = inf\n", "mtt.init_velocity_std: must be a finite number", (_mtt,), "mtt-federated"),
    ("[mtt]\ninit_z_std = inf\n", "mtt.init_z_std: must be a finite number", (_mtt,), "mtt-centralized"),
    ("[mtt]\npicture_delay = inf\nmax_lag = inf\n", "mtt.picture_delay: must be a finite number", (_mtt,),
     "mtt-centralized"),
    ("[mtt]\nclutter_density = inf\n", "mtt.clutter_density: must be a finite number", (_mtt,), "mtt-federated"),
    ("[mtt.sensor.s1]\nclutter_density = inf\n", "mtt.sensor.s1.clutter_density: must be finite and >= 0", (_mtt,),
     "mtt-federated"),
    # launch's Zenoh connect timeout int(inf * 1000): a traceback once the services ran; deadline_s as serve
    # fusion-center --deadline, which refuses inf (tour61)
    ("[deployment]\nready_timeout_s = inf\n", "deployment.ready_timeout_s: must be finite and > 0", (_pipeline,), "kf"),
    ("[deployment]\ndeadline_s = inf\n", "deployment.deadline_s: must be finite and > 0", (_pipeline,), "kf"),
    # TOML's inf / nan passed the range checks of these tables (before tour62): [fusion] q made every estimate NaN,
    # initial_velocity_std a LinAlgError traceback; [imm]'s initial stds and x0 left no estimate written;
    # max_time_jump_s refused no gap; [sonar] / [radar] made NaN or endless scenarios
    ("[fusion]\nq = inf\n", "fusion.q: must be a finite number, got inf", (_pipeline,), "kf"),
    ("[fusion]\ninitial_velocity_std = inf\n", "fusion.initial_velocity_std: must be a finite number", (_pipeline,),
     "kf"),
    ("[fusion.vdie]\ncv_sigma = inf\n", "fusion.vdie.cv_sigma: must be a finite number", (_pipeline,), "fvdie"),
    ("[imm]\ninitial_position_std = inf\n", "imm.initial_position_std: must be a finite number",
     (load_imm_config,), "fsimm"),
    ("[imm]\nx0 = [0.0, -inf, 0.0, 0.0]\nP0 = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]\n",
     "imm.x0: must be a finite number, got ", (load_imm_config,), "fsimm"),
    ("[deployment]\nmax_time_jump_s = inf\n", "deployment.max_time_jump_s: must be finite and > 0", (_pipeline,),
     "kf"),
    ("[sonar]\nsigma_r = inf\n", "sonar.sigma_r: must be a finite number", (_sensor,), "hpda"),
    ("[sonar.scenario]\nduration = inf\n", "sonar.scenario.duration: must be a finite number", (_sensor,), "hpda"),
    ("[radar]\nstraight_s = nan\n", "radar.straight_s: must be a finite number, got nan", (_sensor,), "kf"),
    ("[radar]\nspeed = inf\n", "radar.speed: must be a finite number", (_sensor,), "kf"),
    ("[pda.tracker]\ngate = inf\n", "pda.tracker.gate: must be a finite number", (load_pda_config,), "hpda"),
    ("[pda.tracker]\nsigma_a = nan\n", "pda.tracker.sigma_a: must be a finite number", (load_pda_config,), "hpda"),
    ("[pda.existence]\nmax_speed = inf\n", "pda.existence.max_speed: must be a finite number", (load_pda_config,),
     "hpda"),
    ("[radar_filter]\nq = inf\n", "radar_filter.q: must be a finite number", (_radar_filter,), "kf"),
])
def test_config_errors_name_file_table_and_key(tmp_path: Path, text: str, message: str, consumers: tuple,
                                               algorithm: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The table's consumers and ``launch`` (which checks every table) name file, table and key."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    for load in (load_settings, *consumers):
        with pytest.raises(ConfigError, match=f"^{cfg}: {message}"):
            load(cfg)
    meas = tmp_path / "m.jsonl"
    meas.write_text(json.dumps(SONAR if algorithm == "hpda" else POSITION) + "\n")
    for alg in (algorithm, "kf"):  # the CLI checks every table, whichever the algorithm reads
        assert main(["replay", "--algorithm", alg, "--measurements", str(meas), "--config", str(cfg),
                     "--out", str(tmp_path / "o.jsonl")]) == 2
        assert f"{cfg}: {message}" in capsys.readouterr().err
    assert main(["serve", "router", "--config", str(cfg)]) == 2  # before any session opens
    assert f"{cfg}: {message}" in capsys.readouterr().err


POSITION = {"t": 0.0, "sensor": "1", "z": [1.0, 2.0], "R": [[1.0, 0.0], [0.0, 1.0]]}
SONAR = {"t": 0.0, "sensor": "s", "z": [], "R": [[1.0, 0.0], [0.0, 1.0]],
         "detections": [{"z": [1.0, 2.0], "amplitude": 30.0}]}
RADAR = {"t": 0.0, "sensor": "r", "z": [2000.0, 0.1, 0.2], "R": [[225.0, 0, 0], [0, 4e-6, 0], [0, 0, 4e-6]],
         "sensor_position": [0.0, 0.0, 0.0]}


@pytest.mark.parametrize("algorithm, line", [
    ("kf", POSITION), ("fvdie", POSITION), ("fsimm", POSITION), ("hpda", SONAR), ("ekf", RADAR)])
def test_unknown_input_field_names_file_line_and_field(tmp_path: Path, algorithm: str, line: dict,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    meas = tmp_path / "m.jsonl"
    second = {**line, "t": 1.0, "truth": [0.0], "bogus": 1}
    meas.write_text(json.dumps(line) + "\n" + json.dumps(second) + "\n")
    assert main(["replay", "--algorithm", algorithm, "--measurements", str(meas),
                 "--out", str(tmp_path / "o.jsonl")]) == 2
    assert f"{meas}:2: unknown field 'bogus'" in capsys.readouterr().err


def test_effective_config_round_trips(tmp_path: Path) -> None:
    """``demo`` writes the effective configuration (``to_toml``); it reads back identical."""
    from fedtrack.config import to_toml
    from fedtrack.deploy.demo import settings_table

    settings = load_settings(EVERY)
    (tmp_path / "c.toml").write_text(to_toml(settings_table(settings)))
    assert load_settings(tmp_path / "c.toml") == settings


def test_router_listens_where_the_deployment_table_says(tmp_path: Path) -> None:
    cfg = tmp_path / "r.toml"
    cfg.write_text('[deployment]\nname = "r"\nrouter_listen = "tcp/127.0.0.1:7999"\n')
    parser = service_parser("router", "test", listen_default=("tcp/127.0.0.1:7447",))
    parser.add_argument("--config", type=Path)
    kwargs = service_kwargs(parser, parser.parse_args(["--config", str(cfg)]), mode="router")
    assert kwargs["deployment"] == "r" and kwargs["options"].listen == ("tcp/127.0.0.1:7999",)
    assert kwargs["options"].connect == ()


def test_deployment_duration_extends_the_scenario_at_constant_velocity() -> None:
    import numpy as np

    from fedtrack.sensors.scenarios import deployment_scenario, deployment_truth, paper004_scenario

    paper, longer = paper004_scenario(1), deployment_scenario(1, 250.0)
    assert len(longer.times) == 251 and longer.segments == paper.segments
    a, b = deployment_truth(paper, 3), deployment_truth(longer, 3)
    np.testing.assert_allclose(b[:101], a, atol=1e-9)  # the paper's 100 s unchanged
    assert np.all(b[101:, [2, 5]] == 0.0)  # no commanded acceleration after the last maneuver


@pytest.mark.parametrize(("make", "reason"), [
    (lambda p: p.symlink_to("/dev/zero"), "not a regular file, not a config file"),  # read whole: a MemoryError
    (lambda p: os.mkfifo(p), "not a regular file, not a config file"),  # opened to read: the start blocked for good
    (lambda p: p.write_text("#" * (MAX_CONFIG_BYTES + 1)), f"larger than {MAX_CONFIG_BYTES} bytes, not a config file"),
])
def test_a_config_that_is_no_regular_file_of_a_sane_size_is_refused_unread(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], make: Callable[[Path], None], reason: str) -> None:
    """``--config`` naming a link to /dev/zero, a FIFO or a file of more than ``MAX_CONFIG_BYTES`` ends
    the start with exit 2 and one line naming the file (before: a MemoryError's traceback, a start blocked
    until something wrote to the FIFO, a file of any size read whole)."""
    config = tmp_path / "config.toml"
    make(config)
    code = main(["serve", "mtt-centre", "--config", str(config), "--connect", "tcp/127.0.0.1:1"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == f"fedtrack: error: {config}: {reason}"
