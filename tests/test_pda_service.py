"""``fedtrack serve hpda`` over a loopback Zenoh router: sonar scans in, confirmed tracks out."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
from support import WAIT_S, feed, free_port, wait_until

from fedtrack.cli import main
from fedtrack.keys import Keys
from fedtrack.local_filters.pda.config import PDAReplayConfig
from fedtrack.local_filters.pda.service import PDAService
from fedtrack.sensors.sonar import SonarConfig, sonar_scans
from fedtrack.wire import FusedTrack, Measurement, decode, encode, measurement_from_replay
from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive


def test_service_confirms_the_sonar_target() -> None:
    port = free_port()
    keys = Keys("pda")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    opts = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=5.0)
    service = PDAService("sonar1", "hpda", PDAReplayConfig(), service_id="h1", options=opts, deployment="pda")
    code: list[int] = []
    thread = threading.Thread(target=lambda: code.append(service.run()), daemon=True)
    thread.start()
    session = open_session(opts)
    try:
        tracks: list[FusedTrack] = []
        session.declare_subscriber(keys.tracker_track("hpda"),
                                   lambda s: tracks.append(decode(s.payload.to_bytes(), FusedTrack)))
        assert wait_alive(session, [keys.alive("hpda", "h1")], WAIT_S) == set()
        cfg = SonarConfig(clutter_density=2.5e-5, region_half_width=300.0)
        truth: dict[float, np.ndarray] = {}
        lines = list(sonar_scans(cfg, 4))[:10]
        for seq, line in enumerate(lines):
            truth[line["t"]] = np.array(line.pop("truth"))[[0, 3]]
            feed(session, keys.sensor_meas("sonar1"), encode(measurement_from_replay(line, "test", seq)))
        position = Measurement(sensor="sonar1", seq=99, t=1e6, kind="position", z=np.zeros(2), R=np.eye(2))
        feed(session, keys.sensor_meas("sonar1"), encode(position))
        assert wait_until(lambda: service.counters.get("unsupported", 0) == 1)
        assert wait_until(lambda: service.counters["received"] == len(lines) + 1)
        # tracks reach this subscriber asynchronously: wait for the last scan's, not just the input count
        assert wait_until(lambda: any(tr.t == lines[-1]["t"] for tr in tracks)), "no confirmed track at the last scan"
        last = [tr for tr in tracks if tr.t == lines[-1]["t"]]
        errors = [np.linalg.norm(tr.x[[0, 3]] - truth[tr.t]) for tr in last]
        best = last[int(np.argmin(errors))]
        assert errors[int(np.argmin(errors))] < 60.0 and best.extra["existence"] > 0.6
        for tr in tracks:  # a confirmed track stays confirmed until its existence falls below 0.02
            assert tr.extra["status"] == "confirmed" and 0.02 <= tr.extra["existence"] <= 1.0
            assert tr.model == "hpda" and tr.sensors == ("sonar1",) and tr.x.shape == (6,)
    finally:
        service.stop()
        thread.join(WAIT_S)
        close_session(session)
        close_session(router)
    assert code == [0]


def test_bad_config_is_a_clean_error(tmp_path: Path, capsys: Any) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[pda.tracker]\nsnr = -1.0\n")
    assert main(["serve", "hpda", "--sensor", "sonar1", "--config", str(cfg)]) == 2  # the CLI's one-line error
    assert f"{cfg}: pda.tracker.snr" in capsys.readouterr().err
