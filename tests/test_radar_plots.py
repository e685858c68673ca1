"""A radar engineer's own plots (not `simulate`'s): range / azimuth / elevation in radians in the common
frame's axes about ``sensor_position`` (docs/multitarget-formats.md), checked as a radar's plots and, with a
``[frame]``, the radar's place checked against its site. Each bad value is one line naming the file, the
line, the detection and its component, exit 2, nothing written (tour49)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from test_hostile_messages import KEYS, OPTIONS, Bus

from fedtrack.cli import main
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.geodetic import Frame, FrameConfig, enu_from_aer, site_from_geodetic
from fedtrack.jsonl import InputError
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import SensorScan, parse_scan, scan_from_measurement, scan_to_measurement
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.radar.filters import parse_measurement
from fedtrack.local_filters.radar.measurement import polar_from_cartesian
from fedtrack.wire import Measurement, encode

ORIGIN = (-17.6, 179.8, 20.0)  # Fiji, across the antimeridian from r2
SITES = {"r1": (-17.75, 179.70, 35.0), "r2": (-16.62, -179.95, 420.0)}
R3 = np.diag([30.0, math.radians(0.1), math.radians(0.1)]) ** 2
CONFIG = f"""[frame]
origin = {list(ORIGIN)}

[frame.sites]
r1 = {list(SITES['r1'])}
r2 = {list(SITES['r2'])}

[mtt]
sensors = ["r1", "r2"]
"""


def plots(sensor: str, own_aer_deg: list[tuple[float, float, float]]) -> tuple[list[float], list[list[float]]]:
    """``sensor_position`` and ``z`` of plots given as a radar gives them (azimuth from north clockwise and
    elevation above the site's horizontal [deg], range [m]), by the recipe of docs/multitarget-formats.md."""
    site = site_from_geodetic(Frame(*ORIGIN), *SITES[sensor])
    aer = np.radians(np.array(own_aer_deg))
    aer[:, 2] = np.array(own_aer_deg)[:, 2]
    z = polar_from_cartesian(enu_from_aer(site, aer) - site.position)
    return site.position.tolist(), z.tolist()


def scan_line(t: float, sensor: str, own_aer_deg: list[tuple[float, float, float]]) -> dict:
    position, z = plots(sensor, own_aer_deg)
    return {"t": t, "sensor": sensor, "R": R3.tolist(), "sensor_position": position,
            "detections": [{"z": zz} for zz in z]}


def replay_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str], rows: list[dict],
                          config: str = CONFIG) -> str:
    (tmp_path / "c.toml").write_text(config)
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    out = tmp_path / "p.jsonl"
    code = main(["replay", "--algorithm", "mtt-centralized", "--config", str(tmp_path / "c.toml"),
                 "--measurements", str(tmp_path / "m.jsonl"), "--out", str(out)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (code, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", "m.jsonl"]  # nothing written
    return lines[0]


GOOD = [(40.0, 2.0, 80_000.0), (200.0, 0.5, 120_000.0)]
BAD_PLOTS = {  # (the second detection's z changed so, the message's end)
    "azimuth of 400 deg, in degrees": (lambda z: [z[0], 400.0, z[2]], "detections[1].z[1] (azimuth) must be in"),
    "azimuth of 400 deg, in radians": (lambda z: [z[0], math.radians(400.0), z[2]],
                                       "detections[1].z[1] (azimuth) must be in"),
    "elevation in degrees": (lambda z: [z[0], z[1], 3.0], "detections[1].z[2] (elevation) must be in (-pi/2, pi/2)"),
    "range of -1": (lambda z: [-1.0, z[1], z[2]], "detections[1].z[0] (range) must be > 0 [m], got -1"),
}


@pytest.mark.parametrize("case", sorted(BAD_PLOTS))
def test_a_bad_plot_is_one_line_naming_the_detection_and_its_component(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str],
                                                                      case: str) -> None:
    """The plots as the recipe writes them, on sites across the antimeridian, replay; one value changed, the
    file is refused."""
    change, expected = BAD_PLOTS[case]
    (tmp_path / "c.toml").write_text(CONFIG)
    rows = [scan_line(0.0, "r2", GOOD), scan_line(4.0, "r1", GOOD)]
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(tmp_path / "c.toml"),
                 "--measurements", str(tmp_path / "m.jsonl"), "--out", str(tmp_path / "p.jsonl")]) == 0
    (tmp_path / "p.jsonl").unlink()
    capsys.readouterr()
    rows[1]["detections"][1]["z"] = change(rows[1]["detections"][1]["z"])
    line = replay_one_line_error(tmp_path, capsys, rows)
    assert "m.jsonl:2: " + expected in line, line


def test_plots_in_degrees_are_refused_everywhere_a_radar_plot_is_read() -> None:
    """The scan line, its wire form at a live tracker, and the single-target radar replay's line."""
    position, z = plots("r1", GOOD)
    in_degrees = [[r, math.degrees(a), math.degrees(e)] for r, a, e in z]
    line = {"t": 0.0, "sensor": "r1", "R": R3.tolist(), "sensor_position": position,
            "detections": [{"z": zz} for zz in in_degrees]}
    with pytest.raises(InputError, match=r"m.jsonl:1: detections\[0\].z\[1\] \(azimuth\)"):
        parse_scan(line, "m.jsonl:1")
    wire = scan_to_measurement(SensorScan(0.0, "r1", R3, np.array(in_degrees), None, np.array(position)), 0, 0)
    with pytest.raises(ValueError, match=r"detections\[0\].z\[1\] \(azimuth\)"):
        scan_from_measurement(wire)
    single = {"t": 0.0, "sensor": "r1", "z": in_degrees[1], "R": R3.tolist(), "sensor_position": position}
    with pytest.raises(InputError, match=r"m.jsonl:1: z\[1\] \(azimuth\)"):
        parse_measurement(single, "m.jsonl:1")


SITE_CASES = {  # (the first line's sensor_position changed so, or the config; the message's end)
    "sensor_position 1e7 m up": (lambda p: [p[0], p[1], 1e7], CONFIG,
                                 "m.jsonl:1: sensor_position is 1.00"),
    "site height given above sea level": (lambda p: p, CONFIG.replace("179.8, 20.0]\n\n[frame.sites]\nr1 = "
                                                                      "[-17.75, 179.7, 35.0]",
                                                                      "179.8, 20.0]\n\n[frame.sites]\nr1 = "
                                                                      "[-17.75, 179.7, 95.0]"),
                                          "is 60 m from the site of radar 'r1' in [frame.sites]"),
    "a radar without a site 1e7 m up": (lambda p: [p[0], p[1], 1e7],
                                        CONFIG.replace("r2 = [-16.62, -179.95, 420.0]\n", ""),
                                        "m.jsonl:1: sensor_position is 1.00"),
}


@pytest.mark.parametrize("case", sorted(SITE_CASES))
def test_a_sensor_position_that_is_not_its_radars_site_is_one_line(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str],
                                                                    case: str) -> None:
    change, config, expected = SITE_CASES[case]
    first = scan_line(0.0, "r2", GOOD)
    first["sensor_position"] = change(first["sensor_position"])
    line = replay_one_line_error(tmp_path, capsys, [first, scan_line(4.0, "r1", GOOD)], config)
    assert expected in line, line


def live_tracker(role: str, bad: int | None) -> dict[str, int]:
    """The Health counters of ``role`` (with the config's ``[frame]``) after four scans of r1 4 s apart, scan
    ``bad``'s ``sensor_position`` 60 m above r1's site (the site's height taken above sea level)."""
    config = tomllib.loads(CONFIG)["frame"]
    sites = FrameConfig(tuple(config["origin"]), {k: tuple(v) for k, v in config["sites"].items()})
    cfg = MttConfig(sensors=("r1",), max_lag=3.0)
    if role == "mtt-local":
        svc: MttLocalService | MttCentreService = MttLocalService("r1", False, cfg, sites=sites, service_id="r1",
                                                                  options=OPTIONS, deployment=KEYS.deployment)
    else:
        svc = MttCentreService("mtt-centralized", cfg, 6, sites=sites, service_id="centre", options=OPTIONS,
                               deployment=KEYS.deployment)
    bus = Bus([svc])
    for seq in range(4):
        line = scan_line(4.0 * seq, "r1", GOOD)
        where = np.array(line["sensor_position"]) + (0.0, 0.0, 60.0 if seq == bad else 0.0)
        bus.put(KEYS.sensor_meas("r1"), encode(Measurement(
            sensor="r1", seq=seq, t=line["t"], kind="scan", z=np.zeros(0), R=R3, sensor_position=where,
            detections=[(np.array(d["z"]), 0.0) for d in line["detections"]], stamp_ns=1)))
    return dict(svc.counters)


@pytest.mark.parametrize("role", ["mtt-local", "mtt-centre"])
def test_the_live_trackers_reject_a_scan_off_its_radars_site_counted(role: str) -> None:
    """``serve mtt-local`` and ``serve mtt-centre --algorithm mtt-centralized`` with the config's ``[frame]``: a
    scan whose ``sensor_position`` is not its radar's site is rejected (``rejected_wrong_site``), as ``replay``
    refuses the file; the scans at the site are tracked. Before, every one was taken, and the run's recording
    was one that ``replay`` refused."""
    done = "reports" if role == "mtt-local" else "scans"  # the centre takes a scan when the next one comes
    honest, misplaced = live_tracker(role, None), live_tracker(role, 3)
    assert honest["rejected"] == 0 and honest[done] >= 3, honest
    assert misplaced.get("rejected_wrong_site") == 1 and misplaced["rejected"] == 1, misplaced
    assert misplaced[done] == honest[done] - 1, (honest, misplaced)


def test_a_radar_without_a_site_replays_wherever_it_is(tmp_path: Path) -> None:
    """``[frame.sites]`` is optional per radar: one the table leaves out (on a ship, its ``sensor_position``
    moving) replays, checked for its height only."""
    (tmp_path / "c.toml").write_text(CONFIG.replace("r2 = [-16.62, -179.95, 420.0]\n", ""))
    rows = [scan_line(0.0, "r2", GOOD), scan_line(4.0, "r1", GOOD), scan_line(5.0, "r2", GOOD)]
    rows[2]["sensor_position"] = [v + 50.0 for v in rows[2]["sensor_position"][:2]] + rows[2]["sensor_position"][2:]
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(tmp_path / "c.toml"),
                 "--measurements", str(tmp_path / "m.jsonl"), "--out", str(tmp_path / "p.jsonl")]) == 0
