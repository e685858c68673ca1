"""A new user's deployment paths, followed as README.md and docs/deploy.md write them (loopback only)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support import free_port

from fedtrack.deploy.launcher import LaunchError, prepare_launcher
from fedtrack.deploy.settings import load_settings


def test_launch_of_a_host_whose_router_is_not_up_is_one_line(tmp_path: Path) -> None:
    """A sensor host of deploy/multihost/ launched while host A's router is down (or its address is
    wrong): after ready_timeout_s a Python traceback (SessionError from the launcher's monitor), exit 1.
    Now a LaunchError, which ``launch`` prints as one line (exit 1), naming the timeout and the endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "b.toml"
    cfg.write_text(f'[deployment]\nready_timeout_s = 0.5\nconnect = ["{endpoint}"]\n'
                   'services = ["sensor", "local-filter"]\n[[sensor]]\nid = "1"\n')
    (tmp_path / "o").mkdir()
    launcher = prepare_launcher(load_settings(cfg), cfg, tmp_path / "o", quiet=True)
    with pytest.raises(LaunchError) as error:
        launcher.run()
    message = str(error.value)
    assert message.startswith("no router reached within ready_timeout_s = 0.5 s: ") and "\n" not in message
    assert endpoint in message and ".rs:" not in message
    assert all(sp.proc is None for sp in launcher.plan)  # nothing was started
