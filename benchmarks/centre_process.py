"""``python -m fedtrack.benchmarks.centre_process RECORDING OUT [serve mtt-centre's arguments]``: one centre
of ``fedtrack bench scale`` replayed on its recorded calls in this process alone
(:mod:`fedtrack.benchmarks.centre_replay`). The process is tuned as every ``fedtrack`` process is
(:func:`tune_process`, before numpy is imported)."""

from __future__ import annotations

import sys

from fedtrack.process_tuning import tune_process


def run() -> int:
    tune_process()
    from fedtrack.benchmarks.centre_replay import main
    return main(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(run())
