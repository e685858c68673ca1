"""Online sensor registration at the track-to-track centre (fusion_center/mtt/centre/registration.py)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from support import numbered_measurements
from test_hostile_messages import KEYS, Bus, assert_recording_replays, mtt_services

from fedtrack.cli import main as cli
from fedtrack.fusion_center.mtt.centre import registration
from fedtrack.fusion_center.mtt.centre.consistency import innovations
from fedtrack.fusion_center.mtt.centre.registration import (
    PRIOR_CLOCK_S,
    PRIOR_OFFSET_M,
    WINDOW_ROOM,
    InformationWindow,
    SensorRegistration,
    chi2_of,
    design,
    medoid,
    scan_information,
    sensor_frame,
    solve_estimate,
)
from fedtrack.local_filters.mtt.local import LocalReport, Resets
from fedtrack.wire import TrackReport, TrackResets, encode

RNG = np.random.default_rng(54)


def observations(n: int, theta: np.ndarray, sigma: float = 0.0, dim: int = 4) -> tuple[np.ndarray, ...]:
    """``n`` position observations of random states ``X`` by a sensor registered off by ``theta`` (its
    offsets, then its clock offset: each detection of the target ``theta[-1]`` seconds before its stamp),
    with noise ``sigma`` (0: none), and the central predictions ``(X, P)``."""
    X = RNG.normal(0.0, 1.0, (n, dim)) * np.tile([3000.0, 20.0], dim // 2)
    pos, vel = np.arange(0, dim, 2), np.arange(1, dim, 2)
    H = np.zeros((n, 2, dim))
    H[:, 0, 0] = H[:, 1, 2] = 1.0
    P = np.broadcast_to(np.diag(np.tile([25.0, 4.0], dim // 2)), (n, dim, dim)).copy()
    R = np.broadcast_to(np.diag([100.0, 150.0]), (n, 2, 2)).copy()
    truth = X[:, pos[:2]] + theta[:2] - theta[-1] * X[:, vel[:2]]
    z = truth + sigma * RNG.standard_normal((n, 2))
    return H, R, z, X, P


def test_the_estimate_is_the_weighted_least_squares_one_and_exact_without_noise() -> None:
    """Noise-free observations of a known offset (30 m, -20 m) and clock offset (+2 s) give them back (to the
    weak prior's pull: 4e-6 m here, 1e-7 of the offset); with noise, the information form equals the weighted least
    squares solution of the stacked, whitened rows (the prior two rows more) to round-off."""
    theta = np.array([30.0, -20.0, 2.0])
    H, R, z, X, P = observations(40, theta)
    est, _ = solve_estimate(*scan_information(H, *innovations(H, R, z, X, P), X, 3)[:2])
    assert np.allclose(est, theta, rtol=0, atol=1e-5)
    H, R, z, X, P = observations(40, theta, sigma=12.0)
    Y, y, _ = scan_information(H, *innovations(H, R, z, X, P), X, 3)
    est, cov = solve_estimate(Y, y)
    S = H @ P @ np.swapaxes(H, 1, 2) + R
    L = np.linalg.cholesky(np.linalg.inv(S))  # whitening: L' nu has unit covariance
    A = design(H, X, 3)
    rows = np.concatenate([np.einsum("nmk,nml->nkl", L, A).reshape(-1, 3),
                           np.diag([1 / PRIOR_OFFSET_M, 1 / PRIOR_OFFSET_M, 1 / PRIOR_CLOCK_S])])
    rhs = np.concatenate([np.einsum("nmk,nm->nk", L, z - np.einsum("nmd,nd->nm", H, X)).ravel(), np.zeros(3)])
    lstsq = np.linalg.lstsq(rows, rhs, rcond=None)[0]
    assert np.allclose(est, lstsq, rtol=0, atol=1e-9 * np.abs(lstsq).max())
    assert np.allclose(cov, np.linalg.inv(rows.T @ rows), rtol=1e-9, atol=0)
    assert np.all(np.abs(est - theta) < 5 * np.sqrt(np.diag(cov)))


def feed(reg: SensorRegistration, sensors: dict[str, np.ndarray], scans: int, live: list[str]) -> None:
    """``scans`` scans of 20 observations of each sensor (offsets ``sensors[s]``, less its correction once
    made), 1 s apart, noise 10 m."""
    for k in range(scans):
        for s, theta in sensors.items():
            H, R, z, X, P = observations(20, theta - reg.applied.get(s, 0.0), sigma=10.0)
            reg.add(s, float(k), (H, *innovations(H, R, z, X, P)), X, 5.0, live, 20)


def test_one_sensor_off_the_consensus_is_corrected_and_the_honest_ones_are_not() -> None:
    """s2 off by (15, -10) m and +0.5 s (within the gate: a sensor is estimated only while half its innovations
    are), every estimate of s1, s2 and s3 also pulled by (-10, 5) m, 0.3 s (the
    central tracks' pull, common to all): s2 alone is corrected, at its first test with three estimates, by
    its offset against the consensus; s1 and s3 never (their estimates against the medoid are noise)."""
    pull = np.array([-10.0, 5.0, 0.3])
    off = np.array([15.0, -10.0, 0.5])
    reg = SensorRegistration(3, 3.0)
    feed(reg, {"s1": pull, "s2": pull + off, "s3": pull}, 6, ["s1", "s2", "s3"])
    assert set(reg.applied) == {"s2"} and reg.corrections == 1
    error = reg.applied["s2"] - off
    assert error @ np.linalg.solve(reg.made[0].cov, error) < reg.threshold  # within the correction's covariance
    assert reg.made[0].t == 1.0 and reg.made[0].sensor == "s2"  # at t = 0 s3's estimate came after s2's
    assert all(reg.estimates[s].reference is not None and reg.estimates[s].chi2 < reg.threshold for s in ("s1", "s3"))


def reference_medoid(estimates: dict[str, tuple[np.ndarray, np.ndarray]]) -> str:
    """The medoid as main computed it before session loadcut56: one solve per pair of sensors."""
    names = sorted(estimates)
    cost = dict.fromkeys(names, 0.0)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            dist = math.sqrt(chi2_of(estimates[a][0] - estimates[b][0], estimates[a][1] + estimates[b][1]))
            cost[a] += dist
            cost[b] += dist
    return min(names, key=cost.__getitem__)


def test_the_medoid_solves_its_pairs_in_one_call_to_the_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """The medoid's pairs (six of four sensors) are solved in one call, each pair's chi-square equal to the bit to
    :func:`chi2_of`'s of its difference either way round (the test reads it, no solve of its own), the medoid
    the one of a solve per pair (500 seeded sets of 1-6 estimates, 3 and 4 parameters). A scan of one of four
    sensors makes two solves, its information's and the consensus's (a fixed cost of every region centre's
    report, docs/bench.md; before, eight: one per pair and the sensor's test again); the prior's information
    is made once per size."""
    rng = np.random.default_rng(56)
    for _ in range(500):
        k = int(rng.integers(3, 5))
        est = {}
        for n in range(int(rng.integers(1, 7))):
            A = rng.standard_normal((k, k)) * 10.0 ** rng.integers(-3, 4)
            est[f"s{n}"] = (rng.standard_normal(k) * 10.0 ** rng.integers(-2, 3), A @ A.T + 1e-3 * np.eye(k))
        ref, chi2 = medoid(est)
        assert ref == reference_medoid(est) and len(chi2) == len(est) * (len(est) - 1) // 2
        for (a, b), c in chi2.items():
            C = est[a][1] + est[b][1]
            assert c == chi2_of(est[a][0] - est[b][0], C) == chi2_of(est[b][0] - est[a][0], est[b][1] + est[a][1])
    reg = SensorRegistration(3, 3.0)
    live = ["s1", "s2", "s3", "s4"]
    feed(reg, {s: np.zeros(3) for s in live}, 4, live)
    solves: list[int] = []
    solve = np.linalg.solve
    monkeypatch.setattr(registration.np.linalg, "solve", lambda *a: solves.append(1) or solve(*a))
    H, R, z, X, P = observations(40, np.zeros(3), sigma=10.0)
    reg.add("s1", 4.0, (H, *innovations(H, R, z, X, P)), X, 5.0, live, 40)
    assert len(solves) == 2 and reg.estimates["s1"].reference is not None
    monkeypatch.setattr(registration.np, "stack", None)  # the pairs as arrays of a list, not np.stack (load57)
    reg.add("s2", 4.0, (H, *innovations(H, R, z, X, P)), X, 5.0, live, 40)
    assert len(solves) == 4 and reg.estimates["s2"].reference is not None
    assert registration.prior_information(3) is registration.prior_information(3)
    assert not registration.prior_information(3).flags.writeable


def test_a_window_sums_its_scans_as_adding_them_one_by_one_to_the_bit() -> None:
    """A sensor's window keeps its scans' information as rows of one array and sums them in one reduction
    (load57: before, Python's ``sum`` over the scans' arrays at every report); the sums are those of adding the
    scans one by one from 0, to the bit (a -0.0 sum too), as scans leave and come, the rows move to the front
    and the array grows."""
    rng = np.random.default_rng(57)
    window, scans = InformationWindow(3), []
    for k in range(5 * WINDOW_ROOM):
        Y, y = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-6, 8), rng.normal(size=3) * 10.0 ** rng.uniform(-6, 8)
        Y[0, 1], y[2] = -0.0, -0.0  # a column of -0.0 only: Python's sum from 0 gives 0.0
        window.append(float(k), Y, y, k % 7, 10)
        scans.append((float(k), Y, y, k % 7, 10))
        cut = k - (3 if k < 2 * WINDOW_ROOM else 2 * WINDOW_ROOM - 1) + 0.5  # a short window, then one that grows
        assert window.drop_before(cut) == (scans[0][0] < cut)
        scans = [e for e in scans if e[0] >= cut]
        Ys, ys, n, observed = window.sums()
        want_Y, want_y = sum(e[1] for e in scans), sum(e[2] for e in scans)
        assert len(window) == len(scans) and n == sum(e[3] for e in scans) and observed == 10 * len(scans)
        assert Ys.tobytes() == want_Y.tobytes() and ys.tobytes() == want_y.tobytes()
    assert WINDOW_ROOM < window.rows.shape[0] <= 4 * WINDOW_ROOM  # grown, and bounded by twice the window


def test_a_sensor_mostly_beyond_the_gate_is_not_estimated() -> None:
    """s2 50 m off against predictions of 5 m and noise of 10-12 m: most of its innovations fall beyond the
    gate (here 27 of 120 within it, above ``MIN_OBSERVATIONS``), and those within it are the tail nearest
    the consensus, no sample of its offset (a sensor is estimated only while half of its observations are);
    s2 gets no estimate and no correction."""
    reg = SensorRegistration(3, 3.0)
    feed(reg, {"s1": np.zeros(3), "s2": np.array([35.4, 35.4, 0.0]), "s3": np.zeros(3)}, 6, ["s1", "s2", "s3"])
    assert reg.corrections == 0 and "s2" not in reg.estimates and "s1" in reg.estimates


def test_with_two_live_sensors_nothing_is_corrected_only_reported() -> None:
    """Which of two sensors is off cannot be told: the estimates (against the central tracks) are reported,
    no sensor is corrected."""
    reg = SensorRegistration(3, 3.0)
    feed(reg, {"s1": np.zeros(3), "s2": np.array([15.0, -10.0, 0.5])}, 4, ["s1", "s2"])
    assert reg.corrections == 0 and not reg.applied
    assert reg.estimates["s2"].reference is None and reg.estimates["s2"].chi2 > reg.threshold


def test_a_corrected_report_is_on_the_consensus_clock_and_its_resets_back_on_the_sensors() -> None:
    """The correction takes the offsets off each local estimate and observation, the clock offset off the
    report's time; the resets of the corrected report go back by both."""
    theta = np.array([40.0, 25.0, 1.5])
    x = RNG.normal(0.0, 100.0, (3, 4))
    H = np.zeros((2, 2, 4))
    H[:, 0, 0] = H[:, 1, 2] = 1.0
    report = LocalReport("s2", 10.0, np.arange(3), x, np.broadcast_to(np.eye(4), (3, 4, 4)), np.ones(3, bool),
                         np.array([True, False, True]), H, np.broadcast_to(np.eye(2), (2, 2, 2)), x[[0, 2]][:, [0, 2]],
                         np.zeros(2, bool), np.zeros(0, dtype=np.int64))
    reg = SensorRegistration(3, 3.0, applied={"s2": theta})
    fixed = reg.correct(report)
    assert fixed.t == 8.5
    assert np.array_equal(fixed.x[:, [0, 2]], x[:, [0, 2]] - theta[:2]) and np.array_equal(fixed.x[:, [1, 3]],
                                                                                          x[:, [1, 3]])
    assert np.array_equal(fixed.obs_z, report.obs_z - theta[:2])
    back = sensor_frame(Resets("s2", fixed.t, fixed.ids, fixed.x, fixed.P), theta)
    assert back.t == 10.0 and np.allclose(back.x, x, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 targets, three position sensors (1.0 / 0.7 / 1.3 s), 40 s; and s2's stamps 2 s ahead from t = 15 s."""
    out = tmp_path_factory.mktemp("registration") / "sim"
    assert cli(["simulate", "multitarget", "--targets", "20", "--duration", "40", "--seed", "1", "--out",
                str(out)]) == 0
    with (out / "measurements.jsonl").open() as f, (out / "clock.jsonl").open("w") as g:
        for line in f:
            m = json.loads(line)
            if m["sensor"] == "s2" and m["t"] >= 15.0:
                m["t"] += 2.0
            g.write(json.dumps(m) + "\n")
    return out


def mean_gospa(scenario: Path, measurements: str, algorithm: str, capsys: pytest.CaptureFixture) -> tuple[float, str]:
    """The replay's mean GOSPA and its stderr."""
    out = scenario / f"{measurements}.{algorithm}.out"
    capsys.readouterr()
    assert cli(["replay", "--algorithm", algorithm, "--measurements", str(scenario / f"{measurements}.jsonl"),
                "--config", str(scenario / "config.toml"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert cli(["evaluate", "--tracks", str(out), "--truth", str(scenario / "truth.jsonl"), "--json",
                str(out.with_suffix(".json"))]) == 0
    return json.loads(out.with_suffix(".json").read_text())["mean"]["gospa"], err


def test_a_sensor_clock_two_seconds_ahead_is_found_and_corrected(scenario: Path, capsys: pytest.CaptureFixture,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """s2's stamps 2 s ahead from t = 15 s (``mtt-decentralized``): s2 is corrected within a few scans, by a
    clock offset near +2 s (measured: at 20.5 s by +1.12 s, at 24.98 s by +0.82 s), and the pictures are nearer
    the truth than without the correction (the test's quantile infinite: nothing is ever significant; measured
    mean GOSPA 82.05 m against 115.63 m, as on main)."""
    with_it, err = mean_gospa(scenario, "clock", "mtt-decentralized", capsys)
    line = next(x for x in err.splitlines() if "sensors' registration corrected:" in x)
    assert "s1 at" not in line and "s3 at" not in line
    first = float(line.split("s2 at t=")[1].split(" ")[0])
    assert 15.0 <= first <= 25.0, line
    end = next(x for x in err.splitlines() if "registration corrections at the end:" in x)
    assert 1.7 <= float(end.split("clock ")[1].split(" s")[0]) <= 2.3, end
    monkeypatch.setattr(registration, "FALSE_ALARM", 0.0)
    without, err = mean_gospa(scenario, "clock", "mtt-decentralized", capsys)
    assert "registration corrected" not in err
    assert with_it < without - 5.0, (with_it, without)


def test_honest_data_is_not_corrected(scenario: Path, capsys: pytest.CaptureFixture) -> None:
    """The same 40 s without the clock offset (``mtt-federated``): no sensor corrected."""
    _, err = mean_gospa(scenario, "measurements", "mtt-federated", capsys)
    assert "mtt-federated: 0 registration corrections" in err and "registration corrected" not in err


def test_the_live_centre_corrects_reports_and_its_recording_replays_to_its_pictures(
        scenario: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``serve mtt-centre`` (in-process, federated, its trackers and recorder on a bus) with s2's stamps 2 s
    ahead from t = 15 s, the first 30 s: it counts the correction, names s2 in its status, logs it, sends
    s2's resets on s2's own clock (the stamps of s2's reports), and its recording replays to its pictures
    (the picture clock on the corrected times in both)."""
    services = mtt_services(tmp_path)
    bus = Bus(list(services.values()))
    with caplog.at_level("WARNING"):
        for m in numbered_measurements(scenario / "clock.jsonl", until=30.0):
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    centre = services["centre"]
    assert centre.counters["centre_registration_corrections"] >= 1 and centre.counters["centre_registered_sensors"] == 1
    assert "registration corrected: s2" in centre.status and centre.counters["rejected"] == 0
    assert any(r.getMessage().startswith("sensor s2 off the consensus at t=") for r in caplog.records)
    reports = {(m.sensor, m.seq): m.t for m in bus.of(TrackReport)}
    resets = [m for m in bus.of(TrackResets) if m.sensor == "s2" and m.ids]
    assert resets and all(m.t == reports[("s2", m.seq)] for m in resets)
    assert_recording_replays(services, bus, tmp_path)
