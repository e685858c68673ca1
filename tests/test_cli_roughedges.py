"""Issue 28's rough edges of simulate / replay / evaluate / export, one test per item (4-10): input
errors that say what would be right, outputs written whole or not at all, no folder created,
a closed pipe, the final picture, evaluate's maneuver rates and plot (item 5, every option's help and
README row: tests/test_docs_contract.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fedtrack.cli import main
from fedtrack.jsonl import InputError

README = Path(__file__).resolve().parent.parent / "README.md"
TRAFFIC = README.parent / "tests" / "data" / "traffic_paris.csv.gz"
R2 = [[100.0, 0.0], [0.0, 100.0]]
R3 = [[100.0, 0.0, 0.0], [0.0, 1e-6, 0.0], [0.0, 0.0, 1e-6]]


def scan(t: float, sensor: str = "s1", **extra: object) -> dict:
    return {"t": t, "sensor": sensor, "R": R2, "detections": [{"z": [100.0 * t, 50.0]}], **extra}


def write_lines(path: Path, rows: list[dict]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def one_line_error(capsys: pytest.CaptureFixture[str], code: int) -> str:
    """The single stderr line of a command that failed with exit 2."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (code, err)
    return lines[0]


# --- item 4: input problems: exit 2, one line naming file, line and field, saying what is right

RADAR_SWITCH = [scan(0.0), scan(1.0), {**scan(2.0), "R": R3, "sensor_position": [0.0, 0.0, 0.0],
                                       "detections": [{"z": [1000.0, 0.1, 0.1]}]}]
BAD_LINES = {  # name -> (lines of the file, what the error must say)
    "radar without sensor_position": ([{**scan(0.0), "R": R3, "detections": [{"z": [1000.0, 0.1, 0.1]}]}],
                                      ":1: R is 3x3 but the line has no sensor_position: a radar scan needs "
                                      "sensor_position"),
    "null": ([{**scan(0.0), "detections": [{"z": [None, 0.4]}]}],
             ":1: detections[0].z[0] must be a finite number, got null"),
    "string NaN": ([{**scan(0.0), "detections": [{"z": ["NaN", 0.4]}]}],
                   ':1: detections[0].z[0] must be a finite number, got "NaN" (a string)'),
    "field near miss": ([{**scan(0.0), "sensor_positon": [0.0, 0.0, 0.0]}],
                        ":1: unknown field 'sensor_positon': did you mean sensor_position?"),
    "a sensor switching to radar": (RADAR_SWITCH, ":3: sensor 's1' sent 2-D position scans (line 1) and now a "
                                                  "radar (sensor_position) scan"),
}


@pytest.mark.parametrize("case", sorted(BAD_LINES))
def test_bad_scan_lines_say_what_is_wrong_and_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                            case: str) -> None:
    rows, expected = BAD_LINES[case]
    path = write_lines(tmp_path / "m.jsonl", rows)
    out = tmp_path / "out.jsonl"
    code = main(["replay", "--algorithm", "mtt-federated", "--measurements", str(path), "--out", str(out)])
    assert f"{path}{expected}" in one_line_error(capsys, code)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.jsonl"]  # no output, no temporary file


@pytest.mark.parametrize("algorithm", ["kf", "fsimm", "hpda", "ekf"])
def test_a_number_of_too_many_digits_is_an_input_error(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        algorithm: str) -> None:
    """An integer of more digits than Python converts (4,300) was a ValueError traceback, exit 1."""
    path = tmp_path / "m.jsonl"
    path.write_text('{"t": 1' + "0" * 5000 + ', "sensor": "s1", "z": [1, 0], "R": [[1, 0], [0, 1]]}\n')
    code = main(["replay", "--algorithm", algorithm, "--measurements", str(path), "--out", str(tmp_path / "o.jsonl")])
    assert f"{path}:1: invalid JSON: a number of more than {sys.get_int_max_str_digits()} digits" in \
        one_line_error(capsys, code)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.jsonl"]


def test_nan_token_names_line_and_column(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "m.jsonl"
    line = '{"t": 1.0, "sensor": "s1", "R": [[1, 0], [0, 1]], "detections": [{"z": [nan, 0.4]}]}'
    path.write_text(json.dumps(scan(0.0)) + "\n" + line + "\n")
    code = main(["replay", "--algorithm", "mtt-local", "--sensor", "s1", "--measurements", str(path),
                 "--out", str(tmp_path / "o.jsonl")])
    assert (f"{path}:2: invalid JSON at column {line.index('nan') + 1}: Expecting value (nan and infinity are not "
            "JSON numbers: a finite number is expected)") in one_line_error(capsys, code)


def test_a_sensor_with_no_scan_names_the_files_sensors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``replay --algorithm mtt-local --sensor s9`` of a file without s9 names the sensors it has (what would be
    right); before (tour57) only ``no scan of sensor 's9'``. The sensor service's ``--measurements`` the same."""
    from fedtrack.sensors.service import own_scans

    path = write_lines(tmp_path / "m.jsonl", [scan(0.0, "s2"), scan(0.5, "r1"), scan(1.0, "s2")])
    code = main(["replay", "--algorithm", "mtt-local", "--sensor", "s9", "--measurements", str(path),
                 "--out", str(tmp_path / "o.jsonl")])
    assert one_line_error(capsys, code) == f"fedtrack: error: {path}: no scan of sensor 's9' (its sensors: r1, s2)"
    with pytest.raises(InputError, match=r"no scan of sensor 's9' \(its sensors: r1, s2\)$"):
        own_scans(path, "s9")
    assert not (tmp_path / "o.jsonl").exists()


def test_a_multitarget_file_given_to_kf_says_to_use_mtt(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_lines(tmp_path / "m.jsonl", [scan(0.0)])
    code = main(["replay", "--algorithm", "kf", "--measurements", str(path), "--out", str(tmp_path / "o.jsonl")])
    line = one_line_error(capsys, code)
    assert f"{path}:1: unknown field 'detections'" in line and "--algorithm mtt-local" in line


def test_a_mistyped_config_key_suggests_the_near_miss(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "c.toml"
    config.write_text("[mtt]\nclutter_densty = 1e-6\n")
    path = write_lines(tmp_path / "m.jsonl", [scan(0.0)])
    code = main(["replay", "--algorithm", "mtt-centralized", "--config", str(config), "--measurements", str(path),
                 "--out", str(tmp_path / "o.jsonl")])
    assert one_line_error(capsys, code) == (f"fedtrack: error: {config}: unknown config key mtt.clutter_densty: "
                                            "did you mean mtt.clutter_density?")


def test_values_a_run_cannot_use_fail_at_start_with_one_line(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A picture period of a nanosecond (2e10 pictures over 20 s of data: it ran until killed), a
    figure suffix matplotlib cannot write (a traceback after the work), an unknown bench suite (it
    read as an unknown option of the pipeline bench): each one line, exit 2, nothing written."""
    path = write_lines(tmp_path / "m.jsonl", [scan(0.0), scan(20.0)])
    config = tmp_path / "c.toml"
    config.write_text("[mtt]\nperiod = 1e-4\n")
    replay = ["replay", "--algorithm", "mtt-centralized", "--measurements", str(path), "--out", str(tmp_path / "o")]
    assert one_line_error(capsys, main([*replay, "--period", "1e-9"])).endswith(
        "--period: must be >= 0.001 s (pictures at 1 kHz at most), got 1e-09")
    assert one_line_error(capsys, main([*replay, "--config", str(config)])).endswith(
        f"{config}: mtt.period: must be >= 0.001 s (pictures at 1 kHz at most), got 0.0001")
    truth = write_lines(tmp_path / "u.jsonl", [{"t": 0.0, "targets": []}])
    line = one_line_error(capsys, main(["evaluate", "--tracks", str(truth), "--truth", str(truth),
                                        "--plot", str(tmp_path / "plot.txt")]))
    assert "plot.txt: --plot writes a figure; its suffix '.txt' is not a format" in line and ".svg" in line
    assert one_line_error(capsys, main(["bench", "nosuch"])).endswith(
        "bench: unknown suite 'nosuch' (choose from kernels, montecarlo, multitarget, scale, pipeline, soak, "
        "hpda-soak, all)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", "m.jsonl", "u.jsonl"]


@pytest.mark.parametrize(("key", "value", "right"), [
    ("pd", "1.5", "must be in (0, 1] (a detection probability), got 1.5"),
    ("pd", "0.0", "must be in (0, 1] (a detection probability), got 0"),
    ("gate_probability", "1.0", "must be in (0, 1) (a probability; 1 is an infinite gate), got 1")])
def test_a_probability_out_of_range_says_its_interval(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      key: str, value: str, right: str) -> None:
    """``[mtt] pd`` accepts 1 (a sensor that never misses): said as ``(0, 1]``, was "must be in (0, 1) or 1"."""
    config = tmp_path / "c.toml"
    config.write_text(f"[mtt]\n{key} = {value}\n")
    code = main(["replay", "--algorithm", "mtt-centralized", "--measurements",
                 str(write_lines(tmp_path / "m.jsonl", [scan(0.0)])), "--config", str(config),
                 "--out", str(tmp_path / "o.jsonl")])
    assert one_line_error(capsys, code) == f"fedtrack: error: {config}: mtt.{key}: {right}"


def test_a_failed_replay_leaves_the_previous_output_untouched(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """The radar switch fails after pictures were made: nothing of them reaches ``--out``."""
    rows = [scan(0.1 * k) for k in range(30)] + RADAR_SWITCH[2:]
    path = write_lines(tmp_path / "m.jsonl", rows)
    out = tmp_path / "out.jsonl"
    out.write_text("the previous run\n")
    code = main(["replay", "--algorithm", "mtt-centralized", "--measurements", str(path), "--out", str(out)])
    one_line_error(capsys, code)
    assert out.read_text() == "the previous run\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.jsonl", "out.jsonl"]


def test_no_command_creates_a_missing_folder_and_all_say_so_alike(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    measurements = write_lines(tmp_path / "m.jsonl", [scan(0.0), scan(1.0)])
    truth = write_lines(tmp_path / "u.jsonl", [{"t": 0.0, "targets": []}])
    missing = tmp_path / "missing"
    commands = {
        "simulate": ["simulate", "multitarget", "--targets", "2", "--duration", "5", "--out", str(missing / "o")],
        "simulate traffic": ["simulate", "traffic", "--source", str(TRAFFIC), "--origin", "48.85,2.35",
                             "--out", str(missing / "o")],
        "replay": ["replay", "--algorithm", "mtt-local", "--sensor", "s1", "--measurements", str(measurements),
                   "--out", str(missing / "o")],
        "evaluate": ["evaluate", "--tracks", str(truth), "--truth", str(truth), "--json", str(missing / "o")],
        "export": ["export", "--db", str(tmp_path / "none.db"), "--out", str(missing / "o")],
        "reproduce": ["reproduce", "fvdie", "--runs", "1", "--json", str(missing / "o")],
    }
    for name, argv in commands.items():
        line = one_line_error(capsys, main(argv))
        assert line == (f"fedtrack: error: {missing / 'o'}: the folder {missing} does not exist (fedtrack does not "
                        "create folders; create it first)"), name
    assert not missing.exists()


def test_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    """``fedtrack evaluate ... | head -2`` once head has gone: no traceback, and --json is still written."""
    tracks, truth = _files(tmp_path)
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before anything is written
    try:
        proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "evaluate", "--tracks", str(tracks), "--truth",
                               str(truth), "--json", str(tmp_path / "e.json")],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr == "", proc.stderr
    assert json.loads((tmp_path / "e.json").read_text())["pictures"] == 40


# --- item 5: every option's meaning and default in --help and in the README, the sensor ids documented:
# tests/test_docs_contract.py



# --- item 6 (issue's 8): the last picture holds the end of the data; output lines are pictures

def test_the_final_picture_is_at_the_whole_period_after_the_last_scan(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    path = write_lines(tmp_path / "m.jsonl", [scan(0.5 * k) for k in range(8)])  # t = 0 .. 3.5
    out = tmp_path / "o.jsonl"
    assert main(["replay", "--algorithm", "mtt-local", "--sensor", "s1", "--measurements", str(path),
                 "--out", str(out)]) == 0
    pictures = [json.loads(line) for line in out.read_text().splitlines()]
    assert [p["t"] for p in pictures] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert (pictures[-1]["algorithm"], pictures[-1]["detector"]) == ("mtt-local", "none")
    assert f"wrote 5 pictures to {out}" in capsys.readouterr().out


def test_departures_after_the_last_scan_keep_the_final_pictures_within_the_data() -> None:
    """A live run whose trackers stopped before its centre ends in departure lines: a picture past
    the data would be made without them, so the pictures stop at the latest scan (live and replay)."""
    from fedtrack.fusion_center.mtt.replay import PictureClock

    for departed, expected in ((False, [4.0]), (True, [])):
        clock = PictureClock(period=1.0, delay=0.0)
        assert [T for t in (0.0, 0.5, 1.2, 2.4, 3.5) for T in clock.due(t)] == [0.0, 1.0, 2.0, 3.0]
        if departed:
            clock.left()
        assert clock.final() == expected


# --- item 7 (issue's 9, 10): maneuver rates only when a detector ran; the plot

def _files(tmp_path: Path, **head: str) -> tuple[Path, Path]:
    truth = [{"t": float(k), "targets": [{"id": 1, "x": [10.0 * k, 10.0, 0.0, 0.0]},
                                         {"id": 2, "x": [0.0, 0.0, 10.0 * k, 10.0]}]} for k in range(40)]
    tracks = [{"t": float(k), **head, "tracks": [{"id": 5 + i, "x": g["x"], "status": "confirmed"}
                                                 for i, g in enumerate(line["targets"])]}
              for k, line in enumerate(truth)]
    return write_lines(tmp_path / "tracks.jsonl", tracks), write_lines(tmp_path / "truth.jsonl", truth)


def test_maneuver_flag_rates_only_when_a_detector_ran(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fedtrack.fusion_center.mtt.evaluation import evaluate

    tracks, truth = _files(tmp_path, algorithm="mtt-federated", detector="none")
    man = evaluate(tracks, truth)["maneuvers"]
    assert man["applicable"] is False and man["onsets"] is None and man["flagged_while_straight"] is None
    assert main(["evaluate", "--tracks", str(tracks), "--truth", str(truth)]) == 0
    assert "maneuver flags: not applicable (no maneuver detector ran" in capsys.readouterr().out
    tracks, truth = _files(tmp_path, algorithm="mtt-federated", detector="vdie")
    man = evaluate(tracks, truth)["maneuvers"]
    assert man["applicable"] is True and man["onsets"] == 0 and man["flagged_while_straight"] == 0.0
    assert main(["evaluate", "--tracks", str(tracks), "--truth", str(truth)]) == 0
    printed = capsys.readouterr().out
    assert "0.0% of 56 while it moves straight" in printed and "0 onsets" in printed


@pytest.mark.parametrize("label", [None, "my tracker"])
def test_plot_track_colours_are_never_grey_and_the_title_names_algorithm_and_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, label: str | None) -> None:
    import matplotlib.colors
    from matplotlib.figure import Figure

    figures: list[Figure] = []
    original = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (figures.append(self), original(self, *a, **k)))
    tracks, truth = _files(tmp_path, algorithm="mtt-decentralized", detector="none")
    rows = [json.loads(x) for x in tracks.read_text().splitlines()]
    for row in rows:  # 24 tracks: more than any colour cycle without repeats
        row["tracks"] = [{"id": j, "x": [100.0 * j + row["t"], 1.0, 0.0, 0.0], "status": "confirmed"}
                         for j in range(24)]
    write_lines(tracks, rows)
    argv = ["evaluate", "--tracks", str(tracks), "--truth", str(truth), "--plot", str(tmp_path / "p.png")]
    assert main(argv + (["--label", label] if label else [])) == 0
    (fig,) = figures
    title = fig._suptitle.get_text()
    assert (label or "mtt-decentralized") in title and "tracks.jsonl" in title
    lines = fig.axes[0].get_lines()
    grey = [line for line in lines if len({round(c, 3) for c in matplotlib.colors.to_rgb(line.get_color())}) == 1]
    assert len(grey) == 2 and len(lines) == 26  # the two truths alone are grey


@pytest.mark.parametrize(("role", "option", "extra"), [
    ("sensor", "--health-period", []), ("router", "--connect-timeout", []), ("sensor", "--start-at", []),
    ("sensor", "--lockstep-timeout", []), ("mtt-local", "--reset-timeout", ["--sensor", "s1"]),
    ("fusion-center", "--deadline", ["--sensors", "1,2"])])
def test_a_serve_option_of_nan_seconds_is_refused_at_start(role: str, option: str, extra: list[str],
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """``nan`` passed every ``<= 0`` check of the services' seconds (the service started, with a Health period,
    deadline or reset wait that never elapses or always does) and ``--connect-timeout nan`` ended in a traceback;
    now exit 2 before any session opens, the option named (tour60). An unreachable endpoint keeps a service
    that would start short."""
    timeout = ["--connect-timeout", "0.2"] if option != "--connect-timeout" else []
    with pytest.raises(SystemExit) as stop:  # the option parser's exit, as in a process of its own
        main(["serve", role, *extra, "--connect", "tcp/127.0.0.1:1", *timeout, option, "nan"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err, (stop.value.code, err)
    assert err.strip().splitlines()[-1].endswith(f"error: argument {option}: must be a finite number, got 'nan'")


@pytest.mark.parametrize(("pacing", "start", "code", "said"), [
    ("realtime", "-1", 2, "error: --start-at: must be a Unix time >= 0 (seconds since 1970), got -1"),
    ("lockstep", "-1", 2, "error: --start-at: must be a Unix time >= 0 (seconds since 1970), got -1"),
    ("realtime", "1000", 0, "--start-at 1000.000: every scan of this sensor was due by 1100.000, "),
    ("realtime", "one hour ago", 0, "--start-at "),
])
def test_a_sensor_start_with_nothing_left_to_publish_is_said(pacing: str, start: str, code: int, said: str,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``serve sensor --start-at -1`` (a start in the past) was taken: a realtime sensor found every scan due, said
    "resuming at scan 101" and exited 0 having published nothing, a lockstep one started at once (tour61). Now a time
    before 1970 is exit 2; a realtime start by which every scan of the paper scenario's 100 s was due (an hour ago at
    speed 1: its last scan due 3,500 s ago) ends at once, exit 0, saying so in one line, before any session opens: a
    launcher restarting a sensor that failed after its last scan was due sees it finished (tour61 made it exit 2, and
    the launcher retried it, gave it up and ended in exit 1)."""
    import time

    at = repr(time.time() - 3600.0) if start == "one hour ago" else start
    args = ["serve", "sensor", "--connect", "tcp/127.0.0.1:1", "--connect-timeout", "0.2", "--pacing", pacing,
            "--start-at", at]
    if code:
        with pytest.raises(SystemExit) as stop:
            main(args)
        got = stop.value.code
    else:
        got = main(args)
    err = capsys.readouterr().err
    assert got == code and "Traceback" not in err, (got, err)
    assert f"fedtrack serve sensor: {said}" in err.strip().splitlines()[-1], err


def test_a_sensor_start_in_the_past_with_scans_still_due_is_taken() -> None:
    """A restarted sensor is given its first start's time (the launcher's restarts, or by hand to resume): taken while
    a scan is still due, and the sensor resumes at the scan then due."""
    import time

    from fedtrack.sensors.service import SensorService
    from fedtrack.zsession import SessionOptions

    now = time.time()
    lines = [{"t": float(k)} for k in range(101)]
    sensor = SensorService(lines, 1.0, "realtime", 1.0, 5.0, now - 50.0, service_id="s",
                           options=SessionOptions())
    assert sensor.start_problem(now) is None and sensor.nothing_left(now) is None
    assert sensor.nothing_left(now + 51.0) is not None  # its scan 100 was due at now + 50
    lockstep = SensorService(lines, 1.0, "lockstep", 1.0, 5.0, 0.0, service_id="s", options=SessionOptions())
    assert lockstep.start_problem(now) is None and lockstep.nothing_left(now) is None


def test_a_ctrl_c_before_any_file_leaves_no_empty_output_folder(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """``simulate multitarget --out DIR`` and ``reproduce --plots DIR`` made DIR before their work (seconds of
    simulation, minutes of Monte Carlo): a Ctrl-C then left it empty, though nothing was written (tour61). Now each is
    made as its files are written."""
    from fedtrack.experiments import fvdie
    from fedtrack.sensors import multitarget

    def stopped(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt
    monkeypatch.setattr(multitarget, "simulate", stopped)
    monkeypatch.setattr(fvdie, "reproduce_fvdie", stopped)
    assert main(["simulate", "multitarget", "--targets", "2", "--duration", "5", "--out", str(tmp_path / "s")]) == 130
    assert main(["reproduce", "fvdie", "--runs", "2", "--json", str(tmp_path / "r.json"),
                 "--plots", str(tmp_path / "p")]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("option", ["--population", "--generations", "--max-rules"])
def test_a_training_option_below_one_is_named_as_the_option(option: str, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``train ts-fuzzy --population 0`` said ``fedtrack: error: population: must be >= 1``, a key of no file the
    user gave (tour61); now the option's usage error, as ``--runs 0``'s, before any training."""
    with pytest.raises(SystemExit) as stop:
        main(["train", "ts-fuzzy", "--out", str(tmp_path / "m.npz"), option, "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and err[-1] == f"fedtrack train ts-fuzzy: error: {option}: must be >= 1", err
    assert not (tmp_path / "m.npz").exists()


def test_a_sensor_table_of_no_sensor_in_the_data_is_said(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``[mtt.sensor.S1]`` (a mistyped ``s1``) without ``[mtt] sensors``: its noise floor went unused without a word
    (tour61); now replay notes it, and the pictures are those without the table."""
    sim = tmp_path / "S"
    assert main(["simulate", "multitarget", "--targets", "2", "--duration", "5", "--sensors", "pos:1",
                 "--out", str(sim)]) == 0
    stray = tmp_path / "c.toml"
    stray.write_text("[mtt.sensor.S1]\nnoise_floor = [10.0, 10.0]\n")
    capsys.readouterr()
    for config, out in ((stray, "a.jsonl"), (tmp_path / "none.toml", "b.jsonl")):
        config.touch()
        assert main(["replay", "--algorithm", "mtt-federated", "--config", str(config), "--measurements",
                     str(sim / "measurements.jsonl"), "--out", str(tmp_path / out)]) == 0
    err = capsys.readouterr().err
    assert (f"mtt-federated: note: [mtt.sensor.S1] of {stray} names no sensor of {sim / 'measurements.jsonl'} "
            "(its sensors: s1): its keys are not used") in err, err
    assert err.count("names no sensor") == 1
    assert (tmp_path / "a.jsonl").read_bytes() == (tmp_path / "b.jsonl").read_bytes()


def test_a_command_asked_for_more_memory_than_there_is_ends_in_one_error_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``reproduce fvdie --runs 10000000000000`` (14.4 PiB of positions, beyond any address space) ended in numpy's
    MemoryError traceback; now exit 2 with the allocation that failed and what to ask for less of (tour60)."""
    code = main(["reproduce", "fvdie", "--runs", "10000000000000", "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, (code, err)
    assert err.strip().splitlines()[-1].startswith("fedtrack: error: out of memory: Unable to allocate 14.4 PiB")
    assert not (tmp_path / "r.json").exists()


def test_a_scan_sensor_without_realtime_pacing_is_told_that_alone(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``serve sensor --kind scan --measurements M`` at the default lockstep pacing was told "--kind scan needs
    --measurements FILE and realtime pacing", the file it was given said missing too; now the pacing alone, and the
    file alone when it is the one missing (tour60)."""
    meas = write_lines(tmp_path / "m.jsonl", [scan(0.0)])
    said = []
    for extra in (["--measurements", str(meas)], ["--pacing", "realtime"]):
        with pytest.raises(SystemExit) as stop:
            main(["serve", "sensor", "--kind", "scan", "--id", "s1", *extra])
        assert stop.value.code == 2
        said.append(capsys.readouterr().err.strip().splitlines()[-1])
    assert said == ["fedtrack serve sensor: error: --kind scan paces its scans in real time: give --pacing realtime "
                    "(the pacing is lockstep, deployment.pacing or its default)",
                    "fedtrack serve sensor: error: --kind scan needs --measurements FILE (the scans to publish)"]


def test_more_runs_than_an_array_can_index_end_in_one_error_line(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """``reproduce fvdie --runs 10**21`` is beyond numpy's largest dimension: its ValueError ended in a traceback
    (tour60 noticed); now exit 2 naming ``--runs`` and its bound."""
    code = main(["reproduce", "fvdie", "--runs", str(10**21), "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, (code, err)
    assert err.strip().splitlines()[-1] == (f"fedtrack: error: --runs: at most {sys.maxsize} (the largest array "
                                            f"dimension), got {10**21}")
    assert not (tmp_path / "r.json").exists()
