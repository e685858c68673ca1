"""Track manager (initiation / confirmation / deletion) and ``fedtrack replay`` for pda-ai / hpda."""

import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.config import ConfigError
from fedtrack.jsonl import InputError
from fedtrack.local_filters.pda.config import ExistenceConfig, PDAParams
from fedtrack.local_filters.pda.replay import replay_pda
from fedtrack.local_filters.pda.tracks import initial_manager, manager_step, tracker_spec

R = 225.0 * np.eye(2)


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_clean_target_is_confirmed_after_three_updates_then_deleted(algorithm: str):
    spec = tracker_spec(algorithm, PDAParams(pd=0.9, clutter_density=1e-5), ExistenceConfig())
    rng = np.random.default_rng(0)
    ms = initial_manager()
    statuses = []
    for k in range(12):
        pos = np.array([1000.0 + 100.0 * k, 2000.0])
        visible = k < 8
        z = (pos + rng.normal(size=2) * 15.0)[None, :] if visible else np.zeros((0, 2))
        amp = np.full(len(z), spec.c.tau + 40.0)
        ms, rep = manager_step(spec, ms, 25.0 * k, z, amp, R)
        statuses.append((len(rep.tracks), int(rep.tracks.confirmed.sum()), len(rep.deleted)))
    # born at scan 1 from the pair (0, 1); updated at 2, 3, 4
    assert statuses[1] == (1, 0, 0)
    first_confirmed = next(k for k, s in enumerate(statuses) if s[1] == 1)
    assert first_confirmed <= 4
    # tentative duplicates of the target are pruned once confirmed: one confirmed track
    assert all(s[1] == 1 for s in statuses[first_confirmed:8])
    # without detections the existence decays below the deletion threshold
    assert statuses[-1][0] == 0
    assert sum(s[2] for s in statuses[8:]) >= 1


def test_no_track_from_detections_too_far_apart():
    """Reach over 25 s: 10 m/s x 25 s plus sqrt(9.21 x 2 x 225) = 64.38 m of noise, 314.38 m."""
    spec = tracker_spec("hpda", PDAParams(), ExistenceConfig(max_speed=10.0))
    ms = initial_manager()
    ms, _ = manager_step(spec, ms, 0.0, np.array([[0.0, 0.0]]), np.array([30.0]), R)
    ms, rep = manager_step(spec, ms, 25.0, np.array([[314.5, 0.0]]), np.array([30.0]), R)
    assert len(rep.tracks) == 0
    ms, rep = manager_step(spec, ms, 50.0, np.array([[628.7, 0.0]]), np.array([30.0]), R)
    assert len(rep.tracks) == 1


def write_scans(path: Path, scans: list[dict]) -> Path:
    path.write_text("".join(json.dumps(s) + "\n" for s in scans))
    return path


def good_scan(t: float, x: float) -> dict:
    return {"t": t, "sensor": "s1", "detections": [{"z": [x, 0.0], "amplitude": 40.0}],
            "R": [[225.0, 0.0], [0.0, 225.0]]}


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_replay_outputs_statuses(tmp_path: Path, algorithm: str):
    scans = [good_scan(25.0 * k, 100.0 * k) for k in range(6)] + [
        {**good_scan(25.0 * k, 0.0), "detections": []} for k in range(6, 10)]
    meas = write_scans(tmp_path / "in.jsonl", scans)
    out = tmp_path / "out.jsonl"
    n = replay_pda(algorithm, meas, None, out)
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert n == len(rows) > 0
    assert {r["status"] for r in rows} == {"tentative", "confirmed", "deleted"}
    for r in rows:
        assert len(r["x"]) == 6 and np.array(r["P"]).shape == (6, 6) and 0 <= r["existence"] <= 1
    conf = [r for r in rows if r["status"] == "confirmed"]
    assert abs(conf[-1]["x"][1] - 4.0) < 1.0  # 100 m per 25 s along x


@pytest.mark.parametrize("bad, message", [
    ({"t": float("nan")}, ":2: t must be a finite number"),
    ({"detections": [{"z": [1.0], "amplitude": 3.0}]}, ":2: detections[0].z must be a list of 2 numbers, got 1"),
    ({"detections": [{"z": [1.0, 2.0], "amplitude": 0.0}]}, ":2: detections[0].amplitude must be positive"),
    ({"detections": [{"z": [1.0, 2.0]}]}, "missing field 'amplitude'"),
    ({"R": [[1.0, 0.5], [0.0, 1.0]]}, ":2: R is not symmetric"),
    ({"R": [[1.0, 2.0], [2.0, 1.0]]}, ":2: R is not positive definite"),
    ({"t": -5.0}, ":2: t = -5.0 is earlier than the previous scan"),
    ({"sensor": 3}, ":2: sensor must be a non-empty string"),
])
def test_replay_rejects_bad_input_naming_the_line(tmp_path: Path, bad: dict, message: str):
    meas = tmp_path / "in.jsonl"
    meas.write_text(json.dumps(good_scan(0.0, 0.0)) + "\n"
                    + json.dumps({**good_scan(25.0, 100.0), **bad}).replace("NaN", "NaN") + "\n")
    with pytest.raises(InputError) as exc:
        replay_pda("hpda", meas, None, tmp_path / "out.jsonl")
    assert message in str(exc.value) and str(meas) in str(exc.value)


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_a_scan_at_the_time_of_the_last_is_left_out(tmp_path: Path, capsys, algorithm: str):
    """A scan repeated, moved, at the time of the last one (as one sent again under a new number is;
    ``serve hpda`` rejects it, ``time_jump``) was tracked again (``dt = 0``: its rows written, its
    detections pooled with the last scan's for the births); now it is left out and counted: the track
    lines are those without it, byte for byte."""
    scans = [good_scan(25.0 * k, 100.0 * k) for k in range(8)]
    again = [s for k, scan in enumerate(scans) for s in
             ([scan, {**scan, "detections": [{"z": [100.0 * k + 40.0, 10.0], "amplitude": 50.0}]}]
              if k in (2, 5) else [scan])]
    n_clean = replay_pda(algorithm, write_scans(tmp_path / "in.jsonl", scans), None, tmp_path / "clean.jsonl")
    capsys.readouterr()
    n = replay_pda(algorithm, write_scans(tmp_path / "again.jsonl", again), None, tmp_path / "again-out.jsonl")
    assert (f"{algorithm}: 2 scans at the time of their sensor's last one taken, left out "
            "(live: rejected_time_jump)") in capsys.readouterr().err
    assert n == n_clean > 0
    assert (tmp_path / "again-out.jsonl").read_bytes() == (tmp_path / "clean.jsonl").read_bytes()


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_a_scan_whose_tracks_overflow_is_left_out_as_live(tmp_path: Path, capsys, algorithm: str):
    """A valid scan with an amplitude of 1.7e308 overflowed the association weights: the tracks went
    NaN and the next scan's gate query raised (a traceback, exit 1), where ``serve hpda`` rejects the
    scan (rejected_numerical) and keeps its tracks. Now it is left out and counted: the track lines
    are those without it, byte for byte."""
    scans = [good_scan(25.0 * k, 100.0 * k) for k in range(8)]
    hostile = {**good_scan(62.5, 250.0), "detections": [{"z": [250.0, 0.0], "amplitude": 1.7e308}]}
    n_clean = replay_pda(algorithm, write_scans(tmp_path / "in.jsonl", scans), None, tmp_path / "clean.jsonl")
    capsys.readouterr()
    n = replay_pda(algorithm, write_scans(tmp_path / "bad.jsonl", scans[:3] + [hostile] + scans[3:]), None,
                   tmp_path / "bad-out.jsonl")
    assert (f"{algorithm}: 1 scans whose estimate came out non-finite or not positive definite, left out "
            "(live: rejected_numerical)") in capsys.readouterr().err
    assert n == n_clean > 0
    assert (tmp_path / "bad-out.jsonl").read_bytes() == (tmp_path / "clean.jsonl").read_bytes()


@pytest.mark.parametrize("text, key", [
    ("[pda.tracker]\npd = 0.9\nbogus = 1\n", "c.toml: unknown config key pda.tracker.bogus"),
    ("[pda.existence]\nconfirm_scans = 0\n", "c.toml: pda.existence.confirm_scans"),
    ("[pda.tracker]\npd = 1.5\n", "c.toml: pda.tracker.pd"),
    ("[tracker]\npd = 0.9\n", "c.toml: unknown config key tracker"),
])
def test_replay_config_is_strict(tmp_path: Path, text: str, key: str):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    meas = write_scans(tmp_path / "in.jsonl", [good_scan(0.0, 0.0)])
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        replay_pda("pda-ai", meas, cfg, tmp_path / "out.jsonl")


def test_births_pair_each_detection_once_and_tentative_tracks_are_bounded() -> None:
    from fedtrack.local_filters.pda.tracks import TrackSet, pair_births, surplus_tentative

    dist = np.array([[1.0, 2.0, 9.0], [1.5, 8.0, 9.0], [9.0, 9.0, 9.0]])
    cur, prev = pair_births(dist, reach=5.0)
    assert sorted(zip(cur.tolist(), prev.tolist())) == [(0, 1), (1, 0)]  # least total distance, one each
    n = 6
    tracks = TrackSet(np.arange(n), None, np.array([0.9, 0.1, 0.5, 0.3, 0.8, 0.2]), np.zeros(n, np.int64),
                      np.array([True, False, False, False, True, False]), np.zeros(n), np.zeros(n))
    surplus = surplus_tentative(tracks, np.ones(n, bool), limit=2)
    assert surplus.tolist() == [False, True, False, False, False, True]  # keeps tentative 2 and 3


def test_replay_writes_confirmed_tracks_only_on_request(tmp_path) -> None:
    import json

    from fedtrack.local_filters.pda.replay import replay_pda
    from fedtrack.sensors.sonar import SonarConfig, sonar_scans

    meas = tmp_path / "m.jsonl"
    meas.write_text("".join(json.dumps({k: v for k, v in line.items() if k != "truth"}) + "\n"
                            for line in list(sonar_scans(SonarConfig(), 3))[:30]))
    n_all = replay_pda("hpda", meas, None, tmp_path / "all.jsonl")
    n_conf = replay_pda("hpda", meas, None, tmp_path / "conf.jsonl", status="confirmed")
    rows = [json.loads(x) for x in (tmp_path / "conf.jsonl").read_text().splitlines()]
    assert 0 < n_conf < n_all and all(r["status"] == "confirmed" for r in rows)


def dense_run(algorithm: str, existence: ExistenceConfig, scans: int = 40, seed: int = 7) -> tuple[list[int], list[int], list[bool]]:
    """One target in ~200 clutter detections a scan (lambda 5e-5 over 2 km x 2 km); the tracker
    keeps its default lambda (half the true one). Per scan: false confirmed tracks, confirmed
    tracks, and whether a confirmed track is within 60 m of the target."""
    from fedtrack.sensors.sonar import ScenarioConfig, SonarConfig, sonar_scans

    cfg = SonarConfig(clutter_density=5e-5, scenario=ScenarioConfig(duration=25.0 * scans))
    spec = tracker_spec(algorithm, PDAParams(), existence)
    ms = initial_manager()
    false, confirmed, held = [], [], []
    for k, line in zip(range(scans), sonar_scans(cfg, seed)):
        z = np.array([d["z"] for d in line["detections"]]).reshape(-1, 2)
        amp = np.array([d["amplitude"] for d in line["detections"]])
        ms, rep = manager_step(spec, ms, line["t"], z, amp, np.array(line["R"]))
        pos = rep.tracks.state.x[rep.tracks.confirmed][:, [0, 3]]
        near = np.linalg.norm(pos - np.array(line["truth"])[[0, 3]], axis=1) < 60.0
        false.append(int(np.sum(~near)))
        confirmed.append(len(pos))
        held.append(bool(np.any(near)))
    return false, confirmed, held


@pytest.mark.parametrize("algorithm", ["pda-ai", "hpda"])
def test_dense_clutter_confirms_the_target_and_few_false_tracks(algorithm: str) -> None:
    false, confirmed, held = dense_run(algorithm, ExistenceConfig())
    assert np.mean(false) <= 0.5 and max(confirmed) <= 3
    assert np.mean(held[20:]) >= 0.8  # the target is confirmed and kept


def test_dense_clutter_without_the_false_track_rules_confirms_many(monkeypatch) -> None:
    """The same run with the evidence test off, no shared-detection pruning and every update above the
    threshold counted (the supported streak off): the rules are what keeps the false tracks out."""
    import fedtrack.local_filters.pda.tracks as tracks

    monkeypatch.setattr(tracks, "shared_detection_losers", lambda dominant, evidence, senior: np.zeros(dominant.shape[0], bool))
    false, _, _ = dense_run("pda-ai", ExistenceConfig(false_track_rate=0.0, supported_streak=False), scans=25)
    assert np.mean(false) > 1.0


def test_one_detection_supports_one_tentative_track() -> None:
    from fedtrack.local_filters.pda.tracks import shared_detection_losers

    dominant = np.array([3, 3, 3, -1, 5, 5, 3])
    evidence = np.array([10.0, 30.0, 20.0, 99.0, 1.0, 2.0, 0.0])
    senior = np.array([False, False, False, False, False, False, True])
    # detection 3: the confirmed track (6) ranks first whatever its evidence; detection 5: the larger evidence
    assert shared_detection_losers(dominant, evidence, senior).tolist() == [True, True, True, False, True, False, False]


def test_evidence_threshold_grows_with_the_births_of_a_scan() -> None:
    e = ExistenceConfig(false_track_rate=0.01)
    assert e.evidence_threshold(1) == pytest.approx(np.log(100.0))
    assert e.evidence_threshold(200) == pytest.approx(np.log(20000.0))
    assert ExistenceConfig(false_track_rate=0.0).evidence_threshold(200) == -np.inf


def one_detection_then_misses(algorithm: str, existence: ExistenceConfig) -> list[bool]:
    """Confirmed flags, scan by scan, of a track born from two detections (scans 0, 1) that gets one
    strong detection (scan 2) and then none (scans 3-6), at P_D = 0.5."""
    spec = tracker_spec(algorithm, PDAParams(pd=0.5, clutter_density=2.5e-5), existence)
    ms, flags = initial_manager(), []
    for k in range(7):
        z = np.array([[100.0 * k, 0.0]]) if k < 3 else np.zeros((0, 2))
        ms, rep = manager_step(spec, ms, 25.0 * k, z, np.full(len(z), spec.c.tau + 30.0), R)
        flags.append(bool(rep.tracks.confirmed.any()))
    return flags


def test_misses_do_not_count_toward_confirmation() -> None:
    """At P_D = 0.5 a miss costs little existence (1 - delta = 1 - P_D P_G = 0.505), so an IPDA-AI
    track that caught one target detection (existence 1.00) stayed above 0.6 through the misses that
    followed (0.96, 0.89) and was confirmed on them at scan 4, two scans after its last detection (a
    clutter-born track crossing the target ran away confirmed). Now only updates that raise the
    existence count; the paper's rule (``supported_streak = false``) still confirms it. (HPDA's
    eq (16) takes one detection's existence to 0.41 only: its case is the Monte Carlo below.)"""
    assert not any(one_detection_then_misses("pda-ai", ExistenceConfig()))
    assert one_detection_then_misses("pda-ai", ExistenceConfig(supported_streak=False))[4]


def test_few_false_confirmations_at_low_detection_probability() -> None:
    """Paper 001's target and clutter at P_D = 0.5, 6 seeded runs of 61 scans: IPDA-AI tracks confirmed
    more than 60 m from the target. Before the supported streak 20 in 366 scans, five times the
    false-track test's bound (0.01 a scan, 3.7); now 2. (HPDA: 4 -> 3, within the noise.)"""
    import dataclasses

    from fedtrack.sensors.sonar import SonarConfig, sonar_scans

    sonar = dataclasses.replace(SonarConfig(), pd=0.5)
    spec = tracker_spec("pda-ai", PDAParams(pd=0.5, clutter_density=sonar.clutter_density), ExistenceConfig())
    false, scans = 0, 0
    for seed in range(1, 7):
        ms = initial_manager()
        for line in sonar_scans(sonar, seed):
            z = np.array([d["z"] for d in line["detections"]]).reshape(-1, 2)
            amp = np.array([d["amplitude"] for d in line["detections"]])
            ms, rep = manager_step(spec, ms, line["t"], z, amp, np.array(line["R"]))
            off = np.linalg.norm(rep.tracks.state.x[:, [0, 3]] - np.array(line["truth"])[[0, 3]], axis=1) > 60.0
            false += int(np.sum(rep.newly_confirmed & off))
            scans += 1
    assert false <= 0.01 * scans


def confirmed_on_alternate_detections(algorithm: str, existence: ExistenceConfig) -> list[bool]:
    """Confirmed flags, scan by scan, of a track born from two detections (scans 0, 1) of a target at
    P_D = 0.5 detected on every other scan after (2, 4, 6), no clutter."""
    spec = tracker_spec(algorithm, PDAParams(pd=0.5, clutter_density=2.5e-5), existence)
    ms, flags = initial_manager(), []
    for k in range(8):
        z = np.array([[100.0 * k, 0.0]]) if k < 2 or k % 2 == 0 else np.zeros((0, 2))
        ms, rep = manager_step(spec, ms, 25.0 * k, z, np.full(len(z), spec.c.tau + 30.0), R)
        flags.append(bool(rep.tracks.confirmed.any()))
    return flags


def test_hpda_existence_takes_the_amplitudes_as_ipda_ai() -> None:
    """Eq (16) takes the selected detection's rank but not its amplitude: one strong target detection
    raised an HPDA track's existence to 0.41 (IPDA-AI's eq (9): 1.00), so at P_D = 0.5 the streak of
    three rarely began and HPDA confirmed the target 190 s after IPDA-AI (60 seeded runs, docs/hpda.md).
    With eq (9)'s ratio (``amplitude_existence``, default) HPDA confirms as IPDA-AI does; the paper's
    eq (16) (``amplitude_existence = false``) still does not confirm this track."""
    ipda = confirmed_on_alternate_detections("pda-ai", ExistenceConfig())
    assert ipda[6] and not ipda[5]
    assert confirmed_on_alternate_detections("hpda", ExistenceConfig()) == ipda
    assert not any(confirmed_on_alternate_detections("hpda", ExistenceConfig(amplitude_existence=False)))


def held_after_onset(max_accel: float, seed: int) -> float:
    """Share of the scans from the maneuver's onset (800 s) with a confirmed track within 60 m of a
    target turning at 0.01 g (10x the paper's maneuver), no clutter, PDA-AI with the default rule."""
    import dataclasses

    from fedtrack.sensors.sonar import G0, ScenarioConfig, SonarConfig, scan, truth_states

    sonar = dataclasses.replace(SonarConfig(), pd=0.999, clutter_density=1e-9,
                                scenario=ScenarioConfig(maneuver_accel=(0.0, -0.01 * G0)))
    spec = tracker_spec("pda-ai", PDAParams(pd=0.999, clutter_density=1e-9, max_accel=max_accel), ExistenceConfig())
    times, truth = truth_states(sonar.scenario)
    rng, ms, held = np.random.default_rng(seed), initial_manager(), []
    for k, (t, x) in enumerate(zip(times, truth)):
        dets = scan(rng, sonar, k, x)
        ms, rep = manager_step(spec, ms, t, dets.z, dets.amplitude, sonar.sigma_r**2 * np.eye(2))
        if t >= 800.0:
            off = np.linalg.norm(rep.tracks.state.x[:, [0, 3]] - x[[0, 3]], axis=1)
            held.append(bool(np.any(rep.tracks.confirmed & (off <= 60.0))))
    return float(np.mean(held))


@pytest.mark.parametrize("seed", [1, 2])
def test_a_maneuver_model_holds_a_target_beyond_sigma_a(seed: int) -> None:
    """The paper's Singer model (sigma_a 0.01 m/s^2) loses a 0.01 g maneuver at its onset, even without
    clutter, and every track the manager starts again loses it too: the target was held in 8 % of the
    scans after the onset (30 seeded runs, docs/hpda.md). With ``max_accel`` (the targets' largest
    acceleration, here 0.1 g) a second Singer model of ``max_accel / sqrt(3)`` runs in an IMM and the
    target is held throughout."""
    from fedtrack.sensors.sonar import G0

    assert held_after_onset(0.1 * G0, seed) >= 0.95
    assert held_after_onset(0.0, seed) < 0.3


def test_an_imm_of_two_equal_models_is_the_one_model_tracker() -> None:
    """Two Singer models of the same sigma_a (``max_accel = sqrt(3) sigma_a``): mixing, the models'
    associations, their probabilities and the combination give the one-model tracker's tracks."""
    import dataclasses

    from fedtrack.sensors.sonar import SonarConfig, sonar_scans

    sonar = dataclasses.replace(SonarConfig(), clutter_density=5e-5)
    one = tracker_spec("hpda", PDAParams(clutter_density=5e-5), ExistenceConfig())
    two = tracker_spec("hpda", PDAParams(clutter_density=5e-5, max_accel=np.sqrt(3.0) * one.params.sigma_a),
                       ExistenceConfig())
    assert len(two.params.sigmas) == 2 and np.isclose(two.params.sigmas[1], one.params.sigmas[0])
    a, b = initial_manager(), initial_manager()
    for line in list(sonar_scans(sonar, 3))[:20]:
        z = np.array([d["z"] for d in line["detections"]]).reshape(-1, 2)
        amp = np.array([d["amplitude"] for d in line["detections"]])
        a, ra = manager_step(one, a, line["t"], z, amp, np.array(line["R"]))
        b, rb = manager_step(two, b, line["t"], z, amp, np.array(line["R"]))
        assert ra.tracks.ids.tolist() == rb.tracks.ids.tolist()
        assert ra.tracks.confirmed.tolist() == rb.tracks.confirmed.tolist()
        np.testing.assert_allclose(rb.tracks.state.x, ra.tracks.state.x, rtol=0, atol=1e-6)
        np.testing.assert_allclose(rb.tracks.existence, ra.tracks.existence, rtol=0, atol=1e-9)
    assert np.any(rb.tracks.confirmed)


@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_max_accel_must_be_finite_and_not_negative(value: float) -> None:
    from fedtrack.config import ConfigError

    with pytest.raises(ConfigError, match="max_accel: must be a finite number >= 0"):
        PDAParams(max_accel=value).validate()
