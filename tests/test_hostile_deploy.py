"""Hostile deployments (marker ``security``): an operator's wrong command line or file, and the
transport a single service is started with. Loopback only: an endpoint off loopback is only ever
refused before anything opens, never opened."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fedtrack.services.base import service_kwargs, service_parser

pytestmark = pytest.mark.security
OFF_LOOPBACK = "tcp/192.0.2.1:7447"  # TEST-NET-1: never a target; the check refuses it before any session


@pytest.mark.parametrize("mode, flag", [("router", "--listen"), ("client", "--connect"), ("client", "--listen")])
def test_serve_refuses_a_plain_endpoint_off_loopback_unless_insecure(mode: str, flag: str) -> None:
    """``launch`` refuses a plain endpoint off loopback unless ``[zenoh]`` opts out, but ``serve`` took
    one as given: ``fedtrack serve router --listen tcp/0.0.0.0:7447`` opened an unauthenticated bus to
    the network with no word. ``serve`` now refuses it (exit 2, naming the option and the endpoint)
    unless ``--insecure`` says so, or the endpoint is ``tls/`` with ``--zenoh-config``."""
    parser = service_parser("recorder", "test")
    with pytest.raises(SystemExit) as stop:
        service_kwargs(parser, parser.parse_args([flag, OFF_LOOPBACK]), mode)
    assert stop.value.code == 2
    kwargs = service_kwargs(parser, parser.parse_args([flag, OFF_LOOPBACK, "--insecure"]), mode)
    assert OFF_LOOPBACK in (*kwargs["options"].connect, *kwargs["options"].listen)
    for loopback in ("tcp/127.0.0.1:7447", "tcp/localhost:7447", "tcp/[::1]:7447"):
        service_kwargs(parser, parser.parse_args([flag, loopback]), mode)


def test_serve_router_off_loopback_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """The command line itself: exit 2 and one error line naming the option, before any session
    (the router's listen address is not this machine's: nothing is bound or sent)."""
    run = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "router", "--listen", OFF_LOOPBACK],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    errors = [line for line in run.stderr.splitlines() if "error" in line]
    assert run.returncode == 2 and len(errors) == 1, run.stderr
    assert f"--listen: {OFF_LOOPBACK} is off loopback" in errors[0] and "--insecure" in errors[0]
    assert "Traceback" not in run.stderr
