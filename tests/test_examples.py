"""The third-party examples (examples/) against a launched deployment, in an interpreter
where only zenoh and msgpack are importable (fedtrack is not)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import msgpack
import zenoh
from support import free_port, wait_until

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SCANS = 12


def isolated(tmp_path: Path, code: str) -> list[str]:
    """``python -I -S -c CODE`` with sys.path = [a folder holding only zenoh and msgpack, examples/]."""
    deps = tmp_path / "deps"
    if not deps.exists():
        deps.mkdir()
        for module in (zenoh, msgpack):
            (deps / module.__name__).symlink_to(Path(module.__file__).parent)
    return [sys.executable, "-I", "-S", "-c", f"import sys; sys.path[:0] = [{str(deps)!r}, {str(EXAMPLES)!r}]; {code}"]


def example(tmp_path: Path, name: str, *args: str) -> list[str]:
    run = (f"import runpy; sys.argv = [{name!r}, *sys.argv[1:]]; "
           f"runpy.run_path({str(EXAMPLES / name)!r}, run_name='__main__')")
    return [*isolated(tmp_path, run), *args]


def test_fedtrack_is_not_importable_there(tmp_path: Path) -> None:
    ok = subprocess.run(isolated(tmp_path, "import zenoh, msgpack, wire_contract"), capture_output=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    no = subprocess.run(isolated(tmp_path, "import fedtrack"), capture_output=True, text=True, timeout=60)
    assert no.returncode == 1 and "No module named 'fedtrack'" in no.stderr


def test_third_party_sensor_and_subscriber_against_a_launched_deployment(tmp_path: Path) -> None:
    """Authenticated, as ``fedtrack demo`` is by default: each example presents the certificate of the
    file ``launch`` wrote for it (``--zenoh-config``; before 2026-11-27 they had no way to, and the
    demo's deployment was out of their reach)."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    cfg = tmp_path / "ext.toml"
    cfg.write_text(f'[zenoh]\ntls_dir = "certs"\n[fusion]\nsensors = ["ext"]\n\n[deployment]\nname = "ext"\n'
                   f'router_listen = "{endpoint}"\n'
                   'services = ["router", "local-filter", "fusion-center", "recorder"]\n\n'
                   '[[sensor]]\nid = "ext"\nR = [[100.0, 0.0], [0.0, 100.0]]\n')
    zenoh_args = ["--connect", endpoint, "--deployment", "ext"]
    launch = subprocess.Popen([sys.executable, "-m", "fedtrack.cli", "launch", str(cfg), "--out", str(tmp_path / "out")],
                              cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    files = tmp_path / "out" / "zenoh"
    subscriber = None
    try:
        assert wait_until(lambda: (files / "sensor-ext.json5").exists(), 60.0)
        subscriber = subprocess.Popen(example(tmp_path, "track_subscriber.py", *zenoh_args, "--count", str(SCANS + 3),
                                              "--timeout", "90", "--zenoh-config", str(files / "launcher.json5")),
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        zenoh_args += ["--zenoh-config", str(files / "sensor-ext.json5")]
        assert json.loads(subscriber.stdout.readline()) == {"subscribed": "fedtrack/ext/fusion/track"}
        first = subprocess.run(example(tmp_path, "sensor_publisher.py", *zenoh_args, "--sensor", "ext",
                                       "--scans", str(SCANS)), capture_output=True, text=True, timeout=90)
        assert first.returncode == 0, first.stderr
        assert f"published scans 0..{SCANS - 1}; fused up to {SCANS - 1}" in first.stdout
        late = subprocess.run(example(tmp_path, "sensor_publisher.py", *zenoh_args, "--sensor", "ext",
                                      "--scans", "3", "--seed", "2"), capture_output=True, text=True, timeout=90)
        assert late.returncode == 0, late.stderr
        assert f"published scans {SCANS}..{SCANS + 2}; fused up to {SCANS + 2}" in late.stdout  # joined late
        out, err = subscriber.communicate(timeout=60)
        tracks = [json.loads(line) for line in out.splitlines()]
        assert [tr["seq"] for tr in tracks] == list(range(SCANS + 3)), err
        last = tracks[-1]
        x, y = last["x"][0], last["x"][3 if last["model"] == "ca" else 2]
        assert abs(x - (1000.0 + 20.0 * last["t"])) < 60 and abs(y - (2000.0 + 10.0 * last["t"])) < 60, last
    finally:
        if subscriber is not None:
            subscriber.kill()
        launch.send_signal(signal.SIGTERM)
        try:
            launch.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            launch.kill()
            launch.communicate(timeout=30)
    assert launch.returncode == 130
    recorded = (tmp_path / "out" / "tracks.jsonl").read_text().splitlines()
    assert len(recorded) == SCANS + 3
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())  # written after the stop too
    assert summary["scans"] == SCANS + 3 and summary["health"]["recorder/recorder"]["tracks_recorded"] == SCANS + 3
    assert not (tmp_path / "out" / "truth.jsonl").exists()  # no simulated sensors on this host: no truth


def test_the_examples_speak_the_current_schema() -> None:
    """examples/wire_contract.py (no fedtrack import) names the schema version fedtrack speaks."""
    import ast

    from fedtrack.wire import SCHEMA_VERSION

    tree = ast.parse((EXAMPLES / "wire_contract.py").read_text())
    values = [node.value.value for node in tree.body if isinstance(node, ast.Assign)
              and any(isinstance(t, ast.Name) and t.id == "SCHEMA" for t in node.targets)]
    assert values == [SCHEMA_VERSION]
