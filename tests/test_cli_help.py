"""Every sub-command answers ``--help`` with exit 0 and plain text; ``fedtrack --version`` works.

The cases are built from the registries in :mod:`fedtrack.cli`, so a new sub-command is
covered without editing this file.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from fedtrack import cli
from fedtrack.benchmarks.suites import SUITES


def _help_cases() -> list[list[str]]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    cases: list[list[str]] = [[], *([name] for name in sub.choices)]
    cases += [["serve", role] for role in cli.SERVICES]
    cases += [["train", name] for name in cli.TRAINERS]
    cases += [["simulate", name] for name in cli.SIMULATORS]
    cases += [["reproduce", name] for name in cli.REPRODUCERS]
    cases += [["bench", suite] for suite in SUITES]  # each suite's own parser (before tour57: reST, cut mid-sentence)
    return cases


@pytest.mark.parametrize("argv", _help_cases(), ids=lambda a: " ".join(a) or "fedtrack")
def test_help_exits_0_in_plain_text(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = cli.main([*argv, "--help"])
    except SystemExit as exc:  # argparse's help action exits
        code = exc.code
    out = capsys.readouterr().out
    assert code in (0, None)
    assert "usage: fedtrack" in out
    assert "`" not in out, f"reST markup in help text: {out}"


def test_version_and_serve_help_as_a_process() -> None:
    version = subprocess.run([sys.executable, "-m", "fedtrack.cli", "--version"],
                             capture_output=True, text=True, timeout=60)
    assert version.returncode == 0 and version.stdout.startswith("fedtrack 0."), version
    serve = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "--help"],
                           capture_output=True, text=True, timeout=60)
    assert serve.returncode == 0 and all(role in serve.stdout for role in cli.SERVICES), serve
    missing = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve"],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "ROLE" in missing.stderr
