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
    assert out.stderr.strip() == ("fedtrack: error: fusion.sensors: none given: the filter of sensor '1' needs every "
                                  "sensor of the deployment; give --config FILE with [fusion] sensors or [[sensor]] ids")
    cfg = tmp_path / "d.toml"
    cfg.write_text('[fusion]\nsensors = ["1", "2"]\n')
    out = cli_in_process(["serve", "local-filter", "--sensor", "9", "--config", str(cfg), *NOWHERE], capsys,
                         monkeypatch)
    assert (out.returncode, out.stderr.strip()) == (2, f"fedtrack: error: {cfg}: fusion.sensors: sensor '9' is not "
                                                       "listed (1, 2)")
