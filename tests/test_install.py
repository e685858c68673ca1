"""The wheel installs exactly one top-level package, ``fedtrack``, and works from a clean venv."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(ROOT)],
                   check=True, timeout=300, cwd=out)
    (path,) = out.glob("fedtrack-*.whl")
    return path


def test_wheel_claims_one_top_level_name(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"fedtrack"}
    top_level = next(n for n in names if n.endswith(".dist-info/top_level.txt"))
    assert zipfile.ZipFile(wheel).read(top_level).decode().split() == ["fedtrack"]
    for module in ("fedtrack/local_filters/linear/kalman.py", "fedtrack/fusion_center/replay.py",
                   "fedtrack/experiments/fvdie.py", "fedtrack/deploy/local.toml"):
        assert module in names


def test_wheel_runs_from_a_scratch_venv(wheel: Path, tmp_path: Path) -> None:
    """Installed in a venv that sees the dependencies but not the source tree: --help and a replay work."""
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # dependencies (numpy, zenoh, ...) from the test's environment; a plain path entry, so the
    # editable install's finder there is not activated
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--quiet",
                    str(wheel)], check=True, timeout=300)
    where = subprocess.run([str(py), "-c", "import fedtrack.local_filters, sys; print(fedtrack.local_filters.__file__)"],
                           check=True, capture_output=True, text=True, cwd=tmp_path).stdout
    assert where.startswith(str(site))
    fedtrack = env_dir / "bin" / "fedtrack"
    assert subprocess.run([str(fedtrack), "--help"], capture_output=True, timeout=60, cwd=tmp_path).returncode == 0
    meas = tmp_path / "m.jsonl"
    R = [[100.0, 5.0], [5.0, 100.0]]
    meas.write_text("".join(json.dumps({"t": float(k), "sensor": "a", "z": [10.0 * k, 1.0], "R": R}) + "\n"
                            for k in range(3)))
    run = subprocess.run([str(fedtrack), "replay", "--algorithm", "kf", "--measurements", str(meas),
                          "--out", str(tmp_path / "t.jsonl")], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert len((tmp_path / "t.jsonl").read_text().splitlines()) == 3
