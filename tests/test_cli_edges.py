"""Every file a command reads or writes fails cleanly: one line naming the file, exit 2, no traceback.

Most cases call ``cli.main`` in this process (a traceback is an exception that fails the test; no
process may be started); one bad file per sub-command, and the deeply nested JSON, whose recursion
limit is the interpreter's own, run ``python -m fedtrack.cli`` as a user would, for the exit code."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from support import CliOutcome, cli_in_process
from support import cli_in_subprocess as run

BAD_INPUTS = {
    "binary": lambda p: p.write_bytes(bytes(range(256)) * 4),
    "utf16": lambda p: p.write_bytes('{"t": 0.0, "sensor": "s1"}\n'.encode("utf-16")),
    "deep_json": lambda p: p.write_text("[" * 100_000 + "]" * 100_000 + "\n"),
    "directory": lambda p: p.mkdir(),
    "missing": lambda p: None,
}

# (command, the argument that takes the bad file); {bad} and {out} are filled in
COMMANDS = {
    "replay measurements": ["replay", "--algorithm", "kf", "--measurements", "{bad}", "--out", "{out}"],
    "replay mtt measurements": ["replay", "--algorithm", "mtt-centralized", "--measurements", "{bad}", "--out", "{out}"],
    "replay hpda measurements": ["replay", "--algorithm", "hpda", "--measurements", "{bad}", "--out", "{out}"],
    "replay config": ["replay", "--algorithm", "kf", "--config", "{bad}", "--measurements", "{good}", "--out", "{out}"],
    "evaluate tracks": ["evaluate", "--tracks", "{bad}", "--truth", "{truth}"],
    "evaluate truth": ["evaluate", "--tracks", "{good}", "--truth", "{bad}"],
    "launch config": ["launch", "{bad}"],
    "serve config": ["serve", "fusion-center", "--config", "{bad}"],
    "export db": ["export", "--db", "{bad}", "--out", "{out}"],
}


Run = Callable[[list[str]], CliOutcome]


@pytest.fixture
def run_here(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> Run:
    """:func:`cli_in_process` with this test's capture and patches."""
    return lambda args: cli_in_process(args, capsys, monkeypatch)


def assert_one_line_error(proc: CliOutcome, name: str) -> None:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and name in lines[0], proc.stderr[-2000:]


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("good")
    (folder / "tracks.jsonl").write_text('{"t": 0.0, "tracks": []}\n')
    (folder / "truth.jsonl").write_text('{"t": 0.0, "targets": []}\n')
    return {"good": folder / "tracks.jsonl", "truth": folder / "truth.jsonl"}


# the readers are shared: every kind of bad file through two commands, two kinds through the rest
CASES = [(c, k) for c in ("replay measurements", "replay config") for k in sorted(BAD_INPUTS)]
CASES += [(c, k) for c in sorted(COMMANDS) if c not in ("replay measurements", "replay config")
          for k in ("directory", "utf16")]
# in a new process: one case per sub-command (its exit code as a shell sees it) and the deep JSON
IN_SUBPROCESS = {("replay measurements", "deep_json"), ("replay config", "deep_json"), ("evaluate tracks", "utf16"),
                 ("export db", "directory"), ("launch config", "directory"), ("serve config", "utf16")}
assert IN_SUBPROCESS <= set(CASES) and {COMMANDS[c][0] for c, _ in IN_SUBPROCESS} == {a[0] for a in COMMANDS.values()}


@pytest.mark.parametrize(("command", "kind"), CASES)
def test_bad_input_file_is_one_line_naming_it(tmp_path: Path, good: dict[str, Path], run_here: Run, command: str,
                                              kind: str) -> None:
    bad = tmp_path / f"bad_{kind}"
    BAD_INPUTS[kind](bad)
    args = [a.format(bad=bad, out=tmp_path / "out.jsonl", **good) for a in COMMANDS[command]]
    assert_one_line_error(run(args) if (command, kind) in IN_SUBPROCESS else run_here(args), bad.name)


@pytest.mark.parametrize("out_arg", [["--out", "{missing}/o.jsonl"], ["--out", "{dir}"]])
def test_output_in_a_missing_folder_or_on_a_directory(tmp_path: Path, run_here: Run, out_arg: list[str]) -> None:
    measurements = tmp_path / "m.jsonl"
    measurements.write_text('{"t": 0.0, "sensor": "s1", "z": [1.0, 2.0], "R": [[100.0, 0.0], [0.0, 100.0]]}\n')
    (tmp_path / "adir").mkdir()
    out = [a.format(missing=tmp_path / "nowhere", dir=tmp_path / "adir") for a in out_arg]
    proc = run_here(["replay", "--algorithm", "kf", "--measurements", str(measurements), *out])
    assert_one_line_error(proc, Path(out[1]).name)


IMM_EXAMPLE = Path(__file__).resolve().parents[1] / "deploy" / "imm-3model.toml"
LAUNCH_BASE = """
[deployment]
name = "edges"
router_listen = "tcp/127.0.0.1:{port}"

[[sensor]]
id = "1"

[[sensor]]
id = "2"
"""
MT_BASE = """
[deployment]
name = "edges"
router_listen = "tcp/127.0.0.1:{port}"

[multitarget]
sensors = "pos:1.0,pos:0.7,pos:1.3"
"""
LAUNCH_CASES = {
    "no sensor": (lambda b: b[: b.index("[[sensor]]")], "no [[sensor]] table"),
    "duplicate sensor": (lambda b: b.replace('id = "2"', 'id = "1"'), "duplicate id '1'"),
    "empty fusion sensors": (lambda b: b + "\n[fusion]\nsensors = []\n", "fusion.sensors: empty list"),
    "bad port": (lambda b: b.replace("{port}", "99999"), "router_listen"),
    "bad endpoint": (lambda b: b.replace("tcp/127.0.0.1:{port}", "localhost"), "router_listen"),
    # a host file of another host (deploy/multihost/host-a.toml's 10.47.0.1) run here: said to be a port in use until
    # tour58 (192.0.2.1: TEST-NET-1, on no host; the file off loopback needs its opt-out of TLS to get this far)
    "router address of another host": (lambda b: b.replace("tcp/127.0.0.1:{port}", "tcp/192.0.2.1:{port}")
                                       + "\n[zenoh]\ninsecure = true\n",
                                       "deployment.router_listen: address 192.0.2.1 is not an address of this host "
                                       "(tcp/192.0.2.1:7447), where the router would listen"),
    # cross-field rules (validate58): each launched before, a fusion centre waiting out every scan's deadline for a
    # sensor that never comes, the [[sensor]] it would not fuse, a service dying at start on the sharing factors, or
    # a host starting no sensor or no region centre
    "fusion sensor not defined": (lambda b: b + '\n[fusion]\nsensors = ["1", "3"]\n',
                                  "fusion.sensors: '3' is no [[sensor]] id (1, 2)"),
    "sensor not fused": (lambda b: b + '\n[fusion]\nsensors = ["1"]\n', "fusion.sensors: leaves out [[sensor]] '2'"),
    "sharing per sensor": (lambda b: b + "\n[fusion]\nsharing = [3.0, 3.0, 3.0]\n",
                           "fusion.sharing: 3 factors for the 2 sensors 1, 2"),
    "local sensor not defined": (lambda b: b.replace('name = "edges"', 'name = "edges"\nlocal_sensors = ["l"]'),
                                 "deployment.local_sensors: 'l' is no [[sensor]] id (1, 2)"),
    "local region not defined": (lambda b: b.replace('name = "edges"', 'name = "edges"\nlocal_regions = ["x2y0"]')
                                 + "\n[regions]\nmargin = 100.0\n"
                                 "grid = {origin = [0.0, 0.0], cell = [10.0, 10.0], nx = 2, ny = 1}\n",
                                 "deployment.local_regions: 'x2y0' is no region of [regions] (x0y0, x1y0)"),
    "local region without regions": (lambda b: b.replace('name = "edges"', 'name = "edges"\nlocal_regions = ["a"]'),
                                     "deployment.local_regions: the file has no [regions] table"),
    # a sensor slower than [mtt] central_timeout (tour58): launched before, every central track only it supported
    # was deleted between its scans (simulate multitarget --seed 1 --duration 120, mtt-federated: central_timeout
    # 1.0 beside s3's 1.3 s, id switches 28 -> 42; 0.5, below every period, 554 and mean GOSPA 96.5 -> 174.1 m)
    "central_timeout below a period": (lambda b: MT_BASE + "\n[mtt]\ncentral_timeout = 1.0\n",
                                       "mtt.central_timeout: 1 s is shorter than sensor s3's period 1.3 s: a central "
                                       "track only s3 supports would be deleted between its scans; set it to 1.3 s "
                                       "or more"),
    "a sensor slower than the default central_timeout": (lambda b: MT_BASE.replace("pos:1.3", "pos:6"),
                                                         "mtt.central_timeout: 5 s is shorter than sensor s3's "
                                                         "period 6 s"),
    # a scenario beyond the machine's memory (tour60): numpy's MemoryError and a traceback before, the output made
    "a scenario too large for memory": (lambda b: MT_BASE + "duration = 1e9\n",
                                        "multitarget: the scenario is too large: 1e+09 s of 20 targets"),
    # deploy/imm-3model.toml launched said only "no [[sensor]] table": now also what the file is for
    "a replay config": (lambda b: IMM_EXAMPLE.read_text(), "the file holds [imm] only: a configuration for "
                        "`fedtrack replay --config` or `fedtrack serve ROLE --config`, not a deployment to launch"),
}


@pytest.mark.parametrize("case", sorted(LAUNCH_CASES))
def test_launch_validates_the_whole_deployment_before_starting_anything(tmp_path: Path, run_here: Run,
                                                                        case: str) -> None:
    edit, expected = LAUNCH_CASES[case]
    config = tmp_path / "deploy.toml"
    config.write_text(edit(LAUNCH_BASE).replace("{port}", "7447"))
    proc = run_here(["launch", str(config), "--out", str(tmp_path / "out")])
    assert_one_line_error(proc, config.name)
    assert expected in proc.stderr
    assert not (tmp_path / "out" / "logs").exists()  # no process was started


def test_a_message_exit_is_reported_in_this_process_as_by_the_interpreter(run_here: Run,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A command that ends with ``SystemExit(message)`` (a service module missing from the build) prints
    the message and exits 1 in a new interpreter; :func:`cli_in_process` says the same (it lost the
    message: exit 1 with nothing on standard error)."""
    monkeypatch.setitem(sys.modules, "fedtrack.fusion_center.mtt.service", None)  # not importable
    missing = "fedtrack: fedtrack.fusion_center.mtt.service is not available in this build\n"
    assert run_here(["serve", "mtt-centre"]) == CliOutcome(1, missing)


def test_busy_router_port_fails_at_once_naming_port_and_role(tmp_path: Path) -> None:
    import socket
    import time

    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        t0 = time.monotonic()
        proc = run(["demo", "--port", str(port), "--out", str(tmp_path / "out")], timeout=30)
        elapsed = time.monotonic() - t0
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    # named as --port, before OUT is made (it named OUT/config.toml's router_listen and left that file)
    assert proc.stderr.splitlines()[-1] == f"fedtrack demo: error: --port: {port} is already in use"
    assert not (tmp_path / "out").exists()
    assert elapsed < 10.0  # the bound is 2 s; a loaded CI machine needs ~1 s to import


def test_a_port_left_in_time_wait_by_the_last_run_is_free_a_listening_one_is_not() -> None:
    """Launching again right after a run: its connections to the router's port wait in TIME_WAIT
    for a minute; the router binds regardless (SO_REUSEADDR), so the launcher's check must too."""
    import socket

    from fedtrack.deployment import port_in_use

    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        assert port_in_use(f"tcp/127.0.0.1:{port}")
        client = socket.create_connection(("127.0.0.1", port), timeout=5)
        accepted, _ = server.accept()
        accepted.close()  # the side that closes first keeps the port's end in TIME_WAIT
        client.recv(1)
        client.close()
    assert not port_in_use(f"tcp/127.0.0.1:{port}")


@pytest.mark.parametrize("sensors", ["0", "33"])
def test_a_demo_sensor_count_out_of_range_says_the_count_given(sensors: str,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``demo --sensors 33``: the range and the value given (tour59: the range alone)."""
    from fedtrack.deploy import demo

    with pytest.raises(SystemExit) as exit_:
        demo.main(["--sensors", sensors])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (f"fedtrack demo: error: --sensors must be between 1 and 32, "
                                                        f"got {sensors}")


def test_an_output_that_is_an_input_or_another_output_is_refused_and_nothing_is_replaced(tmp_path: Path,
                                                                                         run_here: Run) -> None:
    """An output naming one of the command's inputs (by any path: a link, ``dir/../dir``) or another of its outputs:
    exit 2, one line naming both options, every file as it was. Before the tour60 session ``replay --out M
    --measurements M`` replaced the measurements with the estimates, ``export --tracks R --db R`` the recording
    database with the tracks, ``evaluate --json U --truth U`` the truth with the result (each exit 0)."""
    from fedtrack.recording import Recording

    meas = tmp_path / "m.jsonl"
    meas.write_text('{"t": 0.0, "sensor": "s1", "z": [1.0, 2.0], "R": [[100.0, 0.0], [0.0, 100.0]]}\n')
    truth, tracks = tmp_path / "u.jsonl", tmp_path / "t.jsonl"
    truth.write_text('{"t": 0.0, "targets": []}\n')
    tracks.write_text('{"t": 0.0, "tracks": []}\n')
    Recording(tmp_path / "r.db").close()
    (tmp_path / "link.jsonl").symlink_to(meas)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    cases = [
        (["replay", "--algorithm", "kf", "--measurements", str(meas), "--out", str(tmp_path / "link.jsonl")],
         "--out is also --measurements"),
        (["export", "--db", str(tmp_path / "r.db"), "--out", str(tmp_path / "e.jsonl"), "--tracks",
          str(tmp_path / ".." / tmp_path.name / "r.db")], "--tracks is also --db"),
        (["export", "--db", str(tmp_path / "r.db"), "--out", str(tmp_path / "e.jsonl"), "--tracks",
          str(tmp_path / "e.jsonl")], "--tracks is also --out"),
        (["evaluate", "--tracks", str(tracks), "--truth", str(truth), "--json", str(truth)], "--json is also --truth"),
    ]
    for args, said in cases:
        proc = run_here(args)
        assert_one_line_error(proc, said)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("algorithm", ["kf", "mtt-centralized", "mtt-federated"])
def test_an_empty_measurements_file_is_refused_by_every_replay(tmp_path: Path, run_here: Run, algorithm: str) -> None:
    """A file of no scans is an error for every algorithm (before, the single-target replay said ``no
    measurements``, exit 2, while ``mtt-*`` wrote 0 pictures and exited 0: tour60)."""
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    out = tmp_path / "out.jsonl"
    assert_one_line_error(run_here(["replay", "--algorithm", algorithm, "--measurements", str(empty),
                                    "--out", str(out)]), empty.name)
    assert not out.exists()
