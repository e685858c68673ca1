"""The launcher's supervision of its children: restart with backoff, the reason, the limit, the stop."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from support import wait_until

from fedtrack.deploy import launcher as launcher_mod
from fedtrack.deploy.launcher import Launcher, LaunchError, ServiceProcess, describe_exit
from fedtrack.deploy.settings import Settings


def crashing(role: str, tmp_path: Path) -> ServiceProcess:
    return ServiceProcess(role, "x", [sys.executable, "-c", "import sys; print('up'); sys.exit(3)"],
                          tmp_path / f"{role}.log")


def supervise(launcher: Launcher, sp: ServiceProcess, rounds: int) -> None:
    """Let ``sp`` crash and be restarted ``rounds`` times (backoff patched to 10 ms)."""
    for _ in range(rounds):
        assert wait_until(lambda: sp.proc.poll() is not None, 10.0)
        old = sp.proc
        launcher._check_alive([sp])  # schedules the restart ...
        assert wait_until(lambda: launcher._check_alive([sp]) or sp.proc is not old, 5.0)  # ... and starts it


@pytest.mark.parametrize("role", ["recorder", "sensor"])
def test_restart_with_backoff_then_the_limit(tmp_path: Path, role: str, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(launcher_mod, "RESTART_BACKOFF_S", 0.01)
    sp = crashing(role, tmp_path)
    launcher = Launcher(Settings(), [sp], quiet=True)
    launcher._start(sp)
    supervise(launcher, sp, launcher_mod.MAX_RESTARTS)
    assert launcher.report.restarts == {sp.name: 3}
    assert wait_until(lambda: sp.proc.poll() is not None, 10.0)
    assert sp.log_path.read_text().count("up") == 4  # every restart appends to the log
    if role == "recorder":  # essential: the deployment stops, naming it and the limit
        with pytest.raises(LaunchError, match=r"recorder/x exited with exit code 3 after 3 restarts \(limit 3\)"):
            launcher._check_alive([sp])
    else:  # a sensor is left out; the rest goes on
        launcher._check_alive([sp])
        assert launcher.report.failed == [sp.name] and launcher._finished(sp)
    err = capsys.readouterr().err
    assert f"{sp.name} exited with exit code 3; restart 1 of 3 in 0.01 s" in err
    assert describe_exit(-9) == "signal SIGKILL"


def test_a_new_run_sets_an_earlier_runs_recording_aside(tmp_path: Path) -> None:
    """The recorder appends to its database (across its restarts within a run): a run into a folder
    that holds another run's recording starts a fresh one, the earlier one kept as
    ``recording.db.previous`` (one generation), so the exports hold this run's data alone (a
    ``fedtrack demo`` after ``fedtrack demo --scenario multitarget`` in the same folder exported the
    earlier run's pictures and ended in a KeyError)."""
    from fedtrack.deploy.launcher import set_aside_recording
    import numpy as np

    from fedtrack.recording import Recording
    from fedtrack.wire import Measurement, encode

    db = tmp_path / "recording.db"
    assert set_aside_recording(db) is None
    for run in range(2):
        rec = Recording(db)
        msg = Measurement(sensor="p1", seq=run, t=float(run), kind="position", z=np.array([float(run), 0.0]),
                          R=np.eye(2), stamp_ns=1)
        rec.add(msg, encode(msg))
        rec.close()
        kept = set_aside_recording(db)
        assert kept == tmp_path / "recording.db.previous" and not db.exists()
        again = Recording(kept)
        assert [m.t for m in again.messages(Measurement, "t")] == [float(run)]  # that run's alone
        again.close()
