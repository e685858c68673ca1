"""A user starting the services by hand, one ``fedtrack serve ROLE`` a shell (tour58): what a start refuses
says in one line what to give. The refusals come before any connection (the endpoint below listens nowhere)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support import cli_in_process

NOWHERE = ["--connect", "tcp/127.0.0.1:1", "--connect-timeout", "0.5"]


def test_a_local_filter_without_the_deployments_sensors_says_where_to_give_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``serve local-filter --sensor 1`` without ``--config`` (the README's by-hand start, every key at its default)
    cannot know its share of the information (1/beta_i of N sensors): the line says so and what to give; before
    (tour58) it said ``fusion.sensors: sensor '1' is not listed (empty)``, while ``serve fusion-center`` in the
    same case named its ``--sensors``. A sensor missing from a config's list is named with the list."""
    out = cli_in_process(["serve", "local-filter", "--sensor", "1", *NOWHERE], capsys, monkeypatch)
    assert out.returncode == 2
    assert out.stderr.strip() == ("fedtrack: error: fusion.sensors: none given: the filter of sensor '1' needs "
                                  "every sensor of the deployment; give --config FILE with [fusion] sensors or "
                                  "[[sensor]] ids")
    cfg = tmp_path / "d.toml"
    cfg.write_text('[fusion]\nsensors = ["1", "2"]\n')
    out = cli_in_process(["serve", "local-filter", "--sensor", "9", "--config", str(cfg), *NOWHERE], capsys,
                         monkeypatch)
    assert (out.returncode, out.stderr.strip()) == (2, f"fedtrack: error: {cfg}: fusion.sensors: sensor '9' is not "
                                                       "listed (1, 2)")


@pytest.mark.parametrize("role", ["local-filter", "mtt-local", "imm", "hpda"])
def test_a_per_sensor_service_started_by_hand_takes_its_sensors_id(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, role: str) -> None:
    """``serve mtt-local --sensor s1`` (and ``imm``, ``hpda``) without ``--id`` runs as ``s1``, as ``local-filter``
    did: a multi-target centre takes a tracker's token ``alive/mtt-local/<id>`` for its sensor's, so that a tracker
    that dies is dropped at once. Before (tour58) three trackers started by hand were all ``mtt-local``: one
    Health key for three, a token the centre never followed (a dead tracker's sensor dropped only after
    ``leave_after_s`` of silence). ``--id`` given still wins."""
    from fedtrack.services.base import Service

    started: list[str] = []
    monkeypatch.setattr(Service, "run", lambda self: started.append(self.id) or 0)
    cfg = tmp_path / "d.toml"
    cfg.write_text('[fusion]\nsensors = ["s1", "s2"]\n')
    for extra in ([], ["--id", "mine"]):
        out = cli_in_process(["serve", role, "--sensor", "s1", "--config", str(cfg), *extra, *NOWHERE], capsys,
                             monkeypatch)
        assert out.returncode == 0, out.stderr
    assert started == ["s1", "mine"]


def test_a_sensor_option_it_cannot_use_or_a_bad_value_is_named_as_the_option(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``serve sensor --join-at 5`` of a simulated position sensor was accepted and ignored (only ``--kind scan``
    replays scans from a time on), and ``--speed 0`` was refused as ``speed: ...``, the config key's name, not the
    option given (tour58)."""
    out = cli_in_process(["serve", "sensor", "--join-at", "5", *NOWHERE], capsys, monkeypatch)
    assert out.returncode == 2
    assert out.stderr.splitlines()[-1] == ("fedtrack serve sensor: error: --measurements and --join-at apply to --kind "
                                           "scan only (a position sensor simulates its scans)")
    out = cli_in_process(["serve", "sensor", "--speed", "0", *NOWHERE], capsys, monkeypatch)
    assert out.returncode == 2
    assert out.stderr.splitlines()[-1] == "fedtrack serve sensor: error: --speed: must be finite and > 0"
