"""Per-sensor consistency monitoring at the track-to-track centre (fusion_center/mtt/centre/consistency.py):
a sensor whose detections disagree with the others' is flagged, an honest run flags no one, and a
flagged sensor's observations are left out of the fusion until it is cleared."""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from support import numbered_measurements
from test_hostile_messages import KEYS, Bus, assert_recording_replays, mtt_services

from fedtrack.cli import main as cli
from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre, consistency
from fedtrack.fusion_center.mtt.centre.consistency import (
    CLEAR_P,
    FALSE_ALARM,
    SensorConsistency,
    Transition,
    cap,
    innovations,
    normalized_innovations,
    relative_tail,
)
from fedtrack.fusion_center.mtt.centre.track_to_track import excluded_sensors
from fedtrack.wire import TrackReport, encode


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 targets, three position sensors (1.0 / 0.7 / 1.3 s), 40 s, light clutter; the config without the
    sensors' noise floors that ``simulate`` declares (they would raise an ``R`` claimed 100x smaller back to the
    sensor's noise before the monitor sees it: tests/test_mtt_noise_floor.py), so that the monitor is tested
    alone."""
    out = tmp_path_factory.mktemp("consistency") / "sim"
    assert cli(["simulate", "multitarget", "--targets", "20", "--duration", "40", "--clutter", "2", "--seed", "1",
                "--out", str(out)]) == 0
    config = out / "config.toml"
    lines = config.read_text().splitlines(keepends=True)
    floors = [line for line in lines if line.startswith("sensor.")]  # the position sensors' floors (all they declare)
    assert floors
    config.write_text("".join(line for line in lines if line not in floors))
    return out


def altered(src: Path, dst: Path, sensor: str, onset: float, *, r_scale: float = 1.0, bias: float = 0.0,
            until: float = math.inf) -> None:
    """``sensor``'s scans from ``onset`` on (before ``until``) with ``R`` claimed ``r_scale`` times its own,
    positions moved by ``bias`` m."""
    with src.open() as f, dst.open("w") as g:
        for line in f:
            m = json.loads(line)
            if m["sensor"] == sensor and onset <= m["t"] < until:
                m["R"] = (np.array(m["R"]) * r_scale).tolist()
                for d in m["detections"]:
                    d["z"][0] += bias / math.sqrt(2)
                    d["z"][1] += bias / math.sqrt(2)
            g.write(json.dumps(m) + "\n")


def flagged(scenario: Path, measurements: Path, algorithm: str, capsys: pytest.CaptureFixture) -> str:
    """``replay``'s line of the sensors flagged inconsistent ("" if none)."""
    out = measurements.with_suffix(f".{algorithm}.out")
    capsys.readouterr()
    assert cli(["replay", "--algorithm", algorithm, "--measurements", str(measurements), "--config",
                str(scenario / "config.toml"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    return next((line for line in err.splitlines() if "sensors flagged inconsistent:" in line), "")


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_an_honest_run_flags_no_one(scenario: Path, algorithm: str, capsys: pytest.CaptureFixture) -> None:
    assert flagged(scenario, scenario / "measurements.jsonl", algorithm, capsys) == ""


@pytest.mark.parametrize("fault", [{"r_scale": 0.01}, {"bias": 200.0}], ids=["R-100x-small", "bias-200m"])
def test_a_faulty_sensor_is_flagged_within_a_few_scans(scenario: Path, tmp_path: Path, fault: dict,
                                                       capsys: pytest.CaptureFixture) -> None:
    """s2 (0.7 s) claims R 100x smaller than its noise, or is 200 m off, from t = 20: flagged within
    15 s (measured here: 2.8 s and 14.0 s; a 200 m bias mostly starts central tracks of its own, which no
    other sensor supports and the test does not see), and no other sensor is."""
    bad = tmp_path / "m.jsonl"
    altered(scenario / "measurements.jsonl", bad, "s2", 20.0, **fault)
    line = flagged(scenario, bad, "mtt-federated", capsys)
    first = re.search(r"sensors flagged inconsistent: (\w+) at t=([0-9.]+)", line)
    assert first and first[1] == "s2" and 20.0 <= float(first[2]) <= 35.0, line
    assert "s1 at" not in line and "s3 at" not in line


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_a_flagged_sensor_is_left_out_until_cleared(scenario: Path, tmp_path: Path, algorithm: str,
                                                    capsys: pytest.CaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """s2 claims ``R`` 100x smaller than its noise from t = 15 to 28: while flagged (three live sensors)
    its reports leave every central track as it was (the same ring entries, none started), get no
    resets and a process-noise factor of 1, and the others' factor counts the fused sensors only (2);
    once cleared its reports are fused again. Before this, a flagged sensor was fused (detection only)."""
    bad = tmp_path / "m.jsonl"
    altered(scenario / "measurements.jsonl", bad, "s2", 15.0, r_scale=0.01, until=28.0)
    seen: dict[str, list] = {"left_out": [], "fused_after": [], "q_others": []}
    answer = TrackToTrackCentre.answer

    def watched(self: TrackToTrackCentre, report, rows=None):  # type: ignore[no-untyped-def]
        before = {cid: self.tracks.entries(cid) for cid in self.tracks}
        fused, cleared = self.counters.fused, self.consistency.onsets and not self.consistency.flagged
        resets, q_scale = answer(self, report, rows)
        if report.sensor in self.excluded:
            assert set(self.tracks) <= set(before) and resets.ids.size == 0 and q_scale == 1.0
            for cid in self.tracks:
                assert all(np.array_equal(a, b) for a, b in zip(self.tracks.entries(cid), before[cid]))
            seen["left_out"].append(report.t)
        elif self.excluded and self.feedback:
            seen["q_others"].append(q_scale)
        if cleared and report.sensor == "s2":
            seen["fused_after"].append(self.counters.fused - fused)
        return resets, q_scale

    monkeypatch.setattr(TrackToTrackCentre, "answer", watched)
    line = flagged(scenario, bad, algorithm, capsys)
    first = re.search(r"sensors flagged inconsistent: (\w+) at t=([0-9.]+)", line)
    assert first and first[1] == "s2" and 15.0 <= float(first[2]) <= 28.0, line
    assert len(seen["left_out"]) >= 3 and min(seen["left_out"]) >= 15.0
    assert seen["fused_after"] and sum(seen["fused_after"]) > 0  # cleared: fused again
    assert all(q == 2.0 for q in seen["q_others"]) and (seen["q_others"] or algorithm == "mtt-decentralized")


def test_exclusion_needs_three_live_sensors_two_of_them_unflagged() -> None:
    """With two sensors the test cannot tell which is wrong: nobody is left out."""
    flags, t, window = {"s2": 10.0}, 20.0, 5.0  # flagged for a whole window at t
    assert excluded_sensors(["s1", "s2", "s3"], flags, t, window) == {"s2"}
    assert excluded_sensors(["s1", "s2"], flags, t, window) == set()
    assert excluded_sensors(["s1", "s2", "s3"], {"s2": 1.0, "s3": 2.0}, t, window) == set()
    assert excluded_sensors(["s1", "s3", "s4"], flags, t, window) == set()


def test_the_relative_test_is_the_f_distribution_under_the_model() -> None:
    """Sums of chi-square innovations of a sensor and of the others: the tail probabilities are
    uniform (a 1e-2 test rejects 1 % of 4,000 seeded windows, within 3 standard errors), and a
    factor common to both sides leaves the test as it was."""
    rng = np.random.default_rng(1)
    n, a, b = 4000, 40, 90
    A, B = rng.chisquare(a, n), rng.chisquare(b, n)
    log_p = np.array([relative_tail(x, a, y, b)[1] for x, y in zip(A, B)])
    rate = float(np.mean(log_p < math.log(1e-2)))
    assert abs(rate - 1e-2) < 3 * math.sqrt(1e-2 * (1 - 1e-2) / n)
    assert relative_tail(7.0 * A[0], a, 7.0 * B[0], b)[1] == pytest.approx(log_p[0], abs=1e-9)
    assert relative_tail(A[0], a, B[0], b)[1] == pytest.approx(math.log(stats.f.sf((A[0] / a) / (B[0] / b), a, b)),
                                                               abs=1e-9)


def test_a_tail_below_the_doubles_range_is_minus_infinity() -> None:
    """The others' innovations all exactly 0 (a copied feed's observations fused right after the
    original's: s1 copied as s9, ``simulate multitarget --targets 20 --duration 120 --seed 2``, at t =
    0.05): the ratio was finite, its F tail 0.0, and its log raised ValueError, ending the replay with a
    traceback; now the tail is -inf (beyond every test)."""
    ratio, log_p = relative_tail(27.67, 26, 0.0, 48)
    assert ratio > 1e290 and log_p == -math.inf
    assert relative_tail(1.0, 2, 0.0, 2)[1] < -690.0 and relative_tail(0.0, 2, 1.0, 2)[1] == 0.0


def test_normalized_innovations_solve_the_innovation_covariance() -> None:
    rng = np.random.default_rng(2)
    H = np.tile(np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), (3, 1, 1))
    L = rng.normal(size=(3, 4, 4))
    P = L @ np.swapaxes(L, 1, 2) + np.eye(4)
    R = np.tile(np.diag([4.0, 9.0]), (3, 1, 1))
    x, z = rng.normal(size=(3, 4)), rng.normal(size=(3, 2))
    got = normalized_innovations(*innovations(H, R, z, x, P))
    for k in range(3):
        nu, S = z[k] - H[k] @ x[k], H[k] @ P[k] @ H[k].T + R[k]
        assert got[k] == pytest.approx(nu @ np.linalg.inv(S) @ nu, rel=1e-9)


def test_innovations_of_a_subset_of_rows_are_those_rows_of_the_whole_to_the_bit() -> None:
    """The registration takes the monitor's innovations and covariances of its rows (the confirmed tracks'),
    made once a report (load57: before, made again from the observations): each row's are its own to the bit."""
    rng = np.random.default_rng(57)
    for n, m in ((1, 2), (37, 2), (300, 3)):
        H = np.zeros((n, m, 6))
        H[:, np.arange(m), 2 * np.arange(m)] = 1.0
        L = rng.normal(size=(n, 6, 6)) * 30.0
        P, R = L @ np.swapaxes(L, 1, 2), np.tile(np.diag(rng.uniform(10.0, 900.0, m)), (n, 1, 1))
        x, z = rng.normal(size=(n, 6)) * 1e4, rng.normal(size=(n, m)) * 1e4
        nu, S = innovations(H, R, z, x, P)
        rows = rng.random(n) < 0.6
        sub_nu, sub_S = innovations(H[rows], R[rows], z[rows], x[rows], P[rows])
        assert nu[rows].tobytes() == sub_nu.tobytes() and S[rows].tobytes() == sub_S.tobytes()


@pytest.mark.parametrize("restarting", [False, True], ids=["plain", "every-report-first"])
def test_the_live_centre_counts_and_logs_a_flagged_sensor(scenario: Path, tmp_path: Path,
                                                        caplog: pytest.LogCaptureFixture, restarting: bool) -> None:
    """``serve mtt-centre`` (in-process, its trackers and recorder on a bus): s2's scans of the first 35 s
    with ``R`` claimed 100x smaller from t = 15 on raise the Health counters (its observations left out
    counted), name s2 in its status and log the onset; its recording replays to its pictures.
    ``restarting``: s2's tracker marks every report ``first`` (a restarted process), which emptied s2's
    window at every report, so that it was never flagged (tour47 session): a restart keeps the sensor's
    window. Its reports keep tracks of earlier scans, so they are no restart (counted ``restarts_ignored``):
    the centre took each as one and the recording listed it, so that the replay restarted s2's tracker
    at every scan where the live one ran on (the first picture apart at t = 6, s2's tentative tracks)."""
    services = mtt_services(tmp_path)
    bus = Bus(list(services.values()))
    if restarting:
        s2, send = services["s2"], services["s2"].publish
        s2.publish = lambda key, msg: send(key, replace(msg, first=True) if isinstance(msg, TrackReport) else msg)
    with caplog.at_level("WARNING"):
        for m in numbered_measurements(scenario / "measurements.jsonl", until=35.0):
            bus.put(KEYS.sensor_meas(m.sensor), encode(replace(m, R=m.R / 100.0) if m.sensor == "s2" and m.t >= 15.0
                                                       else m))
    centre = services["centre"]
    assert centre.counters.get("trackers_restarted", 0) == 0
    assert centre.counters.get("restarts_ignored", 0) == (sum(m.sensor == "s2" for m in bus.of(TrackReport)) - 1
                                                         if restarting else 0)
    assert centre.counters["centre_inconsistency_onsets"] >= 1 and centre.counters["rejected"] == 0
    assert centre.counters["centre_excluded_observations"] > 0  # left out, as replay does (the same centre)
    assert centre.status == "inconsistent sensors: s2"
    assert any("sensor s2 inconsistent at t=" in r.getMessage() and "left out of the fusion" in r.getMessage()
               for r in caplog.records)
    assert not any(f"sensor {s} inconsistent" in r.getMessage() for r in caplog.records for s in ("s1", "s3"))
    assert_recording_replays(services, bus, tmp_path)  # the live centre's exclusion, replayed


def test_a_non_finite_innovation_enters_at_its_cap() -> None:
    """An innovation that came out infinite or NaN adds the cap, not a NaN that would hide the sensor
    from every later test of the window."""
    monitor = SensorConsistency()
    for k in range(4):
        monitor.add("a", float(k), np.full(5, 2.0), 2, 10.0)
        monitor.add("b", float(k) + 0.5, np.array([np.nan, np.inf, 2.0, 2.0, 2.0]), 2, 10.0)
    ratio, log_p = monitor.tests()["b"]
    assert ratio == pytest.approx((2 * cap(2, monitor.cap_tail) + 6.0) / 10.0 / 1.0, rel=1e-12) and np.isfinite(log_p)


class EveryTest(SensorConsistency):
    """The rule as it was before session fixedcost: every sensor's window tested at every scan."""

    def _judge(self, sensor: str, t: float) -> None:
        tests = self.tests()
        if sensor not in tests:
            return
        ratio, log_p = tests[sensor]
        worst = min(lp for _, lp in tests.values())
        if sensor not in self.flagged and log_p < math.log(FALSE_ALARM) and log_p <= worst:
            self.flagged[sensor] = t
            self.onsets += 1
            self.transitions.append(Transition(t, sensor, True, log_p, ratio))
        elif sensor in self.flagged and log_p > math.log(CLEAR_P):
            del self.flagged[sensor]
            self.transitions.append(Transition(t, sensor, False, log_p, ratio))


def test_a_scan_tests_its_own_sensor_alone_unless_it_would_be_flagged(monkeypatch: pytest.MonkeyPatch) -> None:
    """A scan's window test is its own sensor's alone (one F tail a scan, not one per sensor: a fixed cost of
    every region centre's report, docs/bench.md), the others' only when its tail is below ``FALSE_ALARM``
    (a flag needs it to be the worst). Seeded scans of twelve sensors, d's innovations 9x and c's 6x from
    scan 10 (d's scan first: c's tail below the bound while d's is worse), both honest from scan 24: the
    same flags, clears and transitions as testing every sensor at every scan."""
    rng = np.random.default_rng(3)
    new, old = SensorConsistency(), EveryTest()
    calls: list[int] = []
    tail = consistency.relative_tail
    monkeypatch.setattr(consistency, "relative_tail", lambda *a: calls.append(1) or tail(*a))
    tails: list[tuple[int, bool]] = []  # per scan of the new rule: F tails computed, a sensor flagged by it
    for k in range(40):
        for j, sensor in enumerate("dcabefghijkl"):
            nis = rng.chisquare(2, 20) * {"c": 6.0, "d": 9.0}.get(sensor, 1.0) ** (10 <= k < 24)
            t = k + 0.05 * j
            old.add(sensor, t, nis, 2, 3.0)
            before, onsets = len(calls), new.onsets
            new.add(sensor, t, nis, 2, 3.0)
            tails.append((len(calls) - before, new.onsets > onsets))
    assert new.transitions == old.transitions and new.flagged == old.flagged and new.onsets == old.onsets
    assert [tr.sensor for tr in new.transitions if tr.flagged][:1] == ["d"]
    assert any(n > 1 and not flag for n, flag in tails)  # below the bound, not the worst: not flagged
    assert sum(n == 1 for n, _ in tails) > 400 and max(n for n, _ in tails) <= 13  # twelve a scan before


def test_a_window_is_summed_again_only_when_it_changed(monkeypatch: pytest.MonkeyPatch) -> None:
    """A scan sums again only the windows it changed (its own sensor's and those whose oldest scans it ends),
    not every sensor's at every scan (a fixed cost of every region centre's report, docs/bench.md): seeded
    scans of four sensors at 1 Hz, one of them faulty for a while, and a departure: every test's sums equal
    the windows summed afresh (bitwise), and so do the flags, clears and transitions; 1.9 windows summed a scan
    (444 over 235 scans; before, every sensor's: four)."""
    rng = np.random.default_rng(56)
    summed, made = [], 0
    sums = consistency.window_sums
    monkeypatch.setattr(consistency, "window_sums", lambda kept: summed.append(1) or sums(kept))
    new, old = SensorConsistency(), EveryTest()
    for k in range(60):
        for j, sensor in enumerate("abcd"):
            if sensor == "d" and k == 40:
                new.drop("d")
                old.drop("d")
            if sensor == "d" and 40 <= k < 45:
                continue
            nis = rng.chisquare(2, 30) * (8.0 if sensor == "b" and 15 <= k < 25 else 1.0)
            old.add(sensor, k + 0.25 * j, nis, 2, 5.0)
            before = len(summed)
            new.add(sensor, k + 0.25 * j, nis, 2, 5.0)
            made += len(summed) - before
            fresh = {s: (sum(e.nis for e in kept), sum(e.dof for e in kept), sum(e.count for e in kept))
                     for s, kept in new.scans.items()}
            assert new._sums()[0] == fresh
    assert new.transitions == old.transitions and new.flagged == old.flagged and new.onsets == old.onsets
    assert [tr.sensor for tr in new.transitions if tr.flagged] == ["b"]
    assert made < 2.2 * (60 * 4 - 5)


def test_a_sensor_is_left_out_once_flagged_for_a_whole_window() -> None:
    """A flag is a test at 1e-6 of any excess, which a window's thousands of honest innovations pass for a
    moment (1,000 targets: three sensors flagged at t = 1.7-4.25 s, cleared within the window, and their
    exclusion cost 1 % of GOSPA): a sensor is left out only once flagged for a whole window, and only
    with three or more live sensors of which two are not flagged."""
    live, window = ["s1", "s2", "s3", "s4"], 5.0
    assert excluded_sensors(live, {"s2": 4.25}, 9.0, window) == set()
    assert excluded_sensors(live, {"s2": 4.25}, 9.25, window) == {"s2"}
    assert excluded_sensors(live, {"s2": 4.25, "s1": 1.0}, 20.0, window) == {"s1", "s2"}
    assert excluded_sensors(live, {"s2": 4.25, "s1": 1.0, "s3": 1.0}, 20.0, window) == set()
    assert excluded_sensors(live[:2], {"s2": 0.0}, 20.0, window) == set()


def test_a_sensor_pulling_the_tracks_gets_no_honest_sensor_flagged() -> None:
    """A compromised tracker claiming a small ``R`` pulls the central tracks, its own innovations small (its
    reports at the central predictions, or a little off them) and every other sensor's raised: the
    pooled test flagged the honest sensors in turn, the worst first, and two of three flagged switched the
    exclusion off (in process: ``simulate multitarget --seed 1``, s1 from t = 100 s, ``mtt-federated``:
    s2 then s3 flagged, s1 never). A sensor whose excess is matched by another's window lying further
    below the rest is not flagged now; a sensor's own fault, which raises the others' innovations, is
    flagged as before. Seeded chi-square windows of three sensors."""
    def run(scale: dict[str, float], seed: int) -> SensorConsistency:
        rng, monitor = np.random.default_rng(seed), SensorConsistency()
        for k in range(18):  # honest for 6 s, then the fault, in a 5 s window
            for j, sensor in enumerate("abc"):
                monitor.add(sensor, k + 0.3 * j, rng.chisquare(2, 20) * (scale[sensor] if k >= 6 else 1.0), 2, 5.0)
        return monitor

    for seed in range(5):
        pulled = run({"a": 0.2, "b": 1.8, "c": 1.8}, seed)  # a pulls: its innovations a ninth of b's and c's
        assert min(pulled.tests()["b"][1], pulled.tests()["c"][1]) < math.log(FALSE_ALARM)  # failing the pool
        assert pulled.onsets == 0 and not pulled.flagged, seed
        faulty = run({"a": 1.2, "b": 3.0, "c": 1.0}, seed)  # b's own fault raises a's and c's innovations a little
        assert faulty.onsets == 1 and set(faulty.flagged) == {"b"}, seed
