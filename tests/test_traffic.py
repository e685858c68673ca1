"""``fedtrack simulate traffic``: recorded state vectors as truth, sensors on the Earth."""

from __future__ import annotations

import gzip
import json
import tomllib
from pathlib import Path

import matplotlib.colors
import numpy as np
import pytest
from matplotlib.figure import Figure

from fedtrack.cli import main
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.geodetic import Frame, aer_from_enu, enu_from_geodetic, geodetic_from_enu, level_z, site_from_geodetic
from fedtrack.jsonl import InputError
from fedtrack.local_filters.radar.measurement import cartesian_from_polar, polar_from_cartesian, wrap_angle
from fedtrack.sensors.multitarget import DT, Scenario, SensorSpec, sensor_lines
from fedtrack.sensors.state_vectors import read_recording
from fedtrack.sensors.traffic_sensors import adsb_view, parse_noise
from fedtrack.sensors.traffic_truth import (
    TRUTH_CELL_BYTES,
    Truth,
    above_the_runways,
    altitude_glitches,
    build_truth,
    reconcile,
    segments,
)

DATA = Path(__file__).resolve().parent / "data"
PARIS = Frame(48.86, 2.40, 0.0)


def _write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_opensky_and_traffic_columns_and_units_read_alike(tmp_path: Path) -> None:
    si = _write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,baroaltitude,velocity,heading,vertrate,onground",
                    ["1600000000,ABC123,48.0,2.0,3048.0,102.88888888888889,90.0,5.08,false",
                     "1600000001,abc123,48.0,2.001,3053.08,102.88888888888889,90.0,5.08,False",
                     "1600000002,abc123,48.0,2.002,0.0,0.0,0.0,0.0,true"])
    aviation = tmp_path / "b.jsonl.gz"
    with gzip.open(aviation, "wt") as fh:
        for t, lon, alt in (("2020-09-13T12:26:40Z", 2.0, 10000.0), ("2020-09-13T12:26:41", 2.001, 10016.666666666666)):
            fh.write(json.dumps({"timestamp": t, "icao24": "abc123", "latitude": 48.0, "longitude": lon,
                                 "altitude": alt, "groundspeed": 200.0, "track": 90.0, "vertical_rate": 1000.0}) + "\n")
    a, b = read_recording(si), read_recording(aviation, "aviation")
    assert len(a.t) == 2  # the row on the ground is dropped
    np.testing.assert_allclose(a.t, b.t, atol=1e-9)
    np.testing.assert_allclose(a.lla, b.lla, atol=1e-9)
    np.testing.assert_allclose(a.velocity, b.velocity, atol=1e-9)
    np.testing.assert_allclose(a.velocity[0], [102.88888888888889, 0.0, 5.08], atol=1e-9)
    assert list(a.icao24) == ["abc123", "abc123"]


def test_bad_input_names_the_file_line_and_field(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"no altitude column \(accepted names: altitude, baroaltitude"):
        read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon", ["1,a,48,2"]))
    with pytest.raises(InputError, match=r"b\.csv:3: altitude: 'high' is not a number"):
        read_recording(_write_csv(tmp_path / "b.csv", "time,icao24,lat,lon,alt", ["1,a,48,2,100", "2,a,48,2,high"]))
    with pytest.raises(InputError, match=r"c\.csv:2: time: 'noon' is neither"):
        read_recording(_write_csv(tmp_path / "c.csv", "time,icao24,lat,lon,alt", ["noon,a,48,2,100"]))
    with pytest.raises(InputError, match="unknown format"):
        read_recording(_write_csv(tmp_path / "d.txt", "time", ["1"]))


def test_segments_drop_stale_positions_and_split_at_gaps(tmp_path: Path) -> None:
    rows = [f"{t},a,48.0,{2.0 + 0.001 * t},1000" for t in (0, 1, 2, 3, 40, 41, 42)]
    rows.insert(2, "1.5,a,48.0,2.001,1000")  # the position of t = 1 again: stale
    rows += ["0,b,47.0,2.0,1000", "100,b,47.0,2.1,1000"]  # a gap of 100 s: two tracks of one sample each
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt", rows))
    pieces = segments(rec, max_gap=30.0).pieces
    assert [rec.t[p].tolist() for p in pieces] == [[0, 1, 2, 3], [40, 41, 42]]


def test_reconcile_keeps_consistent_samples_and_follows_the_velocities() -> None:
    t = np.array([0.0, 1.0, 2.5, 3.0, 10.0])
    v = np.array([200.0, -50.0, 3.0])
    pos = 1000.0 + t[:, None] * v
    np.testing.assert_allclose(reconcile(t, pos, np.tile(v, (5, 1))), pos, atol=1e-9)
    # positions jittered by +-40 m: the result keeps the recorded velocity between samples
    jitter = np.array([[40.0, 0, 0], [-40, 0, 0], [40, 0, 0], [-40, 0, 0], [0, 0, 0]])
    s = reconcile(t, pos + jitter, np.tile(v, (5, 1)))
    steps = np.diff(s, axis=0) / np.diff(t)[:, None] - v
    assert np.abs(steps).max() < 1.0 and np.abs(np.diff(pos + jitter, axis=0)[0] / 1.0 - v).max() == 80.0


def test_truth_passes_through_the_samples_in_the_common_frame(tmp_path: Path) -> None:
    """An aircraft flying east at 200 m/s 150 km from the origin: the truth at each sample time is the
    sample's ENU position (the Earth's curvature included) and its velocity the turned recorded one."""
    a, e2, phi = 6378137.0, 6.69437999014e-3, np.radians(48.86)
    per_degree = (a / np.sqrt(1 - e2 * np.sin(phi) ** 2) + 10000.0) * np.cos(phi) * np.pi / 180  # along the parallel
    rows = []
    for k in range(60):
        lon = 4.4 + k * 200.0 / per_degree
        rows.append(f"{1000 + k},a,48.86,{lon},10000,200,90,0")
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt,gs,track,vertical_rate", rows))
    truth = build_truth(rec, PARIS, 0.0, None, 400e3, 30.0)
    at = np.round((rec.t - truth.t0) / DT).astype(int)
    expected = enu_from_geodetic(PARIS, *rec.lla.T)
    np.testing.assert_allclose(truth.x[at, 0][:, [0, 2, 4]], expected, atol=1e-3)
    assert expected[0, 2] < 10000.0 - 1500.0  # the Earth curves away below the origin's plane
    assert truth.alive[at[0]:at[-1] + 1, 0].all() and not truth.alive[at[-1] + 1:, 0].any()
    # the recorded east velocity, turned by the meridian convergence into the common axes
    vel = truth.x[at[1:-1], 0][:, [1, 3, 5]]
    assert np.abs(np.linalg.norm(vel[:, :2], axis=1) - 200.0).max() < 1.0
    # the local east turned to the north by the meridians' convergence, (lon - lon0) sin(lat), about 1.5 deg
    convergence = np.radians(rec.lla[1:-1, 1] - PARIS.lon) * np.sin(np.radians(48.86))
    np.testing.assert_allclose(np.arctan2(vel[:, 1], vel[:, 0]), convergence, atol=np.radians(0.02))


def test_a_recorded_track_the_positions_rule_out_is_not_the_truths(tmp_path: Path) -> None:
    """An aircraft flying straight south-east (135 deg) at 65 m/s, a state vector every 5 s, its track stored as
    an 8-bit integer (-121: read as 239 deg, as in the traffic package's calibration samples): the truth's velocity
    is the positions' (within 1 m/s) and the command says how many recorded velocities it left out (all); the same
    recording with its track right keeps them all. Before, the truth followed the recorded velocities, 104 deg
    off, and looped between the samples (its velocity 100 m/s off)."""
    heading = np.radians(135.0)
    enu = np.array([[np.sin(heading), np.cos(heading), 0.0]]) * 65.0 * np.arange(0.0, 300.0, 5.0)[:, None]
    lla = geodetic_from_enu(PARIS, enu + [0.0, 0.0, 600.0])
    for track, odd in ((-121, 60), (135, 0)):
        rows = [f"{1000 + 5 * k},a,{la},{lo},{h},{65.0},{track},0" for k, (la, lo, h) in enumerate(lla.tolist())]
        rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt,gs,track,vertical_rate", rows))
        truth = build_truth(rec, PARIS, 0.0, None, 400e3, 30.0)
        vel = truth.x[truth.alive[:, 0], 0][:, [1, 3]]
        assert np.abs(vel - 65.0 * np.array([np.sin(heading), np.cos(heading)])).max() < 1.0
        assert truth.dropped["horizontal velocities at odds with the positions (their derivative taken)"] == odd


def test_a_glitched_position_is_left_out_of_the_truth(tmp_path: Path) -> None:
    """An aircraft flying straight south-west (224 deg) at 215 m/s, a state vector every second, with two positions
    decoded wrong as in the traffic package's ``featured/airbus_tree`` (2.7 km west, then 2.9 km south, each for one
    sample) before a gap of 21 s: both are left out and counted, and the truth flies within 1 m/s of 215 m/s. Before,
    they made the velocities beside them 'at odds', the positions' derivative (2.8 km/s) was taken for them and the
    truth flew at up to 1,740 m/s."""
    heading = np.radians(224.0)
    times = np.r_[np.arange(0.0, 60.0), np.arange(81.0, 140.0)]
    enu = np.array([[np.sin(heading), np.cos(heading), 0.0]]) * 215.0 * times[:, None]
    k = int(np.flatnonzero(times == 58.0)[0])
    enu[k] += [-2700.0, 0.0, 0.0]
    enu[k + 1] += [-2700.0, -2900.0, 0.0]
    lla = geodetic_from_enu(PARIS, enu + [0.0, 0.0, 8000.0])
    rows = [f"{1000 + t},a,{la},{lo},{h},215.0,224.0,0" for t, (la, lo, h) in zip(times.tolist(), lla.tolist())]
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt,gs,track,vertical_rate", rows))
    truth = build_truth(rec, PARIS, 0.0, None, 400e3, 30.0)
    speed = np.hypot(*truth.x[truth.alive[:, 0], 0][:, [1, 3]].T)
    assert np.abs(speed - 215.0).max() < 1.0, speed.max()
    assert truth.dropped["positions farther from the previous one than the aircraft could fly (glitches)"] == 2


@pytest.mark.parametrize("rate", [True, False], ids=["vertical-rate", "no-vertical-rate"])
def test_an_altitude_decoded_wrong_is_left_out_of_the_truth(tmp_path: Path, rate: bool) -> None:
    """An aircraft descending at 5 m/s from 1,410 m, flying east at 80 m/s, a state vector every second, with three
    altitudes decoded wrong as in the Paris extract's ``4d21ec`` (a sample 8.3-8.4 km above the others, once two in
    a row): they are left out and counted, and the truth's altitude stays within 1 m of the descent, with the vertical
    rate recorded or not. Before, with it recorded the reconciliation spread the glitches over the track (the truth
    up to 221 m above the descent); without it the truth climbed to 9.4 km above it in a second."""
    times = np.arange(0.0, 120.0)
    alt = 1410.0 - 5.0 * times
    wrong = np.isin(times, [30.0, 70.0, 71.0])
    recorded = np.where(wrong, alt + 8344.0, alt)
    lla = geodetic_from_enu(PARIS, np.column_stack([80.0 * times, np.zeros((len(times), 2))]))
    lla[:, 2] = recorded
    velocity, header = (",80.0,90.0,-5.0", ",gs,track,vertical_rate") if rate else ("", "")
    rows = [f"{1000 + t},a,{la},{lo},{h}{velocity}" for t, (la, lo, h) in zip(times.tolist(), lla.tolist())]
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt" + header, rows))
    truth = build_truth(rec, PARIS, 0.0, None, 400e3, 30.0)
    at = np.round((rec.t - truth.t0) / DT).astype(int)
    flown = geodetic_from_enu(PARIS, truth.x[at[0]:at[-1] + 1, 0][:, [0, 2, 4]])[:, 2]
    expected = 1410.0 - 5.0 * np.arange(len(flown)) * DT
    assert np.abs(flown - expected).max() < 1.0, np.abs(flown - expected).max()
    assert truth.dropped["altitudes off those either side by more than the aircraft could climb or descend "
                         "(altitude glitches)"] == 3


def test_an_altitude_held_a_step_or_a_parabola_is_no_glitch() -> None:
    """What aircraft fly and recordings hold is kept: an altitude held for 10 s and then caught up (a step, as
    ``featured/dreamliner_airfrance`` records), a climb at 30 m/s, a parabolic flight's 1 g pull-up and push-over
    (``featured/zero_gravity``), samples 1 s apart, 30 s apart, and a track's ends."""
    t = np.arange(0.0, 60.0)
    held = np.where(t < 20.0, 7925.0, 8222.0)
    parabola = 8000.0 - 9.80665 * (t - 30.0) ** 2 / 2.0
    for times, alt in ((t, held), (t, 3000.0 + 30.0 * t), (t, parabola), (30.0 * t, 3000.0 + 10.0 * t)):
        assert not altitude_glitches(times, alt, np.full_like(times, np.nan)).any()
    assert not altitude_glitches(t[:2], np.array([1000.0, 9000.0]), np.full(2, np.nan)).any()


def test_an_aircraft_on_the_ground_read_11_km_up_is_left_out_of_the_truth(tmp_path: Path) -> None:
    """As ``noisy/noisy_takeoff``: an aircraft taxis east at 20 m/s for 61 s, its rows flagged on the ground (altitude
    empty) and airborne (10,965 m) alternating every 3 s; 100 s later it takes off from a runway at 400 m and climbs
    at 15 m/s, a row on the ground 1 s before its first. The taxiing rows, between reports on the ground seconds away
    and far above any runway, are left out and counted; the climb is kept whole (on the ground before it only).
    Before, the truth held a track at 10,965 m moving at 20 m/s, and the site check and init_z_std took it."""
    rows = []
    for t in range(61):
        la, lo, _ = geodetic_from_enu(PARIS, np.array([20.0 * t, 0.0, 0.0])).tolist()
        on = (t // 3) % 2 == 0
        rows.append(f"{1000 + t},a,{la},{lo},{'' if on else 10965.0},{str(on).lower()}")
    for t in range(160, 280):
        la, lo, _ = geodetic_from_enu(PARIS, np.array([20.0 * 60 + 80.0 * (t - 160), 0.0, 0.0])).tolist()
        rows.append(f"{1000 + t},a,{la},{lo},{400.0 + 15.0 * (t - 159) if t > 160 else 400.0},{str(t == 160).lower()}")
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt,onground", rows))
    truth = build_truth(rec, PARIS, 0.0, None, 400e3, 30.0)
    assert len(truth.icao24) == 1 and truth.highest == 400.0 + 15.0 * 120, (truth.icao24, truth.highest)
    assert truth.dropped["altitudes above every runway between reports on the ground"] == 30
    # what can be flown between two reports on the ground 1 s and 30 s away (at 1 g off the highest runway) is kept
    nan = np.full(2, np.nan)
    assert above_the_runways(np.array([1.0, 1.0]), np.array([4411.0 + 30.0 + 9.80665 / 2, 5000.0]), nan,
                             np.array([0.0, 2.0])).tolist() == [False, True]
    assert not above_the_runways(np.array([30.0, 30.0]), np.array([8800.0, 8800.0]), nan, np.array([0.0, 60.0])).any()
    assert not above_the_runways(np.array([1.0]), np.array([9000.0]), nan[:1], np.array([0.0])).any()  # one side


def test_a_recording_sampled_every_31_s_is_one_track(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A survey aircraft recorded every 31 s (as the traffic package's ``surveys/texas``): without --max-gap the
    truth is one track of it (--max-gap three sampling intervals, 93 s). Before, the default 30 s cut every
    sample into a track of one, left out, and the command found no aircraft (exit 2)."""
    rows = [f"{1000 + 31 * k},a,48.86,{2.40 + 0.03 * k},3000" for k in range(12)]
    source = _write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt", rows)
    code = main(["simulate", "traffic", "--source", str(source), "--origin", "48.86,2.55", "--sensors", "pos:2",
                 "--out", str(tmp_path / "o")])
    assert code == 0, capsys.readouterr().err
    ids = {g["id"] for line in (tmp_path / "o" / "truth.jsonl").read_text().splitlines()
           for g in json.loads(line)["targets"]}
    assert ids == {0}


def test_a_window_too_long_for_memory_is_one_line_and_writes_nothing(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Two flights three years apart (``onground/zurich_airport`` spans 55 days): the whole recording's window
    on the 0.05 s grid needs about 200 GB. Before: numpy's MemoryError as a traceback (or the machine's memory
    taken); now one line naming --duration, exit 2, no folder."""
    rows = [f"{t0 + k},{icao},48.86,{2.40 + 0.002 * k},3000"
            for t0, icao in ((0, "a"), (1e8, "b")) for k in range(10)]
    source = _write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt", rows)
    code = main(["simulate", "traffic", "--source", str(source), "--origin", "48.86,2.40",
                 "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "the window is too long" in err[0] and "--duration" in err[0], err
    assert not (tmp_path / "o").exists()


def test_tracks_outside_the_box_take_no_room_in_the_truth_grid(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """Memory for one track of the window's grid: one aircraft inside the box and 30 outside it fit; two
    inside do not (before, the grid held every track of the window, inside the box or not)."""
    rows = [f"{k},{i:06x},{48.86 + 0.5 * i + 0.0009 * k},2.40,3000,100,0,0" for i in range(31) for k in range(100)]
    monkeypatch.setattr("fedtrack.sensors.traffic_truth.memory_room", lambda: 1.5 * 1981 * TRUTH_CELL_BYTES)
    rec = read_recording(_write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt,gs,track,vertical_rate", rows))
    truth = build_truth(rec, PARIS, 0.0, None, 40e3, 30.0)
    assert truth.icao24 == ["000000"] and truth.x.shape == (1981, 1, 6)
    with pytest.raises(InputError, match="the window is too long"):
        build_truth(rec, PARIS, 0.0, None, 150e3, 30.0)


def _cv_truth(n: int, seconds: float, rng: np.random.Generator) -> Truth:
    steps = int(round(seconds / DT)) + 1
    t = np.arange(steps) * DT
    p0 = np.column_stack([rng.uniform(-60e3, 60e3, (n, 2)), rng.uniform(3e3, 11e3, n)])
    v = np.column_stack([rng.uniform(-200, 200, (n, 2)), np.zeros(n)])
    pos = p0[None] + t[:, None, None] * v[None]
    x = np.stack([pos[..., 0], np.broadcast_to(v[:, 0], pos.shape[:2]), pos[..., 1],
                  np.broadcast_to(v[:, 1], pos.shape[:2]), pos[..., 2], np.zeros(pos.shape[:2])], axis=-1)
    return Truth(0.0, x, np.ones((steps, n), bool), [f"{i:06x}" for i in range(n)], {})


def test_radar_errs_in_its_own_frame_and_reports_in_the_trackers_model() -> None:
    """A radar 150 km from the origin (its north turned by about 1.6 deg): its detections, read as
    range, azimuth, elevation about ``sensor_position`` in the common axes, are the truth's plus R's
    noise in that model (mean 0, variance 1 after scaling, within 4 standard errors), and the noise is
    the radar's own azimuth and elevation's (2 mrad about its north and its horizontal plane)."""
    rng = np.random.default_rng(7)
    truth = _cv_truth(30, 300.0, rng)
    site = site_from_geodetic(PARIS, 49.5, 4.0, 200.0)
    sc = Scenario(targets=30, duration=300.0, region=75e3, pd=1.0, clutter=0.0, late=0.0)
    lines = sensor_lines(SensorSpec("r1", "radar", 4.0), sc, truth.x, truth.alive, True, rng, site=site)
    common, own = [], []
    for _, line in lines:
        step = int(round(line["t"] / DT))
        z = np.array([d["z"] for d in line["detections"]])
        where = np.array(line["sensor_position"])
        p = truth.x[step][:, [0, 2, 4]]
        # match each detection with its aircraft: the nearest truth
        back = where + cartesian_from_polar(z)
        idx = np.argmin(np.linalg.norm(back[:, None] - p[None], axis=-1), axis=1)
        r = z - polar_from_cartesian(p[idx] - where)
        r[:, 1] = wrap_angle(r[:, 1])
        common.append(r / np.sqrt(np.diag(line["R"])))
        o = aer_from_enu(site, back) - aer_from_enu(site, p[idx])
        o[:, 0] = wrap_angle(o[:, 0])
        own.append(o)
    common, own = np.concatenate(common), np.concatenate(own)
    se = 1.0 / np.sqrt(len(common))
    assert np.all(np.abs(common.mean(axis=0)) < 4 * se)
    assert np.all(np.abs(common.var(axis=0) - 1.0) < 4 * np.sqrt(2) * se)
    np.testing.assert_allclose(own[:, :2].std(axis=0), [0.002, 0.002], rtol=4 * se)
    np.testing.assert_allclose(own[:, 2].std(), 10.0, rtol=4 * np.sqrt(2) * se)


def test_adsb_reports_move_to_the_scan_time() -> None:
    rng = np.random.default_rng(3)
    truth = _cv_truth(5, 20.0, rng)
    period = rng.uniform(0.4, 0.6, 5)
    moved, fresh = adsb_view(truth, 1.0, period, rng)
    np.testing.assert_allclose(moved[fresh], truth.x[fresh], atol=1e-6)  # constant velocity: exact
    assert fresh[round(1.0 / DT):].all()  # a report within every second of every aircraft
    sparse = adsb_view(truth, 0.2, period, rng)[1]
    assert 0.2 < sparse[20:].mean() < 0.6  # scans of 0.2 s: about 0.2 / 0.5 of them hold an aircraft


def test_simulate_traffic_on_the_extract_then_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    code = main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "46.9,8.2",
                 "--sensors", "radar:4@47.3/8.0/900,pos:2,adsb:1", "--seed", "2", "--start", "60", "--duration", "120",
                 "--box", "250", "--out", str(out)])
    assert code == 0
    assert "at most" in capsys.readouterr().out
    config = tomllib.loads((out / "config.toml").read_text())
    assert config["frame"] == {"origin": [46.9, 8.2, 0.0], "sites": {"r1": [47.3, 8.0, 900.0]}}
    assert config["mtt"]["sensors"] == ["r1", "s2", "a3"]
    # two motion modes from civil kinematics (docs/geodetic.md): the maneuvering mode's q lets the velocity
    # change by g tan(25 deg) over the longest period (4 s); a 90 deg turn at 3 deg/s; legs of 2 min
    mtt = config["mtt"]
    assert mtt["process_noise"] == "imm" and mtt["maneuver_s"] == 30.0 and mtt["straight_s"] == 120.0
    assert mtt["q"] == pytest.approx((9.80665 * np.tan(np.radians(25.0))) ** 2 * 4.0, abs=1e-3)
    lines = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    assert len(lines) == 121 and min(len(line["targets"]) for line in lines) >= 20
    g = lines[60]["targets"]
    lla = np.array([[tg["lat"], tg["lon"], tg["alt"]] for tg in g])
    enu = np.array([np.asarray(tg["x"])[[0, 2, 4]] for tg in g])
    np.testing.assert_allclose(lla, geodetic_from_enu(Frame(46.9, 8.2), enu), atol=2e-3)
    scans = [json.loads(line) for line in (out / "measurements.jsonl").read_text().splitlines()]
    assert {s["sensor"] for s in scans} == {"r1", "s2", "a3"}
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(out / "config.toml"),
                 "--measurements", str(out / "measurements.jsonl"), "--out", str(out / "tracks.jsonl")]) == 0


def test_cli_errors_and_help(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "traffic", "--source", str(tmp_path / "none.csv"), "--origin", "46.9,8.2",
                 "--out", str(tmp_path / "o")]) == 2
    assert "none.csv: file does not exist" in capsys.readouterr().err
    assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "95,8",
                 "--out", str(tmp_path / "o")]) == 2
    assert "--origin: '95,8' is not LAT,LON[,H]" in capsys.readouterr().err
    assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "46.9,8.2",
                 "--sensors", "pos:1@47/8/0", "--out", str(tmp_path / "o")]) == 2
    assert "only a radar takes a site" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit):
        main(["simulate", "traffic", "--help"])
    text = capsys.readouterr().out
    for word in ("baroaltitude", "ft/min", "vertical_rate", "onground", "seconds since 1970", "LAT/LON/H", "NACp"):
        assert word in text or word.lower() in text.lower(), word


@pytest.mark.parametrize(("option", "says"), [
    (["--sensors", "radar:4@0.8528/0.0419/100"], "the site is 5242 km from the box, beyond the radio horizon"),  # rad
    (["--sensors", "radar:4@2.40/48.86/100"], "the site is 6678 km from the box"),  # longitude and latitude swapped
    (["--sensors", "radar:4@49.2/2.0/120000"], ("the site is not LAT/LON/H (expected lat deg in [-90, 90], lon deg "
                                                "in [-180, 360], h m in [-10000, 100000])")),  # 120 m in mm
    (["--origin", "48.86,2.40,120000"], "--origin: '48.86,2.40,120000' is not LAT,LON[,H]")],
    ids=["radians", "swapped", "millimetres", "origin-height"])
def test_a_site_or_origin_in_the_wrong_units_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         option: list[str], says: str) -> None:
    """Before: a site in radians or with latitude and longitude swapped was taken (its radar, thousands of km
    away, gave clutter only, silently); a height out of ``[frame]``'s range was written to config.toml, which
    replay then refused."""
    rows = [f"{k},{icao},{48.86 + 0.01 * i},{2.40 + 0.002 * k},3000" for i, icao in enumerate("abc") for k in range(20)]
    args = {"--origin": "48.86,2.40", "--sensors": "radar:4,pos:2"} | dict([option])
    source = _write_csv(tmp_path / "a.csv", "time,icao24,lat,lon,alt", rows)
    code = main(["simulate", "traffic", "--source", str(source),
                 *[v for item in args.items() for v in item], "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()


def test_tracks_on_the_earth_geojson_and_map(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Replay with a [frame] gives each track lat, lon, alt; export --geojson parses as GeoJSON whose
    lines are the pictures' positions; evaluate --plot --config draws the map."""
    out = tmp_path / "run"
    assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "46.9,8.2",
                 "--sensors", "radar:4@47.3/8.0/900,pos:2", "--seed", "3", "--start", "60", "--duration", "60",
                 "--box", "250", "--out", str(out)]) == 0
    config = out / "config.toml"
    assert main(["replay", "--algorithm", "mtt-federated", "--config", str(config), "--measurements",
                 str(out / "measurements.jsonl"), "--out", str(out / "tracks.jsonl")]) == 0
    pictures = [json.loads(line) for line in (out / "tracks.jsonl").read_text().splitlines()]
    rows = [r for p in pictures for r in p["tracks"]]
    assert rows and all({"lat", "lon", "alt"} <= set(r) for r in rows)
    enu = np.array([np.asarray(r["x"])[[0, 2, 4]] for r in rows])
    flat = np.array([r.get("alt_measured", True) is False for r in rows])  # an altitude not measured: the origin's h
    assert flat.any() and all(r["alt_measured"] is False for r in rows if "alt_measured" in r)
    enu[flat, 2] = level_z(Frame(46.9, 8.2), enu[flat, :2])
    lla = geodetic_from_enu(Frame(46.9, 8.2), enu)  # written to 1e-9 deg and 1e-4 m
    np.testing.assert_allclose([[r["lat"], r["lon"]] for r in rows], lla[:, :2], atol=1e-9)
    np.testing.assert_allclose([r["alt"] for r in rows], lla[:, 2], atol=1e-4)
    geo = tmp_path / "picture.geojson"
    assert main(["export", "--geojson", str(geo), "--config", str(config), "--tracks", str(out / "tracks.jsonl"),
                 "--truth", str(out / "truth.jsonl")]) == 0
    doc = json.loads(geo.read_text())
    assert doc["type"] == "FeatureCollection"
    kinds: dict[str, int] = {}
    for f in doc["features"]:
        assert f["type"] == "Feature" and set(f) == {"type", "geometry", "properties"}
        g = f["geometry"]
        assert g["type"] in ("LineString", "Point")
        points = g["coordinates"] if g["type"] == "LineString" else [g["coordinates"]]
        assert len(points) >= (2 if g["type"] == "LineString" else 1)
        for p in points:  # RFC 7946: [lon, lat(, alt)] in degrees
            assert len(p) in (2, 3) and -180 <= p[0] <= 180 and -90 <= p[1] <= 90
        kinds[f["properties"]["kind"]] = kinds.get(f["properties"]["kind"], 0) + 1
    confirmed = {r["id"] for r in rows if r["status"] == "confirmed"}
    assert kinds["track"] == len(confirmed) and kinds["sensor"] == 1 and kinds["origin"] == 1
    assert kinds["truth"] >= 20
    site = next(f for f in doc["features"] if f["properties"]["kind"] == "sensor")
    assert site["geometry"]["coordinates"] == [8.0, 47.3, 900.0] and site["properties"]["id"] == "r1"
    # a track's line is its confirmed pictures' positions in time order
    tid = min(confirmed)
    line = next(f for f in doc["features"] if f["properties"] == {**f["properties"], "kind": "track", "id": tid})
    mine = [(p["t"], r) for p in pictures for r in p["tracks"] if r["id"] == tid and r["status"] == "confirmed"]
    assert line["properties"]["times"] == [t for t, _ in mine]
    np.testing.assert_allclose(line["geometry"]["coordinates"], [[r["lon"], r["lat"], r["alt"]] for _, r in mine])
    plot = tmp_path / "eval.png"
    figures: list[Figure] = []
    original = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (figures.append(self), original(self, *a, **k)))
    assert main(["evaluate", "--tracks", str(out / "tracks.jsonl"), "--truth", str(out / "truth.jsonl"), "--horizontal",
                 "--plot", str(plot), "--config", str(config)]) == 0
    assert (tmp_path / "eval-map.png").stat().st_size > 10_000
    the_map = figures[-1]  # after evaluate's own plot: titled with the algorithm and the file, no grey track
    assert the_map._suptitle.get_text() == "mtt-federated: tracks.jsonl"
    colours = [matplotlib.colors.to_rgb(line.get_color()) for line in the_map.axes[0].get_lines()]
    grey = [c for c in colours if len({round(v, 3) for v in c}) == 1]
    assert len(grey) == kinds["truth"] and len(colours) == kinds["truth"] + kinds["track"]
    assert "altitude error over the assigned pairs" in capsys.readouterr().out
    assert main(["export", "--geojson", str(geo), "--config", str(out / "none.toml"), "--truth",
                 str(out / "truth.jsonl")]) == 2


@pytest.mark.parametrize(("row", "says"), [
    ('"lat": 95, "lon": 3', "tracks[1]: lat must be in [-90, 90] (degrees), got 95"),
    ('"lat": 1e400, "lon": 3', "tracks[1]: lat must be a finite number, got Infinity"),
    ('"lat": null, "lon": 3', "tracks[1]: lat must be a finite number, got null"),
    ('"lat": 3', "tracks[1]: missing field 'lon'"),
    ('"lat": 3, "lon": 3, "alt": "x"', 'tracks[1]: alt must be a finite number, got "x" (a string)'),
    ('"id": [1]', 'tracks[1]: each needs "id" (a number or a string) and "x"')],
    ids=["lat-95", "lat-inf", "lat-null", "no-lon", "alt-string", "id-list"])
def test_export_geojson_refuses_a_row_off_the_earth_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                 row: str, says: str) -> None:
    """A tracks file's row whose lat, lon, alt are not a place on the Earth, or whose id is no id: exit 2, one line
    naming the file, the line, the row and the field, no GeoJSON written. Before, a lat of 95, null or 1e400 and an alt
    "x" were written into the GeoJSON (exit 0: 1e400 as Infinity, not JSON), and a lat without lon or a list for id
    ended in a traceback."""
    config = tmp_path / "c.toml"
    config.write_text("[frame]\norigin = [46.9, 8.2, 0.0]\n")
    fields = row if row.startswith('"id"') else f'"id": 2, {row}'
    tracks = tmp_path / "t.jsonl"
    tracks.write_text('{"t": 0, "tracks": [{"id": 1, "x": [0, 0, 0, 0]}]}\n'
                      f'{{"t": 1, "tracks": [{{"id": 1, "x": [0, 0, 0, 0]}}, {{{fields}, "x": [1, 2, 3, 4]}}]}}\n')
    geo = tmp_path / "t.geojson"
    assert main(["export", "--geojson", str(geo), "--config", str(config), "--tracks", str(tracks)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and f"t.jsonl:2: {says}" in err, err
    assert not geo.exists()


def test_parquet_reads_as_csv(tmp_path: Path) -> None:
    """Parquet (pyarrow: the ``real`` and ``dev`` extras) gives the CSV's samples."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    src = read_recording(DATA / "traffic_switzerland.csv.gz")
    table = pa.table({"time": src.t, "icao24": src.icao24.tolist(), "lat": src.lla[:, 0], "lon": src.lla[:, 1],
                      "baroaltitude": src.lla[:, 2]})
    pq.write_table(table, tmp_path / "a.parquet")
    again = read_recording(tmp_path / "a.parquet")
    np.testing.assert_array_equal(again.t, src.t)
    np.testing.assert_array_equal(again.lla, src.lla)
    assert np.isnan(again.velocity).all()


def test_sensor_noise_in_the_spec(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``pos:P/SIGMA`` and ``radar:P/SIGMA_R/SIGMA_AZ[/SIGMA_EL]`` set the scans' ``R`` (m, deg, deg;
    the elevation's default 2 mrad); a malformed one is a one-line error naming the item."""
    np.testing.assert_allclose(parse_noise("pos", "106", "pos:2/106"), 106.0**2 * np.eye(2), rtol=1e-15)
    np.testing.assert_allclose(parse_noise("radar", "70/0.08", "radar:4/70/0.08"),
                               np.diag([70.0**2, np.radians(0.08) ** 2, 0.002**2]), rtol=1e-15)
    np.testing.assert_allclose(parse_noise("radar", "70/0.08/0.5", "radar:4/70/0.08/0.5"),
                               np.diag([70.0**2, np.radians(0.08) ** 2, np.radians(0.5) ** 2]), rtol=1e-15)
    assert parse_noise("radar", "", "radar:4") is None
    out = tmp_path / "run"
    assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "46.9,8.2",
                 "--sensors", "radar:4/70/0.08@47.3/8.0/900,pos:2/106,radar:5", "--seed", "2", "--duration", "30",
                 "--box", "250", "--out", str(out)]) == 0
    R = {}
    for line in (out / "measurements.jsonl").read_text().splitlines():
        scan = json.loads(line)
        R.setdefault(scan["sensor"], scan["R"])
    np.testing.assert_allclose(R["r1"], np.diag([70.0**2, np.radians(0.08) ** 2, 0.002**2]), rtol=1e-15)
    np.testing.assert_allclose(R["s2"], 106.0**2 * np.eye(2), rtol=1e-15)
    np.testing.assert_allclose(R["r3"], np.diag([10.0**2, 0.002**2, 0.002**2]), rtol=1e-15)
    assert tomllib.loads((out / "config.toml").read_text())["mtt"]["sensors"] == ["r1", "s2", "r3"]
    capsys.readouterr()
    for spec, message in (("pos:2/0", "'pos:2/0': the noise is pos:P/SIGMA (m), each > 0"),
                          ("radar:4/70@47/8/0", "'radar:4/70': the noise is radar:P/SIGMA_R/SIGMA_AZ[/SIGMA_EL]"),
                          ("adsb:1/5", "'adsb:1/5': an ADS-B receiver takes no noise")):
        assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin",
                     "46.9,8.2", "--sensors", spec, "--out", str(tmp_path / "bad")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_radar_plots_update_the_tracks_2d_plots_started(tmp_path: Path) -> None:
    """A position sensor starts every aircraft's track (``mtt-centralized``, 3-D: z = 0 with
    ``init_z_std`` = 6 km); from 10 s a radar 20-170 km away sees them at 3-11 km up. Its plots update
    those tracks, which take the altitude (sigma under 400 m, the radar's 2 mrad at that range; every
    error within 5 sigma of their own P_zz, the mean squared normalized error under 2), and no second
    track starts. Without relinearizing about the plot's altitude the range at z = 0 is short by about
    z^2 / 2r (tens to hundreds of metres against 10 m of noise): no plot of the radar updated a track,
    and every track kept z = 0 (sigma 7.5 km)."""
    rng = np.random.default_rng(5)
    n = 8
    truth = _cv_truth(n, 90.0, rng)
    sc = Scenario(targets=n, duration=90.0, region=75e3, pd=1.0, clutter=0.0, late=0.0)
    lines = sensor_lines(SensorSpec("s1", "pos", 1.0), sc, truth.x, truth.alive, True, rng, noise=15.0**2 * np.eye(2))
    lines += [item for item in sensor_lines(SensorSpec("r2", "radar", 4.0), sc, truth.x, truth.alive, True, rng)
              if item[1]["t"] >= 10.0]
    lines.sort(key=lambda item: item[0])
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(line) + "\n" for _, line in lines))
    (tmp_path / "c.toml").write_text('[mtt]\nsensors = ["s1", "r2"]\nq = 1.0\ninit_velocity_std = 150.0\n'
                                     'init_z_std = 6000.0\nclutter_density = 1e-9\n')
    replay_mtt("mtt-centralized", tmp_path / "m.jsonl", tmp_path / "c.toml", tmp_path / "t.jsonl")
    normalized = []
    for line in (tmp_path / "t.jsonl").read_text().splitlines():
        picture = json.loads(line)
        if picture["t"] < 30.0:
            continue
        tracks = [tr for tr in picture["tracks"] if tr["status"] == "confirmed"]
        assert len(tracks) == n, f"t = {picture['t']}: {len(tracks)} confirmed tracks of {n} aircraft"
        p = truth.x[int(round(picture["t"] / DT))]
        for tr in tracks:
            x = np.asarray(tr["x"])
            near = np.argmin(np.hypot(p[:, 0] - x[0], p[:, 2] - x[2]))
            sd = np.sqrt(tr["P"][4][4])
            assert sd < 400.0 and abs(x[4] - p[near, 4]) < 5 * sd, (picture["t"], tr["id"], x[4], p[near, 4], sd)
            normalized.append((x[4] - p[near, 4]) / sd)
    assert len(normalized) >= 50 * n and np.mean(np.square(normalized)) < 2.0


def test_a_sensor_slower_than_the_window_does_not_set_the_tracker_keys() -> None:
    """`q`, `max_lag` and `central_timeout` follow the sensors that scan again within the window: one
    slower than it scans once (before, `radar:4,radar:5,pos:1000` over 300 s of the Swiss extract wrote
    q 20,912, max_lag and central_timeout 2,001 s, and mtt-federated's mean GOSPA was 176 m; 111 m now,
    the keys those of the two radars)."""
    from fedtrack.sensors.traffic import derived_tracker

    truth = _cv_truth(3, 100.0, np.random.default_rng(1))
    radars = [SensorSpec("r1", "radar", 4.0), SensorSpec("r2", "radar", 5.0)]
    assert derived_tracker(truth, [*radars, SensorSpec("s3", "pos", 1000.0)], PARIS) == derived_tracker(
        truth, radars, PARIS)
    once = derived_tracker(truth, [SensorSpec("s1", "pos", 1000.0)], PARIS)  # no sensor scans twice: the window
    assert once["max_lag"] == 2 * 100.0 + 1.0


def test_a_window_of_one_truth_step_writes_a_config_that_replays(tmp_path: Path) -> None:
    """``--duration 0.01`` (below the truth's 0.05 s step; ``--start`` within it of the recording's end
    alike): the window's one grid row made its length 0 and ``q`` 0, and ``replay`` refused the config
    ``simulate traffic`` had written ("mtt.q: must be > 0", tour47 session). Now one step."""
    out = tmp_path / "run"
    assert main(["simulate", "traffic", "--source", str(DATA / "traffic_switzerland.csv.gz"), "--origin", "46.9,8.2",
                 "--duration", "0.01", "--out", str(out)]) == 0
    assert tomllib.loads((out / "config.toml").read_text())["mtt"]["q"] > 0.0
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(out / "config.toml"),
                 "--measurements", str(out / "measurements.jsonl"), "--out", str(out / "tracks.jsonl")]) == 0
