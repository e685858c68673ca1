"""A new user's first hour with recorded traffic and the simulators: the ``traffic`` package's own sample
files (pandas JSON) as ``simulate traffic --source``, a southern or western ``--origin``, and option values
no run can use (infinite, or a scan too large for replay to read) as one-line errors."""

from __future__ import annotations

import contextlib
import gzip
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fedtrack.cli import main
from fedtrack.sensors.multitarget import MAX_CLUTTER
from fedtrack.sensors.state_vectors import read_recording

# three aircraft, 40 s of 1 s state vectors in the traffic package's columns and units (ft, kt, ft/min, ms)
T0_MS = 1_600_000_000_000


def _records(seconds: int = 40) -> list[dict]:
    rows = []
    for k, icao in enumerate(("3c6444", "4b1805", "39b415")):
        for i in range(seconds):
            rows.append({"timestamp": T0_MS + 1000 * i, "icao24": icao, "latitude": -33.9 + 0.01 * k + 0.0005 * i,
                         "longitude": 151.2 - 0.01 * k, "altitude": 10000.0 + 100 * k, "groundspeed": 108.0,
                         "track": 0.0, "vertical_rate": 0.0, "onground": False, "callsign": f"TEST{k}"})
    return rows


def _csv(path: Path, rows: list[dict]) -> Path:
    cols = list(rows[0])
    path.write_text(",".join(cols) + "\n" + "".join(",".join(str(r[c]) for c in cols) + "\n" for r in rows))
    return path


@pytest.mark.parametrize("orient", ["records", "columns"])
def test_the_traffic_packages_sample_json_reads_as_its_csv(tmp_path: Path, orient: str) -> None:
    """Every sample the ``traffic`` package ships is pandas' ``to_json`` (an array of rows, or an object of
    columns by row label), gzipped: it was refused as an unknown format."""
    rows = _records()
    table = rows if orient == "records" else {c: {str(i): r[c] for i, r in enumerate(rows)} for c in rows[0]}
    sample = tmp_path / "sample.json.gz"
    with gzip.open(sample, "wt") as fh:
        json.dump(table, fh)
    plain = tmp_path / "sample.json"
    plain.write_text(json.dumps(table))
    want = read_recording(_csv(tmp_path / "sample.csv", rows), "aviation")
    for path in (sample, plain):
        got = read_recording(path, "aviation")
        assert list(got.icao24) == list(want.icao24)
        np.testing.assert_array_equal(got.t, want.t)
        np.testing.assert_array_equal(got.lla, want.lla)
        np.testing.assert_array_equal(got.velocity, want.velocity)


def test_a_sample_runs_through_simulate_replay_evaluate_and_export(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    sample = tmp_path / "sample.json.gz"
    with gzip.open(sample, "wt") as fh:
        json.dump(_records(), fh)
    out = tmp_path / "S"
    # a southern and eastern origin written as a user would, with a space: argparse took "-33.9,..." for an option
    assert main(["simulate", "traffic", "--source", str(sample), "--origin", "-33.89,151.19", "--units", "aviation",
                 "--sensors", "pos:2/20", "--clutter", "0", "--late", "0", "--seed", "1", "--out", str(out)]) == 0
    assert "read " in capsys.readouterr().out
    tracks = tmp_path / "c.jsonl"
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(out / "config.toml"),
                 "--measurements", str(out / "measurements.jsonl"), "--out", str(tracks)]) == 0
    assert main(["evaluate", "--tracks", str(tracks), "--truth", str(out / "truth.jsonl"), "--horizontal",
                 "--json", str(tmp_path / "e.json")]) == 0
    assert json.loads((tmp_path / "e.json").read_text())["mean"]["gospa"] < 40.0
    assert main(["export", "--geojson", str(tmp_path / "g.geojson"), "--config", str(out / "config.toml"),
                 "--tracks", str(tracks), "--truth", str(out / "truth.jsonl")]) == 0
    lats = [c[1] for f in json.loads((tmp_path / "g.geojson").read_text())["features"]
            if f["properties"]["kind"] == "truth" for c in f["geometry"]["coordinates"]]
    assert lats and all(-33.95 < lat < -33.85 for lat in lats)


def test_a_southern_western_origin_given_with_a_space(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--origin -33.89,-151.19`` failed with 'argument --origin: expected one argument'."""
    rows = [{**r, "longitude": -r["longitude"]} for r in _records()]
    assert main(["simulate", "traffic", "--source", str(_csv(tmp_path / "s.csv", rows)), "--origin", "-33.89,-151.19",
                 "--units", "aviation", "--sensors", "pos:2", "--out", str(tmp_path / "o")]) == 0
    assert "3 aircraft" in capsys.readouterr().out


@pytest.mark.parametrize("content", [{"name": "SIV TOULOUSE", "shapes": [{"upper": 65.0}]},  # an airspace
                                     {"result": {"request": {}, "response": {"timestamp": 1704724122}}}],  # fr24
                         ids=["airspace", "flightradar24"])
def test_json_that_is_not_a_table_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              content: dict) -> None:
    bad = tmp_path / "airspace.json"
    bad.write_text(json.dumps(content))
    code = main(["simulate", "traffic", "--source", str(bad), "--origin", "43.6,1.4", "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and f"{bad}: not a table of state vectors" in err[0], err
    assert not (tmp_path / "o").exists()


BAD_VALUES = [
    (["simulate", "traffic", "--box", "inf"], "--box: must be finite and > 0, got inf"),
    (["simulate", "traffic", "--clutter", "inf"], f"--clutter: must be in [0, {MAX_CLUTTER:.0f}], got inf"),
    (["simulate", "traffic", "--clutter", "1e9"], f"--clutter: must be in [0, {MAX_CLUTTER:.0f}], got 1e+09"),
    (["simulate", "traffic", "--duration", "inf"], "--duration: must be finite and > 0, got inf"),
    (["simulate", "traffic", "--sensors", "pos:inf"], "'pos:inf' is not KIND:PERIOD"),
    (["simulate", "multitarget", "--clutter", "inf"], f"--clutter: must be in [0, {MAX_CLUTTER:.0f}], got inf"),
    (["simulate", "multitarget", "--clutter", "1e9"], f"--clutter: must be in [0, {MAX_CLUTTER:.0f}], got 1e+09"),
    (["simulate", "multitarget", "--duration", "inf"], "--duration: must be finite and > 0, got inf"),
    (["simulate", "multitarget", "--sensors", "pos:inf"], "'pos:inf' is not KIND:PERIOD"),
    (["simulate", "multitarget", "--sensors", "pos:1e-9"], "PERIOD a finite number of seconds >= 0.05"),
]


@pytest.mark.parametrize(("argv", "says"), BAD_VALUES, ids=lambda v: " ".join(v) if isinstance(v, list) else "")
def test_values_no_run_can_use_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   argv: list[str], says: str) -> None:
    """Before: tracebacks (OverflowError, ValueError 'lam value too large'), or at --clutter 1e9 or a period of
    1e-9 s the memory of the machine (killed)."""
    extra = (["--source", str(_csv(tmp_path / "s.csv", _records())), "--origin", "-33.89,151.19", "--units",
              "aviation"] if argv[1] == "traffic" else [])
    code = main([*argv, *extra, "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()


def launch_config(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str) -> tuple[int, list[str], bool]:
    """``launch`` of a config ``text``: (its exit code, its stderr lines, whether it made the output folder)."""
    config = tmp_path / "c.toml"
    config.write_text(text)
    code = main(["launch", str(config), "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, err, (tmp_path / "o").exists()


@pytest.mark.parametrize(("table", "says"), [("clutter = inf", "multitarget.clutter: must be in [0, "),
                                             ("duration = inf", "multitarget.duration: must be finite and > 0"),
                                             ('source = "x.csv"\norigin = [1.0, 2.0, 0.0]\nbox = inf',
                                              "a finite box > 0"),
                                             ('source = "x.csv"\norigin = [48.86, 2.4, 200000.0]',
                                              "multitarget.origin: expected lat deg in [-90, 90], lon deg in "
                                              "[-180, 360], h m in [-10000, 100000]")])
def test_launch_refuses_a_multitarget_value_out_of_range(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         table: str, says: str) -> None:
    """Infinite values; the origin 200 km up (before 2026-11-27 the run went ahead and wrote a config.toml whose
    [frame] origin replay then refused)."""
    code, err, made = launch_config(tmp_path, capsys, f'[deployment]\npacing = "realtime"\n\n[multitarget]\n{table}\n')
    assert code == 2 and len(err) == 1 and says in err[0] and not made, err


@pytest.fixture(scope="module")
def small_replay(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 3-target, 5 s simulation and its ``mtt-centralized`` pictures: (the simulation's folder, the pictures)."""
    out = tmp_path_factory.mktemp("small") / "S"
    assert main(["simulate", "multitarget", "--targets", "3", "--duration", "5", "--out", str(out)]) == 0
    tracks = out.parent / "c.jsonl"
    assert main(["replay", "--algorithm", "mtt-centralized", "--config", str(out / "config.toml"),
                 "--measurements", str(out / "measurements.jsonl"), "--out", str(tracks)]) == 0
    return out, tracks


@pytest.mark.parametrize(("option", "says"), [(["--c", "inf"], "--c must be finite and > 0"),
                                              (["--p", "inf"], "--p finite and >= 1"),
                                              (["--p", "200"], "c^p overflows"),
                                              (["--c", "1e300"], "c^p overflows")])
def test_evaluate_refuses_a_cut_off_or_order_whose_power_is_not_finite(tmp_path: Path, small_replay: tuple[Path, Path],
                                                                      capsys: pytest.CaptureFixture[str],
                                                                      option: list[str], says: str) -> None:
    """Before: --c inf printed 'mean GOSPA nan m' with exit 0; --p inf, --p 200 and --c 1e300 were tracebacks
    (scipy: 'cost matrix is infeasible')."""
    out, tracks = small_replay
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", "--tracks", str(tracks), "--truth", str(out / "truth.jsonl"), *option,
              "--json", str(tmp_path / "e.json")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and says in err and "Traceback" not in err, err
    assert not (tmp_path / "e.json").exists()


SEEDED = [["simulate", "multitarget"], ["simulate", "traffic", "--origin", "48.86,2.4"], ["train", "ts-fuzzy"],
          ["reproduce", "fvdie", "--json", "a.json"], ["demo"], ["bench", "pipeline"], ["bench", "hpda-soak"],
          ["serve", "sensor"]]


@pytest.mark.parametrize("argv", SEEDED, ids=" ".join)
def test_a_negative_seed_is_refused_before_anything_is_written(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                               monkeypatch: pytest.MonkeyPatch,
                                                               argv: list[str]) -> None:
    """Before: numpy's 'ValueError: expected non-negative integer' as a traceback, after simulate multitarget had
    made its --out folder."""
    monkeypatch.chdir(tmp_path)
    extra = {"simulate": ["--out", "o"], "train": ["--out", "m.npz"], "demo": ["--out", "o"]}.get(argv[0], [])
    source = ["--source", str(_csv(tmp_path / "s.csv", _records()))] if argv[1:2] == ["traffic"] else []
    with pytest.raises(SystemExit) as exit_:
        main([*argv, *source, *extra, "--seed", "-1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "argument --seed: must be a whole number >= 0, got '-1'" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == (["s.csv"] if source else [])


@pytest.mark.parametrize(("table", "says"), [("seed = -1", "deployment.seed: must be a whole number >= 0"),
                                             ("duration_s = inf", "deployment.duration_s: must be finite and > 0"),
                                             ("speed = inf", "deployment.speed: must be finite and > 0")])
def test_launch_refuses_a_negative_seed_or_an_endless_run(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          table: str, says: str) -> None:
    """Before: the services started, then a traceback (numpy's seed; OverflowError of an infinite duration)."""
    code, err, made = launch_config(tmp_path, capsys, f'[deployment]\n{table}\n\n[[sensor]]\nid = "1"\n')
    assert code == 2 and len(err) == 1 and says in err[0] and not made, err


def test_reproduce_with_one_run_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: 'ValueError: --runs must be at least 2' as a traceback, exit 1."""
    code = main(["reproduce", "fvdie", "--runs", "1", "--json", str(tmp_path / "a.json")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and err == ["fedtrack: error: --runs: must be at least 2 (standard errors need two runs), got 1"]
    assert not (tmp_path / "a.json").exists()


@pytest.mark.parametrize("argv", [["--source", "x.csv"], ["--scenario", "traffic", "--source", "missing.csv"],
                                  ["--units", "aviation"], ["--scenario", "multitarget", "--sensors", "5"]],
                         ids=" ".join)
def test_demo_input_errors_leave_no_output_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                  argv: list[str]) -> None:
    """Before: the demo made --out, then failed (an empty folder left behind); --sensors was ignored by the
    multitarget and traffic scenarios (a live run with their own three sensors)."""
    with contextlib.suppress(SystemExit):
        main(["demo", *argv, "--out", str(tmp_path / "o")])
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_demo_refuses_units_without_a_source(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """``demo --scenario traffic --units aviation`` without ``--source`` read the committed Paris extract (in si
    units: m, m/s) as ft and kt, altitudes 0.3048 of the truth's, and ran the whole deployment on it (before
    tour57); ``--units`` is the units of ``--source`` (README: ``[--source FILE [--units si|aviation]]``)."""
    from fedtrack.deploy import demo

    def started(*args: object, **kwargs: object) -> None:
        raise AssertionError("the demo went on to simulate the extract")
    monkeypatch.setattr(demo, "traffic_settings", started)
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--scenario", "traffic", "--units", "aviation", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert "--units applies to --source FILE only (the committed Paris extract is in si units)" in \
        capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_launch_refuses_a_frame_other_than_the_recordings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A recording's scenario is simulated in ``[multitarget] origin``'s frame and the services place tracks
    (lat, lon) and ``lat_lon`` regions in ``[frame] origin``'s: 98 km apart here, taken without a word before
    2026-11-27."""
    code, err, made = launch_config(tmp_path, capsys, '[deployment]\npacing = "realtime"\n\n[multitarget]\n'
                                    'source = "x.csv"\norigin = [48.878, 2.423, 0.0]\n\n[frame]\n'
                                    'origin = [48.0, 2.423, 0.0]\n')
    says = "frame.origin: [48.0, 2.423, 0.0] is not multitarget.origin [48.878, 2.423, 0.0]"
    assert code == 2 and len(err) == 1 and says in err[0] and not made, err


@pytest.mark.parametrize(("source", "says"), [("missing.csv", "multitarget.source: missing.csv: file does not exist"),
                                              ("far", "multitarget.source: no airborne aircraft inside the box")])
def test_launch_names_the_recordings_key_and_leaves_no_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              source: str, says: str) -> None:
    """A ``[multitarget] source`` that is missing, or whose window holds no aircraft about ``origin``: the error named
    neither the config nor the key, and the output folder the launch had made was left behind, empty (tour61)."""
    path = source if source == "missing.csv" else str(_csv(tmp_path / "s.csv", _records()))
    code, err, made = launch_config(tmp_path, capsys, f'[deployment]\npacing = "realtime"\n\n[multitarget]\n'
                                    f'source = "{path}"\nunits = "aviation"\norigin = [30.0, 2.0, 0.0]\n')
    assert code == 2 and len(err) == 1 and f"{tmp_path / 'c.toml'}: {says}" in err[0] and not made, err
    if source == "far":  # the keys a launch takes, not simulate traffic's --origin / --box (before tour62)
        assert err[0].endswith(": move multitarget.origin, widen multitarget.box or change multitarget.start / "
                               "multitarget.duration") and "--" not in err[0], err


@pytest.mark.parametrize("frame", ["", "\n[frame]\norigin = [-33.88, 151.19, 0.0]\n"], ids=["window", "frame"])
def test_launch_derives_a_recordings_origin_as_simulate_traffic(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                frame: str) -> None:
    """``[multitarget] source`` without ``origin`` was refused at start ("source: needs origin = [lat, lon, h]"),
    while ``simulate traffic`` and the demo take the median position of the window's airborne samples (tour61). Now
    ``launch`` takes ``[frame] origin`` (the tracks' frame) when given, else the window's, and says which."""
    import tomllib

    from fedtrack.deploy.multitarget import prepare
    from fedtrack.deploy.settings import check_launchable, load_settings

    source = _csv(tmp_path / "s.csv", _records())
    config = tmp_path / "mt.toml"
    config.write_text(f'[deployment]\npacing = "realtime"\n\n[multitarget]\nsource = "{source}"\nunits = "aviation"\n'
                      f'sensors = "pos:2"\nduration = 30.0\n{frame}')
    settings = load_settings(config)
    check_launchable(settings, config)
    prepare(settings, tmp_path / "o")
    origin = tomllib.loads((tmp_path / "o" / "scenario" / "config.toml").read_text())["frame"]["origin"]
    err = capsys.readouterr().err
    if frame:
        assert origin == [-33.88, 151.19, 0.0] and "origin" not in err.splitlines()[0], err
    else:
        lat = [r["latitude"] for r in _records() if r["timestamp"] <= T0_MS + 30_000]
        assert origin == pytest.approx([float(np.median(lat)), 151.19, 0.0])
        assert err.startswith(f"scenario: origin {np.median(lat):.6f},151.190000: the median position of the "
                              "window's airborne samples"), err


def test_demo_and_launch_read_a_recording_in_aviation_units(tmp_path: Path) -> None:
    """The traffic library's samples are in ft, kt and ft/min: ``demo --scenario traffic --source`` read them as
    m and m/s (aircraft 3.28 times higher than recorded), with no way to say otherwise."""
    from fedtrack.deploy.demo import traffic_settings

    sample = tmp_path / "sample.json.gz"
    with gzip.open(sample, "wt") as fh:
        json.dump(_records(120), fh)  # the demo starts 60 s into a recording
    settings = traffic_settings(sample, "federated", 1, 7447, tmp_path, None, "aviation")
    assert settings.multitarget is not None and settings.multitarget.units == "aviation"
    alts = [t["alt"] for line in (tmp_path / "scenario" / "truth.jsonl").read_text().splitlines()
            for t in json.loads(line)["targets"]]
    assert alts and min(alts) == pytest.approx(3048.0, abs=1.0) and max(alts) == pytest.approx(3108.96, abs=1.0)
    config = tmp_path / "mt.toml"
    config.write_text('[deployment]\npacing = "realtime"\n\n[multitarget]\nunits = "feet"\n')
    assert main(["launch", str(config), "--out", str(tmp_path / "o")]) == 2


def _long_haul(tmp_path: Path) -> tuple[Path, np.ndarray]:
    """One aircraft flying due north at 200 m/s for two hours, a sample every 10 s (1,440 km, as the traffic
    package's long-haul samples), gzipped pandas JSON in ft and kt; and its latitudes."""
    lat = 40.0 + 0.018 * np.arange(720)  # 2,001 m a sample
    rows = [{"timestamp": T0_MS + 10_000 * i, "icao24": "3c6444", "latitude": round(float(la), 6), "longitude": 10.0,
             "altitude": 30000.0, "groundspeed": 389.0, "track": 0.0, "vertical_rate": 0.0, "onground": False}
            for i, la in enumerate(lat)]
    sample = tmp_path / "long.json.gz"
    with gzip.open(sample, "wt") as fh:
        json.dump(rows, fh)
    return sample, lat


def test_the_demo_centres_a_long_recording_on_its_window(tmp_path: Path) -> None:
    """``demo --scenario traffic --source`` centred its 150 km box on the whole recording's median position and ran
    600 s from 60 s after its first sample: for a long flight the aircraft were hundreds of km away then, and the
    demo was refused ("no airborne aircraft inside the box", naming options it does not have) on 20 of the traffic
    package's 73 ``.json.gz`` samples (``featured/elal747``: 1,730 km; ``collections/savan``,
    ``noisy/noisy_time_issue``: 490 and 780 km; before earth60)."""
    from fedtrack.deploy.demo import TRAFFIC_DURATION, TRAFFIC_START, traffic_settings

    sample, lat = _long_haul(tmp_path)
    settings = traffic_settings(sample, "federated", 1, 7447, tmp_path, None, "aviation")
    assert settings.multitarget is not None and settings.multitarget.origin is not None
    in_window = lat[(np.arange(720) * 10 >= TRAFFIC_START) & (np.arange(720) * 10 <= TRAFFIC_START + TRAFFIC_DURATION)]
    assert settings.multitarget.origin == pytest.approx((float(np.median(in_window)), 10.0, 0.0), abs=1e-9)
    truth = [json.loads(line)["targets"] for line in (tmp_path / "scenario" / "truth.jsonl").read_text().splitlines()]
    assert len(truth) == TRAFFIC_DURATION + 1 and all(len(t) == 1 for t in truth)


def test_simulate_traffic_without_an_origin_centres_on_the_window(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--origin`` was required (exit 2 without it); now it defaults to the median position of the window's
    airborne samples, as the demo's, and says so."""
    import tomllib

    sample, lat = _long_haul(tmp_path)
    out = tmp_path / "o"
    assert main(["simulate", "traffic", "--source", str(sample), "--units", "aviation", "--start", "3600",
                 "--duration", "300", "--sensors", "pos:2", "--out", str(out)]) == 0
    median = float(np.median(lat[360:391]))  # the samples 3,600-3,900 s after the first
    assert f"origin {median:.6f},10.000000: the median position of the window's airborne samples" in \
        capsys.readouterr().out
    assert tomllib.loads((out / "config.toml").read_text())["frame"]["origin"] == pytest.approx([median, 10.0, 0.0])
    truth = [json.loads(line)["targets"] for line in (out / "truth.jsonl").read_text().splitlines()]
    assert len(truth) == 301 and all(len(t) == 1 for t in truth)


@pytest.mark.parametrize("period", ["inf", "1e300"])
def test_a_picture_period_beyond_an_hour_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    period: str) -> None:
    """Before: exit 0 with a picture at "t": null (inf) or at 1e300 s with infinite coordinates, which evaluate then
    refused."""
    out = tmp_path / "S"
    assert main(["simulate", "multitarget", "--targets", "3", "--duration", "5", "--out", str(out)]) == 0
    capsys.readouterr()
    code = main(["replay", "--algorithm", "mtt-federated", "--config", str(out / "config.toml"), "--measurements",
                 str(out / "measurements.jsonl"), "--out", str(tmp_path / "p.jsonl"), "--period", period])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and err == [f"fedtrack: error: --period: must be <= 3600 s (a picture predicts the tracks up to "
                                 f"a period past their last scan), got {float(period):g}"], err
    assert not (tmp_path / "p.jsonl").exists()


@pytest.mark.parametrize("script", ["sensor_publisher.py", "track_subscriber.py"])
def test_the_examples_help_gives_every_options_meaning_and_default(script: str) -> None:
    """Before: --scans, --seed and --lockstep-timeout had no help, no option showed its default, and --deployment
    defaulted to "default" while a deployment's name defaults to "demo"."""
    path = Path(__file__).resolve().parent.parent / "examples" / script
    text = subprocess.run([sys.executable, str(path), "--help"], capture_output=True, text=True, timeout=60,
                          check=True).stdout
    options = re.findall(r"^  (--[a-z-]+)", text, re.M)
    assert len(options) >= 4
    for option in options:
        entry = re.search(rf"^  {option}\b(.*?)(?=^  -|\Z)", text, re.M | re.S)
        assert entry and "default:" in entry.group(1), (option, text)
    assert "default: demo" in text


def test_no_aircraft_in_the_box_says_where_the_recording_is(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: 'no airborne aircraft inside the box during the window' and nothing more (18 of the traffic
    package's samples with an origin at their median position and the first 20 minutes)."""
    source = _csv(tmp_path / "s.csv", _records())
    code = main(["simulate", "traffic", "--source", str(source), "--origin", "30,2", "--units", "aviation",
                 "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err
    assert "(box 100 km about 30, 2; window 0 s to the end after the first sample)" in err[0]
    assert "latitudes -33.9 to -33.8605, longitudes 151.18 to 151.2" in err[0]
    # where the window's aircraft are, as --origin defaults to (earth60): 17,000 km away
    assert "; the window's median position is -33.8803, 151.1900, 17077 km from the origin" in err[0]
    assert not (tmp_path / "o").exists()


def test_tracks_cut_to_single_samples_by_max_gap_are_named_as_the_cause(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``--max-gap 0.5`` on 1 s state vectors cut every aircraft's track into tracks of one sample, all left
    out: the error said only that no aircraft was inside the box and advised moving the origin or the box,
    which were right (tour47 session). Now it names the samples left out and ``--max-gap``."""
    source = _csv(tmp_path / "s.csv", _records())
    argv = ["simulate", "traffic", "--source", str(source), "--origin", "-33.9,151.2", "--units", "aviation",
            "--out", str(tmp_path / "o")]
    assert main([*argv, "--max-gap", "0.5"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "120 samples inside the box left out as tracks of one sample" in err[0], err
    assert "raise --max-gap above the recording's sampling interval" in err[0]
    assert main(argv) == 0 and not capsys.readouterr().err  # the same box and window, the default gap
    assert (tmp_path / "o" / "config.toml").exists()


def test_a_wrong_origin_is_not_told_to_raise_max_gap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A recording with one lone sample (a track of one sample) far from its aircraft, and an origin where none is:
    the error advised raising --max-gap, which cannot put an aircraft into an empty box (tour61). Now only samples of
    one sample inside the box and window name --max-gap."""
    lone = {**_records()[0], "icao24": "aaaaaa", "latitude": 10.0, "longitude": 10.0}
    source = _csv(tmp_path / "s.csv", [*_records(), lone])
    code = main(["simulate", "traffic", "--source", str(source), "--origin", "30,2", "--units", "aviation",
                 "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err
    assert "--max-gap" not in err[0] and err[0].endswith("from the origin: move --origin, widen --box or change "
                                                         "--start / --duration"), err


def test_a_frozen_position_is_named_as_the_cause(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The traffic package's ``noisy/noisy_spoofing`` holds one position for hours (a spoofed report): each repeat is
    left out as stale, and the window about it was refused saying the box was right ("0 km from the origin") and
    advising --max-gap, --origin and --box, none of which help (tour61). Now it names the frozen position."""
    rows = [{**row, "latitude": -33.9, "longitude": 151.2} for row in _records()[:40]]  # one aircraft, 40 s, frozen
    source = _csv(tmp_path / "s.csv", rows)
    code = main(["simulate", "traffic", "--source", str(source), "--units", "aviation", "--start", "10",
                 "--out", str(tmp_path / "o")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err
    assert ("0 km from the origin; its 30 samples inside the box are 1 frozen position, each aircraft's samples "
            "repeating one (a spoofed or stuck report; a repeated position is left out as stale): change --start / "
            "--duration to a window where the aircraft move") in err[0], err
    assert "--max-gap" not in err[0]


def test_version_into_a_closed_pipe_ends_quietly() -> None:
    """``fedtrack --version | true``: was a BrokenPipeError traceback, exit 1 (--version prints while the command
    line is parsed, outside the closed-pipe handling)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "--version"], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr == "", proc.stderr


@pytest.mark.parametrize("argv", [["serve", "router", "--listen", "tcp/127.0.0.1:99999"],
                                  ["serve", "recorder", "--connect", "tcp/127.0.0.1:70000", "--db", "r.db"],
                                  ["serve", "sensor", "--connect", "tcp/127.0.0.1:0"]], ids=lambda a: a[1])
def test_an_endpoint_port_out_of_range_is_named_as_such(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        monkeypatch: pytest.MonkeyPatch, argv: list[str]) -> None:
    """Before: 'tcp/127.0.0.1:99999 is off loopback and not tls/ ...: give --insecure', and with --insecure the
    router started and logged Zenoh's 'invalid port value'."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "not PROTO/HOST:PORT with a port in 1-65535" in err and "loopback" not in err, err


@pytest.mark.parametrize("option", [["--out", "missing/o"], ["--db", "missing/r.db"]], ids=lambda a: a[0])
def test_serve_recorder_checks_its_outputs_before_it_connects(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              option: list[str]) -> None:
    """Before: it connected first (a timeout without a router) and then made the missing folders above --out."""
    monkeypatch.chdir(tmp_path)
    code = main(["serve", "recorder", "--connect", "tcp/127.0.0.1:9", "--connect-timeout", "0.5", *option])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "the folder missing does not exist" in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_export_geojson_names_a_truth_file_given_as_tracks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: 'expected {"t": number, "tracks": [...]}' (evaluate said which option the file belongs to; export
    had its own copy of the check without it)."""
    out = tmp_path / "S"
    assert main(["simulate", "traffic", "--source", str(_csv(tmp_path / "s.csv", _records())),
                 "--origin=-33.89,151.19", "--units", "aviation", "--sensors", "pos:2", "--out", str(out)]) == 0
    capsys.readouterr()
    code = main(["export", "--geojson", str(tmp_path / "g.geojson"), "--config", str(out / "config.toml"),
                 "--tracks", str(out / "truth.jsonl")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and err == [f"fedtrack: error: {out / 'truth.jsonl'}:1: has \"targets\" where \"tracks\" is "
                                 "expected: give the truth file to --truth"], err
    assert not (tmp_path / "g.geojson").exists()


def test_evaluate_config_without_plot_is_refused(tmp_path: Path, small_replay: tuple[Path, Path],
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Before: --config without --plot was never read (a missing file, or one with errors, passed unnoticed)."""
    out, tracks = small_replay
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", "--tracks", str(tracks), "--truth", str(out / "truth.jsonl"), "--config",
              str(tmp_path / "missing.toml"), "--json", str(tmp_path / "e.json")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--config applies with --plot" in err, err
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("argv", [["bench", "soak", "--minutes", "inf"], ["bench", "hpda-soak", "--minutes", "inf"],
                                  ["bench", "hpda-soak", "--rate", "inf"]], ids=" ".join)
def test_an_endless_soak_is_refused_at_start(capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    """Before: soak ran a deployment that failed and said '/tmp/...: summary.json: No such file or directory';
    hpda-soak raised OverflowError in a thread and hung."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "must be finite" in err and "Traceback" not in err, err


def test_launch_on_a_recording_runs_the_keys_simulate_traffic_derives(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """``launch`` with ``[multitarget] source`` ran the file's own ``[mtt]`` (the defaults when absent) and
    ``[frame]`` (no radar sites), not the keys ``simulate traffic`` derives for the recording (q, pd, the clutter
    densities, the sites, ...; launchtraffic62: Paris, 60 s, GOSPA 136 m live against 81 m replayed). Now every key
    the file does not set is the derived one, the file's own win (key by key in an ``[mtt.sensor.<id>]`` table), the
    services read them and it says which it derived."""
    import tomllib

    from fedtrack.deploy.demo import free_port
    from fedtrack.deploy.launcher import prepare_launcher
    from fedtrack.deploy.settings import load_settings

    source = _csv(tmp_path / "s.csv", _records())
    config = tmp_path / "mt.toml"
    config.write_text(f'[deployment]\npacing = "realtime"\nrouter_listen = "tcp/127.0.0.1:{free_port()}"\n\n'
                      f'[multitarget]\nsource = "{source}"\nunits = "aviation"\nsensors = "radar:4,pos:3"\n'
                      'duration = 30.0\npd = 0.8\n\n[mtt]\nmax_lag = 9.5\n\n[mtt.sensor.s2]\nclutter_density = 1e-9\n')
    launcher = prepare_launcher(load_settings(config), config, tmp_path / "o", quiet=True)
    scene = tomllib.loads((tmp_path / "o" / "scenario" / "config.toml").read_text())
    centre = next(sp for sp in launcher.plan if sp.role == "mtt-centre")
    ran = tomllib.loads(Path(centre.argv[centre.argv.index("--config") + 1]).read_text())
    mtt = scene["mtt"]
    assert {k: v for k, v in ran["mtt"].items() if k not in ("max_lag", "sensor")} == {
        k: v for k, v in mtt.items() if k not in ("max_lag", "sensor")}
    assert mtt["max_lag"] != 9.5 and ran["mtt"]["max_lag"] == 9.5 and ran["mtt"]["pd"] == 0.8
    assert ran["mtt"]["sensor"] == {"r1": mtt["sensor"]["r1"], "s2": {**mtt["sensor"]["s2"], "clutter_density": 1e-9}}
    assert ran["frame"] == scene["frame"] and set(ran["frame"]["sites"]) == {"r1"}
    assert ran["multitarget"]["source"] == str(source) and launcher.settings.mtt.q == mtt["q"]
    assert ran == tomllib.loads((tmp_path / "o" / "config.toml").read_text())  # replay --config OUT/config.toml's
    said = [line for line in capsys.readouterr().err.splitlines() if "tracker keys derived" in line]
    assert said and "mtt.q, " in said[0], said
    assert "mtt.sensor.r1, mtt.sensor.s2.noise_floor, frame.origin, frame.sites" in said[0], said
    assert "max_lag" not in said[0], said
    assert "mtt.clutter_density, " in said[0] and "s2.clutter_density" not in said[0]
