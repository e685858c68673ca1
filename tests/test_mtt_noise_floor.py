"""A sensor's noise floor (``[mtt.sensor.<id>] noise_floor``): a claimed ``R`` below it is raised to it at the
centre (local_filters/linear/noise_floor.py), so that a sensor claiming a tiny ``R`` weighs no more than its class
(attack50's puller: docs/multitarget.md, "A sensor pulling the tracks")."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import linalg
from support import route_reports

from fedtrack.config import ConfigError, load_tables
from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.linear.noise_floor import floor_factors, raise_to_floor
from fedtrack.local_filters.mtt.config import MttConfig, MttSettings, SensorOverride
from fedtrack.local_filters.mtt.local import LocalReport
from fedtrack.sensors.multitarget import Scenario, SensorSpec, noise_floors, simulate

H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def test_a_claim_below_the_floor_is_scaled_to_just_above_it() -> None:
    """The factor is the largest generalized eigenvalue of ``(F, R)`` (to 1e-9); the raised ``R`` is ``F`` plus a
    positive semi-definite matrix with a zero eigenvalue (the least scaling); a claim above the floor is kept."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(50, 2, 2))
    R = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(2)
    floor = np.array([1.5, 0.7])
    F = np.diag(floor**2)
    expected = np.array([linalg.eigh(F, r, eigvals_only=True)[-1] for r in R])
    np.testing.assert_allclose(floor_factors(R, floor), expected, rtol=1e-9)
    raised_R, raised = raise_to_floor(R, floor)
    assert raised.any() and not raised.all()
    np.testing.assert_array_equal(raised_R[~raised], R[~raised])
    least = np.linalg.eigvalsh(raised_R - F)[:, 0]
    assert np.all(np.abs(least[raised]) < 1e-9 * np.abs(raised_R[raised]).max()) and np.all(least > -1e-9)


def _report(sensor: str, t: float, z: np.ndarray, R: np.ndarray, first: bool, var: float) -> LocalReport:
    """A position sensor's report of local tracks 1..n, each detected at ``z`` (its estimate at ``z``, still, its
    position's variance ``var``: at most the detection's, as after a Kalman update, docs/multitarget.md, "A local
    track vaguer than its detection")."""
    n = z.shape[0]
    x = np.column_stack([z[:, 0], np.zeros(n), z[:, 1], np.zeros(n)])
    return LocalReport(sensor, t, np.arange(1, n + 1), x, np.tile(np.diag([var, 100.0, var, 100.0]), (n, 1, 1)),
                       np.full(n, not first), np.ones(n, bool), np.tile(H, (n, 1, 1)), np.tile(R, (n, 1, 1)), z,
                       np.full(n, first), np.zeros(0, dtype=np.int64))


def _run(cfg: MttConfig, claimed: np.ndarray, var: float | None = None) -> tuple[TrackToTrackCentre, np.ndarray]:
    """Three sensors on two targets for 8 s; s1 reports a walk of 5 m/s off the targets with ``claimed`` as its
    ``R`` (its tracks' position variance ``var``, default the claim's; the others their 15 m). Returns the centre
    and its central estimates at the end."""
    centre = TrackToTrackCentre(cfg, 4, True)
    targets = np.array([[0.0, 0.0], [2000.0, 0.0]])
    rng = np.random.default_rng(1)
    honest = 225.0 * np.eye(2)
    for k in range(8):
        for j, sensor in enumerate(("s1", "s2", "s3")):
            t = k + 0.2 * j
            if sensor == "s1":
                centre.answer(_report(sensor, t, targets + 5.0 * t, claimed, k == 0,
                                      claimed[0, 0] if var is None else var))
            else:
                centre.answer(_report(sensor, t, targets + rng.normal(0.0, 15.0, (2, 2)), honest, k == 0, 225.0))
    ids = sorted(centre.tracks.slot)
    X, _ = centre.tracks.states_at(np.array([centre.tracks.slot[i] for i in ids]), 8.0)
    return centre, X


@pytest.mark.parametrize("claim", [1.0, 1e-310])
def test_a_report_claiming_less_than_its_floor_is_fused_as_one_at_the_floor(claim: float) -> None:
    """A sensor claiming ``R`` = 1 m² with a floor of 10 m gives the central tracks it would give claiming 100 m²
    (to 1e-9), each observation counted ``noise_raised``; without the floor its claim drags them further. So does
    a subnormal claim, 1e-310 m² (the wire's relative check passes it): its factor overflowed to inf, the NaN
    compared false and the claim was fused unraised (attack53: 27.8 m from the tracks at the floor)."""
    floored = MttConfig(sensor={"s1": SensorOverride(noise_floor=(10.0, 10.0))})
    tiny, at_floor = claim * np.eye(2), 100.0 * np.eye(2)
    centre, X = _run(floored, tiny)
    reference, X_ref = _run(floored, at_floor, claim)
    np.testing.assert_allclose(X, X_ref, rtol=0, atol=1e-9)
    assert centre.counters.noise_raised == 16 and reference.counters.noise_raised == 0
    assert centre.counters.floor_mismatch == 0
    _, X_free = _run(MttConfig(), tiny)
    assert np.abs(X_free - X_ref)[:, [0, 2]].max() > 5.0  # the tiny claim pulled the tracks without the floor


def test_a_report_of_another_size_than_its_floor_is_not_fused() -> None:
    """A radar's floor (three numbers) on a sensor reporting 2-D observations: its reports are counted
    ``floor_mismatch`` and fused nowhere (its claim could not be checked)."""
    centre, _ = _run(MttConfig(sensor={"s1": SensorOverride(noise_floor=(10.0, 0.001, 0.001))}), np.eye(2))
    assert centre.counters.floor_mismatch == 8
    assert "s1" not in centre.sensor_seen and not any(key[0] == "s1" for key in centre.mapping)


@pytest.mark.parametrize("text", ["[-1.0, 5.0]", "[5.0]", "[1.0, 2.0, 3.0, 4.0]", "[5.0, inf]", "[1e200, 5.0]"])
def test_a_bad_noise_floor_fails_at_start_naming_it(tmp_path: Path, text: str) -> None:
    path = tmp_path / "c.toml"
    path.write_text(f"[mtt.sensor.s1]\nnoise_floor = {text}\n")
    with pytest.raises(ConfigError, match=r"sensor\.s1\.noise_floor"):
        load_tables(path, MttSettings)


def test_simulate_declares_each_sensors_noise_and_no_honest_scan_is_raised(tmp_path: Path) -> None:
    """``simulate multitarget`` writes every sensor's ``noise_floor`` (``sqrt(0.7) sd`` for a position sensor's
    correlated ``R``, a radar's standard deviations) and no scan it writes claims less."""
    simulate(Scenario(targets=3, duration=10.0), [SensorSpec("s1", "pos", 1.0), SensorSpec("r2", "radar", 2.0)],
             1, tmp_path)
    cfg = load_tables(tmp_path / "config.toml", MttSettings).mtt
    lines = [json.loads(line) for line in (tmp_path / "measurements.jsonl").read_text().splitlines()]
    for line in lines:
        floor = cfg.noise_floor_of(line["sensor"])
        assert floor is not None and not raise_to_floor(np.array([line["R"]]), floor)[1].any()
    sd = np.sqrt(lines[[ln["sensor"] for ln in lines].index("s1")]["R"][0][0])
    np.testing.assert_allclose(cfg.noise_floor_of("s1"), np.sqrt(0.7) * sd, rtol=1e-12)
    np.testing.assert_allclose(cfg.noise_floor_of("r2"), [10.0, 0.002, 0.002], rtol=1e-12)
    assert noise_floors([(0.0, {"sensor": "a", "R": [[4.0, 0.0], [0.0, 9.0]]}),
                         (1.0, {"sensor": "a", "R": [[9.0, 0.0], [0.0, 1.0]]})]) == {"a": [2.0, 1.0]}


def test_centralized_replay_of_a_tiny_claim_equals_the_claim_at_the_floor(tmp_path: Path) -> None:
    """``mtt-centralized`` (the centre fuses the scans): s1's scans claiming ``R / 100`` give, byte for byte,
    the pictures of the same scans claiming their floor (``R`` scaled to it); the detections are counted."""
    simulate(Scenario(targets=4, duration=20.0, clutter=2.0),
             [SensorSpec("s1", "pos", 1.0), SensorSpec("s2", "pos", 0.7)], 2, tmp_path)
    cfg = load_tables(tmp_path / "config.toml", MttSettings).mtt
    lines = [json.loads(line) for line in (tmp_path / "measurements.jsonl").read_text().splitlines()]
    for name, scale in (("tiny", None), ("floor", 1.0)):
        with open(tmp_path / f"{name}.jsonl", "w") as fh:
            for line in lines:
                if line["sensor"] == "s1" and "R" in line:
                    R = np.array(line["R"]) / 100.0
                    line = {**line, "R": (R * floor_factors(R[None], cfg.noise_floor_of("s1"))[0]).tolist()
                            if scale else R.tolist()}
                fh.write(json.dumps(line) + "\n")
    for name in ("tiny", "floor"):
        replay_mtt("mtt-centralized", tmp_path / f"{name}.jsonl", tmp_path / "config.toml", tmp_path / f"{name}.out")
    assert (tmp_path / "tiny.out").read_bytes() == (tmp_path / "floor.out").read_bytes()


def test_the_live_centre_raises_a_tiny_claim_as_the_replay_does(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The live services, driven in-process through their own dispatch (the path of a Zenoh sample), on three
    sensors of which s1 claims ``R / 100`` from t = 5 s: the centre publishes the pictures ``replay`` writes (to
    1e-9) and names what it raised in its Health counter ``centre_noise_raised``, the replay's count."""
    from fedtrack.fusion_center.mtt.service import MttCentreService
    from fedtrack.keys import Keys
    from fedtrack.local_filters.mtt.scan import parse_scan, scan_to_measurement
    from fedtrack.local_filters.mtt.service import MttLocalService
    from fedtrack.wire import TrackPicture, encode
    from fedtrack.zsession import SessionOptions

    simulate(Scenario(targets=4, duration=12.0, clutter=1.0, late=0.0),
             [SensorSpec("s1", "pos", 1.0), SensorSpec("s2", "pos", 0.7), SensorSpec("s3", "pos", 1.3)], 3, tmp_path)
    rows = [json.loads(line) for line in (tmp_path / "measurements.jsonl").read_text().splitlines()]
    rows = [{**r, "R": (np.array(r["R"]) / 100.0).tolist()} if r["sensor"] == "s1" and r["t"] >= 5.0 else r
            for r in rows]
    (tmp_path / "attack.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    cfg = load_tables(tmp_path / "config.toml", MttSettings).mtt
    keys, opts = Keys("floor"), SessionOptions(connect=("tcp/127.0.0.1:1",))
    published: list[object] = []
    centre = MttCentreService("mtt-federated", cfg, 4, service_id="centre", options=opts, deployment="floor")
    local = {s: MttLocalService(s, True, cfg, 5.0, service_id=s, options=opts, deployment="floor")
             for s in ("s1", "s2", "s3")}
    for svc in (centre, *local.values()):
        svc._subscriptions = svc.subscriptions()
        svc.publish = lambda key, msg: published.append(msg)  # type: ignore[method-assign]
    seq, done = dict.fromkeys(local, 0), 0
    for row in rows:
        s = row["sensor"]
        local[s]._dispatch(("sample", 0, keys.sensor_meas(s), encode(scan_to_measurement(parse_scan(row, "t"),
                                                                                          seq[s], 1))))
        seq[s] += 1
        done = route_reports(centre, local, published, keys, done)
    centre.on_stop()
    live = [m for m in published if isinstance(m, TrackPicture) and not m.closing]
    capsys.readouterr()
    replay_mtt("mtt-federated", tmp_path / "attack.jsonl", tmp_path / "config.toml", tmp_path / "out.jsonl")
    counted = re.search(r"mtt-federated: (\d+) centre observations whose R claimed less", capsys.readouterr().err)
    want = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert [p.t for p in live] == [p["t"] for p in want]
    for got, w in zip(live, want):
        assert list(got.ids) == [tr["id"] for tr in w["tracks"]]
        want_x = np.array([tr["x"] for tr in w["tracks"]]).reshape(-1, 4)
        np.testing.assert_allclose(np.asarray(got.x).reshape(-1, 4), want_x, rtol=1e-12, atol=1e-9)
    raised = centre.counters["centre_noise_raised"]
    assert counted is not None and raised == int(counted.group(1)) >= 20
    assert centre.counters["centre_floor_mismatch"] == 0


def test_the_multitarget_demo_declares_the_floors_of_the_sensors_it_simulates(tmp_path: Path) -> None:
    """``fedtrack demo --scenario multitarget`` runs its centre with each sensor's floor as ``simulate`` declares
    it for the scenario the launch simulates (its ``OUT/scenario/config.toml``), so a tiny claim is raised live."""
    from fedtrack.deploy.demo import multitarget_settings

    settings = multitarget_settings("federated", 2, 7447, tmp_path)
    declared = load_tables(tmp_path / "scenario" / "config.toml", MttSettings).mtt
    assert set(settings.mtt.sensor) == {"s1", "s2", "s3"}
    for sid in settings.mtt.sensor:
        np.testing.assert_array_equal(settings.mtt.noise_floor_of(sid), declared.noise_floor_of(sid))
