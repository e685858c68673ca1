"""The tracker split into roles (issue 25 item 1): ``gnn`` pictures identical to main 886cab1.

``data/mtt_reference`` holds two seeded scenarios of ``fedtrack simulate multitarget`` (three
position sensors; a radar and a position sensor), their configs, and a fingerprint of the
pictures main 886cab1 (the tracker before the split) wrote for them with each algorithm, with
``maneuver = "none"`` and ``"vdie"`` (the pictures at 886cab1's picture times): per track its id, status, sensors, model, and ``x . w``,
``w' P w`` and the maneuver numbers (``w = 1, 2, ...``), to compare to 1e-12.

Since issue 26's altitude fix the centralized tracker of the radar scenario (its tracks started from
the position sensor's plots at z = 0, then updated by the radar) relinearizes the radar about a
plot's altitude (:func:`~fedtrack.local_filters.mtt.roles.gating.relinearize_altitude`): those two cases
equal 886cab1 with the relinearization taken out, and ``gnn-relinearized.json.gz`` (frozen when it
came) with it.

Since the sensor-coverage session a centralized tracker counts a sensor's scan for a track only
once the sensor detected it or put a detection in its gate (``roles.life.scan_counts``):
``gnn-sensor-counts.json.gz`` (frozen when it came) holds the centralized cases with that rule, and
with every scan counted for every track (``CentralizedEngine.bit`` 0) they equal the references above.

Since the far-radar session a radar's scan counts for a track another sensor also detected only
inside the radar's view its detections show (``roles.life.radar_view``): ``gnn-radar-view.json.gz``
(frozen when it came) holds the radar scenario's centralized cases with that rule, and with every
track in view they equal ``gnn-sensor-counts.json.gz`` (the position scenario's have no radar).

Since the untuned3 session a tracker of scans less than 1 s apart deletes after more misses
(``config.scan_lost``: ``LOST`` a second as well as a scan), which changes the pictures of the
trackers of the 0.7 s and 0.8 s sensors: every case is compared with that taken out
(``LOST_SCAN_S`` = 0).

Since the fastinit session a detection no track took may pair with an earlier one-point start
(two-point starts, :mod:`fedtrack.local_filters.mtt.initiation`): ``gnn-two-point.json.gz`` (frozen
when it came) holds the cases that changes, and with no pairs they equal the references above.

Since the starts2 session a one-point start waits for its pair while its track's velocity is
unmeasured, not only while the track has its one detection (``initiation.unmeasured``):
``gnn-start-waits.json.gz`` (frozen when it came) holds the cases that
changes (the position scenario's ``mtt-federated``: one more tentative track in two pictures, the
ids after it one higher), and with the old rule they equal ``gnn-two-point.json.gz``.
Since the untuned56 session a counting tracker raises its M-of-N count on a position sensor whose
clutter the count would confirm (:func:`~fedtrack.local_filters.mtt.roles.life.count_at`,
``config.raised_count``), and a track-to-track centre then asks for a local confirmation: the radar
scenario's config gives its position sensor the radar's clutter density (8.8e-5, per m rad^2, read as
per m^2: the simulator's before 2026-11-26), so its fusions change; ``gnn-cluttered-count.json.gz``
(frozen when it came) holds them, and with the count as configured they equal the references above.
Since the mixnoise59 session ``mtt-centralized`` gnn keeps the configured count and adds Wald's test on each
scan's evidence (:func:`~fedtrack.local_filters.mtt.roles.life.m_of_n`, ``keeps_evidence``):
``gnn-evidence.json.gz`` (frozen when it came) holds the centralized cases, and without that test they equal
the references above.
Since the clutter61 session every counting tracker keeps the evidence and its count confirms only where Wald's test
passes too (``roles.life.passes_wald``: none of these cases changes), and a pair's track takes its start's evidence
and births share plus the pair's ratio (``initiation.paired_evidence``): ``gnn-paired-evidence.json.gz`` (frozen
when it came) holds the radar scenario's centralized cases, which that changes, and with a pair's track's evidence
started afresh they equal ``gnn-evidence.json.gz``.
"""

from __future__ import annotations

import gzip
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.replay import replay_mtt

DATA = Path(__file__).parent / "data" / "mtt_reference"
REFERENCE = DATA / "gnn-886cab1.json.gz"
RELINEARIZED = DATA / "gnn-relinearized.json.gz"  # the cases the altitude's relinearization changes
SENSOR_COUNTS = DATA / "gnn-sensor-counts.json.gz"  # the centralized cases: the scans counted per track
RADAR_VIEW = DATA / "gnn-radar-view.json.gz"  # the radar scenario's centralized cases: the radar's view
TWO_POINT = DATA / "gnn-two-point.json.gz"  # the cases two-point starts change
START_WAITS = DATA / "gnn-start-waits.json.gz"  # the cases a start waiting while its velocity is unmeasured changes
CLUTTERED = DATA / "gnn-cluttered-count.json.gz"  # the cases a count raised on a cluttered sensor changes
EVIDENCE = DATA / "gnn-evidence.json.gz"  # the centralized cases: Wald's test on each scan's evidence
PAIRED = DATA / "gnn-paired-evidence.json.gz"  # the cases a pair's track taking its start's evidence changes
CASES = [(scenario, maneuver, algorithm) for scenario in ("pos", "radar") for maneuver in ("none", "vdie")
         for algorithm in ("mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized")]
LOCAL_SENSOR = {"pos": "s2", "radar": "r1"}


def fingerprint(path: Path) -> list:
    """Per picture its time and per track ``[id, x . w, w' P w, maneuver numbers . w, digest of the
    rest]``."""
    out = []
    for line in path.read_text().splitlines():
        picture = json.loads(line)
        rows = []
        for track in picture["tracks"]:
            x, P = np.array(track["x"]), np.array(track["P"])
            w = np.arange(1.0, x.size + 1.0)
            man = track.get("maneuver")
            m = 0.0 if man is None else (man["onset"] + 2.0 * man["accel"][0] + 3.0 * man["accel"][1]
                                         + 4.0 * man["statistic"])
            rest = json.dumps([track["status"], track["sensors"], track["model"], man is None])
            rows.append([track["id"], float(x @ w), float(w @ P @ w), m, hashlib.sha1(rest.encode()).hexdigest()[:8]])
        out.append([picture["t"], rows])
    return out


def replay_case(tmp_path: Path, scenario: str, maneuver: str, algorithm: str) -> Path:
    cfg = tmp_path / f"{scenario}-{maneuver}.toml"
    cfg.write_text((DATA / f"{scenario}.toml").read_text().replace("[mtt]\n", f'[mtt]\nmaneuver = "{maneuver}"\n', 1))
    out = tmp_path / f"{scenario}-{maneuver}-{algorithm}.jsonl"
    replay_mtt(algorithm, DATA / f"{scenario}-scans.jsonl", cfg, out,
               sensor=LOCAL_SENSOR[scenario] if algorithm == "mtt-local" else None)
    return out


def assert_fingerprints_equal(got: list, expected: list) -> None:
    # since 886cab1 the replay also writes the picture at the first whole period after the last
    # scan (issue 28 item 6): one more at the end
    assert [t for t, _ in got][:len(expected)] == [t for t, _ in expected] and len(got) <= len(expected) + 1
    for (t, rows), (_, want) in zip(got, expected):
        assert [r[0] for r in rows] == [r[0] for r in want], f"track ids at t = {t}"
        assert [r[4] for r in rows] == [r[4] for r in want], f"status, sensors or model at t = {t}"
        np.testing.assert_allclose(np.array([r[1:4] for r in rows]).reshape(-1, 3),
                                   np.array([r[1:4] for r in want]).reshape(-1, 3), rtol=1e-12, atol=1e-9,
                                   err_msg=f"t = {t}")


@pytest.mark.parametrize("scenario, maneuver, algorithm", CASES)
def test_gnn_pictures_equal_main_886cab1(tmp_path: Path, scenario: str, maneuver: str, algorithm: str,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    from fedtrack.fusion_center.mtt import engines
    from fedtrack.fusion_center.mtt.engines import CentralizedEngine
    from fedtrack.local_filters.mtt import config, initiation, tracker
    from fedtrack.local_filters.mtt.roles import gating, life

    monkeypatch.setattr(config, "LOST_SCAN_S", 0.0)  # a count per scan only, as before the untuned3 session

    key = f"{scenario}-{maneuver}-{algorithm}"
    paired_evidence = json.loads(gzip.decompress(PAIRED.read_bytes()))
    if key in paired_evidence:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)),
                                  paired_evidence[key])
    monkeypatch.setattr(tracker, "paired_evidence", lambda new, init, partner: new)  # as before clutter61
    weighed = json.loads(gzip.decompress(EVIDENCE.read_bytes()))
    if key in weighed:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), weighed[key])
    for module in (engines, initiation, life):  # the count alone, as before the mixnoise59 session
        monkeypatch.setattr(module, "keeps_evidence", lambda params: False)
    raised = json.loads(gzip.decompress(CLUTTERED.read_bytes()))
    if key in raised:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), raised[key])
    for module in (config, life):  # the count as configured, as before the untuned56 session
        monkeypatch.setattr(module, "raised_count", lambda hit, pd, hits, window: (hits, window))
    waited = json.loads(gzip.decompress(START_WAITS.read_bytes()))
    if key in waited:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), waited[key])
        monkeypatch.setattr(initiation, "unmeasured", lambda tracks, std: tracks.hits == 1)  # the one-detection rule
    paired = json.loads(gzip.decompress(TWO_POINT.read_bytes()))
    if key in paired:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), paired[key])
    monkeypatch.setattr(initiation, "pair_starts",  # no two-point starts, as before the fastinit session
                        lambda starts, waiting, t, pos, cov, scale, p: initiation.no_pairing(p.dim))
    viewed = json.loads(gzip.decompress(RADAR_VIEW.read_bytes()))
    if key in viewed:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), viewed[key])
        monkeypatch.setattr(life, "radar_view", lambda x, scan, frame=None: np.ones(x.shape[0], bool))  # all in view
    counted = json.loads(gzip.decompress(SENSOR_COUNTS.read_bytes()))
    if key in counted:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), counted[key])
        monkeypatch.setattr(CentralizedEngine, "bit", lambda self, sensor: 0)  # every scan counts
    relinearized = json.loads(gzip.decompress(RELINEARIZED.read_bytes()))
    if key in relinearized:
        assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), relinearized[key])
        monkeypatch.setattr(gating, "relinearize_altitude", lambda pred, lin, scan, gate_d2: lin)
    expected = json.loads(gzip.decompress(REFERENCE.read_bytes()))[key]
    assert_fingerprints_equal(fingerprint(replay_case(tmp_path, scenario, maneuver, algorithm)), expected)


def test_associator_key_selects_each_associator(tmp_path: Path) -> None:
    from fedtrack.config import ConfigError, load_tables
    from fedtrack.local_filters.mtt.config import ASSOCIATORS, MttSettings
    from fedtrack.local_filters.mtt.tracker import ASSOCIATORS as IMPLEMENTED
    from fedtrack.local_filters.mtt.tracker import track_params

    assert set(IMPLEMENTED) == set(ASSOCIATORS)
    path = tmp_path / "c.toml"
    for name in ASSOCIATORS:
        path.write_text(f'[mtt]\nassociator = "{name}"\n')
        assert track_params(load_tables(path, MttSettings).mtt, "s1", 4).associator.name == name
    path.write_text('[mtt]\nassociator = "pda"\n')
    with pytest.raises(ConfigError, match="associator: must be one of gnn, jipda, mht"):
        load_tables(path, MttSettings)


def test_a_soft_associator_with_memory_and_existence_plugs_in() -> None:
    """An associator that gives every gated pair a share of weight, keeps existence, its own
    update and track management, and a memory: the tracker carries all of it through a scan."""
    from fedtrack.local_filters.linear.kalman import GaussianState, update_residual
    from fedtrack.local_filters.mtt.association import Association, AssociationInput, Associator
    from fedtrack.local_filters.mtt.config import MttConfig
    from fedtrack.local_filters.mtt.roles.filtering import Updated
    from fedtrack.local_filters.mtt.roles.tracks import Observation
    from fedtrack.local_filters.mtt.scan import SensorScan
    from fedtrack.local_filters.mtt.tracker import initial_state, track_params, tracker_step

    def associate(inp: AssociationInput) -> Association:
        w = np.exp(inp.log_likelihood)
        w = w / (np.bincount(inp.rows, weights=w, minlength=inp.n_tracks)[inp.rows] + 1e-300)
        claimed = np.zeros(inp.n_detections, bool)
        claimed[inp.cols] = True
        return Association(np.arange(inp.rows.size), w, claimed, np.minimum(inp.existence + 0.1, 1.0),
                           (inp.memory or 0) + 1)

    def update(tracks, pred, gating, assoc, scan, dt, params, q_scale):  # the weighted mean innovation
        m, d, n = scan.dim, params.dim, tracks.size
        if gating is None:  # no tracks or no detections
            return Updated(tracks._replace(x=pred.x, P=pred.P), np.zeros(n, bool),
                           Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m))))
        g = gating.pairs
        nu = np.zeros((n, m))
        np.add.at(nu, g.rows[assoc.pairs], assoc.weight[:, None] * g.nu[assoc.pairs])
        x, P = update_residual(GaussianState(pred.x, pred.P), nu, gating.lin.H, scan.R).state
        return Updated(tracks._replace(x=x, P=P, existence=assoc.existence), np.ones(n, bool),
                       Observation(np.zeros((n, m, d)), np.zeros((n, m, m)), np.zeros((n, m))))

    def manage(tracks, detected, params, sees):
        return tracks._replace(confirmed=tracks.existence > 0.75), np.ones(tracks.size, bool)

    soft = Associator("soft", associate, update, manage)
    params = track_params(MttConfig(), "s1", 4)._replace(associator=soft, initial_existence=0.5)
    R = np.eye(2) * 100.0
    state = initial_state(4)
    for k in range(4):
        z = np.array([[100.0 * k, 0.0], [100.0 * k + 5.0, 3.0]])
        state = tracker_step(state, SensorScan(float(k), "s1", R, z if k else z[:1], None, None), params).state
    assert state.memory == 3  # associate ran on scans 1, 2, 3
    assert state.tracks.size == 1  # scan 0 started one track; the others' detections were claimed
    np.testing.assert_allclose(state.tracks.existence, [0.8])
    assert state.tracks.confirmed.tolist() == [True]
    assert 200.0 < state.tracks.x[0, 0] < 305.0
