"""The 3-host example across Linux network namespaces (deploy/netns-demo.sh).

Runs only where network namespaces can be created (root, iproute2); otherwise it is
skipped with the real reason. Bounded: the script has 75 s, the test 85 s.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "deploy" / "netns-demo.sh"
SCRIPT_TIMEOUT_S = 75
TEST_TIMEOUT_S = 85


def netns_unavailable() -> str | None:
    """Why network namespaces cannot be used here (None when they can)."""
    if shutil.which("ip") is None:
        return "the 'ip' command (iproute2) is not installed"
    if os.geteuid() != 0:
        return f"needs root, running as uid {os.geteuid()}"
    probe = f"ftprobe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, timeout=10)
    if made.returncode != 0:
        return f"'ip netns add' failed: {made.stderr.strip() or made.returncode}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=10, check=True)
    return None


def namespaces() -> str:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=10).stdout


def test_netns_demo_three_hosts(tmp_path: Path) -> None:
    reason = netns_unavailable()
    if reason is not None:
        pytest.skip(f"ip netns unavailable: {reason}")
    env = dict(os.environ, NETNS_DEMO_TIMEOUT_S=str(SCRIPT_TIMEOUT_S), FEDTRACK_PYTHON=sys.executable)
    proc = subprocess.Popen(["bash", str(SCRIPT), str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    try:
        out, err = proc.communicate(timeout=TEST_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGTERM)  # the script's EXIT trap removes its namespaces and processes
        out, err = proc.communicate(timeout=20)
        pytest.fail(f"netns-demo.sh did not finish within {TEST_TIMEOUT_S} s:\n{err[-3000:]}")
    assert proc.returncode == 0, f"netns-demo.sh exited {proc.returncode}:\n{err[-3000:]}"
    verdict = json.loads((tmp_path / "verify.json").read_text())
    assert verdict["ok"], verdict
    assert verdict["scans"] == verdict["scans_expected"] == 101
    assert verdict["measurements"] == 3 * 101
    assert verdict["degraded"] == 0
    assert verdict["max_replay_diff"] <= 1e-9
    # the sensors really ran on other hosts than the recorder: their launch logs are separate
    assert "scans fused 101" in (tmp_path / "launch-b.log").read_text()
    assert "scans fused 101" in (tmp_path / "launch-c.log").read_text()
    tag = re.search(r"run (ftnd\d+)", err)
    assert tag is not None, err
    assert tag.group(1) not in namespaces(), "namespaces left behind"


@pytest.mark.parametrize("script, subnet_var", [("netns-demo.sh", "NETNS_DEMO_SUBNET"),
                                                ("netns-regions.sh", "NETNS_REGIONS_SUBNET")])
def test_a_run_that_cannot_start_leaves_no_output_folder(tmp_path: Path, script: str, subnet_var: str) -> None:
    """Refused by its preflight (not root: exit 77; a malformed subnet: exit 1), a run without OUT_DIR leaves no
    folder behind: before (tour58) its default ``$TMPDIR/fedtrack-netns.XXXXXX`` was made first, and every refused
    run left an empty one. Needs neither root nor namespaces: the preflight refuses before any is made."""
    env = {**os.environ, "TMPDIR": str(tmp_path), subnet_var: "not-a-subnet"}
    proc = subprocess.run(["bash", str(REPO / "deploy" / script)], capture_output=True, text=True, timeout=30,
                          env=env, check=False)
    assert proc.returncode in (1, 77), proc.stderr
    assert "must be three octets" in proc.stderr or "cannot run" in proc.stderr, proc.stderr
    assert list(tmp_path.iterdir()) == []
