"""The multi-target trackers on what real sensor networks bring and the simulator does not
(untuned6 session): repeated detections, duplicated feeds, registration errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fedtrack.cli import main as cli
from fedtrack.fusion_center.mtt.centre.copies import FeedCopies, Found, Observations, equal_rows
from fedtrack.fusion_center.mtt.evaluation import evaluate
from fedtrack.local_filters.mtt.scan import parse_scan, scan_from_measurement, scan_to_measurement


def two_target_scans(path: Path, repeat: int = 1) -> None:
    """One sensor's scans of two targets 500 m apart at 10 m/s for 20 s, noiseless, no clutter; each
    detection listed ``repeat`` times in its scan."""
    rows = [{"t": float(k), "sensor": "s1", "R": [[25.0, 0.0], [0.0, 25.0]],
             "detections": [{"z": [10.0 * k, y]} for y in (0.0, 500.0) for _ in range(repeat)]} for k in range(20)]
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_a_repeated_detection_is_dropped_and_counted() -> None:
    """A detection equal to an earlier one of its scan is dropped (the first kept, order and
    amplitudes with it), on a file's line and on the wire alike, and ``repeated`` counts it."""
    line = {"t": 1.0, "sensor": "s1", "R": [[4.0, 0.0], [0.0, 4.0]],
            "detections": [{"z": [1.0, 2.0], "amplitude": 3.0}, {"z": [5.0, 6.0], "amplitude": 4.0},
                           {"z": [1.0, 2.0], "amplitude": 9.0}, {"z": [1.0, 2.5], "amplitude": 1.0}]}
    scan = parse_scan(line, "m.jsonl:1")
    assert scan.z.tolist() == [[1.0, 2.0], [5.0, 6.0], [1.0, 2.5]] and scan.amplitude.tolist() == [3.0, 4.0, 1.0]
    assert scan.repeated == 1
    wired = scan_from_measurement(scan_to_measurement(scan._replace(z=np.repeat(scan.z, 2, axis=0),
                                                                    amplitude=np.repeat(scan.amplitude, 2)), 1, 0))
    assert np.array_equal(wired.z, scan.z) and wired.repeated == 3
    assert parse_scan({**line, "detections": line["detections"][:2]}, "m.jsonl:1").repeated == 0


@pytest.mark.parametrize("algorithm", [["mtt-local", "--sensor", "s1"], ["mtt-centralized"], ["mtt-federated"]])
def test_a_sensor_reporting_each_detection_twice_gives_the_pictures_of_once(
        tmp_path: Path, capsys: pytest.CaptureFixture, algorithm: list[str]) -> None:
    """Each detection twice in its scan: the second copy started a second track on every target,
    confirmed by the next scans' copies (``simulate multitarget --targets 20 --duration 120``, each
    s1 detection twice: 17.3 confirmed tracks a picture for 16.6, gnn ``mtt-federated`` 194 id
    switches, mean GOSPA 45.3 -> 199.5); now the pictures of the scans with each detection once."""
    (tmp_path / "c.toml").write_text("[mtt]\nclutter_density = 1e-9\n")
    out = {}
    for repeat in (1, 2):
        two_target_scans(tmp_path / f"m{repeat}.jsonl", repeat)
        assert cli(["replay", "--algorithm", *algorithm, "--config", str(tmp_path / "c.toml"), "--measurements",
                    str(tmp_path / f"m{repeat}.jsonl"), "--out", str(tmp_path / f"t{repeat}.jsonl")]) == 0
        out[repeat] = (tmp_path / f"t{repeat}.jsonl").read_text()
        err = capsys.readouterr().err
    assert {t["id"] for line in out[2].splitlines() for t in json.loads(line)["tracks"]} == {0, 1}
    assert out[2] == out[1]
    assert f"{algorithm[0]}: 40 detections equal to an earlier one of their scan, dropped" in err


def test_evaluate_recovers_a_sensors_registration_errors(tmp_path: Path) -> None:
    """Tracks of one sensor that are truth shifted by b = (30, -20) m, rotated by 1 deg about the
    origin and 0.5 s behind (track = truth + b + tau v + theta J p exactly, tau = -0.5): the
    fit gives them back to 1e-9; another sensor's tracks 150 m off every target count as false."""
    b, tau, theta = np.array([30.0, -20.0]), -0.5, np.radians(1.0)
    rng = np.random.default_rng(3)
    start = rng.uniform(-2000, 2000, (6, 2))
    vel = rng.uniform(-20, 20, (6, 2))
    truth, tracks = [], []
    for k in range(10):
        p = start + k * vel
        x = np.column_stack([p[:, 0], vel[:, 0], p[:, 1], vel[:, 1]])
        q = p + b + tau * vel + theta * np.column_stack([-p[:, 1], p[:, 0]])
        truth.append({"t": float(k), "targets": [{"id": i, "x": x[i].tolist()} for i in range(6)]})
        tracks.append({"t": float(k), "tracks": [
            *({"id": i, "x": [q[i, 0], vel[i, 0], q[i, 1], vel[i, 1]], "sensors": ["s1"]} for i in range(6)),
            {"id": 99, "x": [p[0, 0] + 150.0, 0.0, p[0, 1], 0.0], "sensors": ["s2"]}]})
    (tmp_path / "u.jsonl").write_text("".join(json.dumps(r) + "\n" for r in truth))
    (tmp_path / "t.jsonl").write_text("".join(json.dumps(r) + "\n" for r in tracks))
    reg = evaluate(tmp_path / "t.jsonl", tmp_path / "u.jsonl")["registration"]
    assert reg["s1"]["pairs"] == 60 and reg["s1"]["false"] == 0
    assert reg["s1"]["offset"] == pytest.approx(b.tolist(), abs=1e-9)
    assert reg["s1"]["time_offset"] == pytest.approx(tau, abs=1e-9)
    assert reg["s1"]["rotation_deg"] == pytest.approx(1.0, abs=1e-9)
    assert reg["s2"] == {"pairs": 0, "false": 10}


def test_mtt_centralized_fuses_a_duplicated_feed_once(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A second sensor id carrying the very same scans as s1 (a duplicated feed): ``mtt-centralized``
    took each detection twice as independent, so tracks twice as confident as they are, and a
    second track where the copy's detection went unclaimed (``simulate multitarget --targets 20
    --duration 120``, s1 copied as s9: jipda mean GOSPA 37.19 -> 192.59, 24.4 confirmed tracks a
    picture for 16.6); now the copy is not fused and the pictures are those of s1's scans alone."""
    two_target_scans(tmp_path / "m1.jsonl")
    lines = (tmp_path / "m1.jsonl").read_text().splitlines()
    copy = [json.dumps({**json.loads(x), "sensor": "s9"}) for x in lines]
    (tmp_path / "m2.jsonl").write_text("".join(f"{a}\n{b}\n" for a, b in zip(lines, copy)))
    (tmp_path / "c.toml").write_text('[mtt]\nclutter_density = 1e-9\nassociator = "jipda"\n')
    for k in (1, 2):
        assert cli(["replay", "--algorithm", "mtt-centralized", "--config", str(tmp_path / "c.toml"), "--measurements",
                    str(tmp_path / f"m{k}.jsonl"), "--out", str(tmp_path / f"t{k}.jsonl")]) == 0
    assert (tmp_path / "t2.jsonl").read_text() == (tmp_path / "t1.jsonl").read_text()
    err = capsys.readouterr().err
    assert "mtt-centralized: 20 scans equal to another sensor's (a duplicated feed), not fused" in err


def noisy_scans(sensor: str, seed: int) -> list[dict]:
    """One sensor's scans of :func:`two_target_scans`' two targets, 5 m noise per axis (``R`` 25 m^2),
    at t = 0, 1, ..., 19 (every sensor of the test at the same times: the worst case for a false alarm)."""
    rng = np.random.default_rng(seed)
    return [{"t": float(k), "sensor": sensor, "R": [[25.0, 0.0], [0.0, 25.0]],
             "detections": [{"z": [10.0 * k + 5.0 * rng.standard_normal(), y + 5.0 * rng.standard_normal()]}
                            for y in (0.0, 500.0)]} for k in range(20)]


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_track_to_track_centre_fuses_a_duplicated_feed_once(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                            algorithm: str) -> None:
    """s1's scans copied as s9 beside an honest s2 of equal ``R`` scanning at the same times: the centre
    fused the copy's reports as a third sensor's (``simulate multitarget --targets 20 --duration 120``, s1
    copied as s9: gnn mean GOSPA 45.31 / 44.64 -> 65.59 / 62.03, federated / decentralized); now s9 is found
    a copy at its third report (t = 2), that one and the 17 after it not fused, s2 is never taken for one, and the
    central tracks end as without s9 (the two early reports long forgotten), not a third more confident."""
    s1, s2 = noisy_scans("s1", 1), noisy_scans("s2", 2)
    s9 = [{**scan, "sensor": "s9"} for scan in s1]
    (tmp_path / "c.toml").write_text("[mtt]\nclutter_density = 1e-9\n")
    last = {}
    for name, scans in (("copy", zip(s1, s9, s2)), ("none", zip(s1, s2))):
        (tmp_path / f"{name}.jsonl").write_text("".join(json.dumps(s) + "\n" for group in scans for s in group))
        assert cli(["replay", "--algorithm", algorithm, "--config", str(tmp_path / "c.toml"), "--measurements",
                    str(tmp_path / f"{name}.jsonl"), "--out", str(tmp_path / f"{name}.out.jsonl")]) == 0
        last[name] = json.loads((tmp_path / f"{name}.out.jsonl").read_text().splitlines()[-1])["tracks"]
        err = capsys.readouterr().err
        if name == "copy":
            assert f"{algorithm}: 18 reports of a sensor copying another's feed" in err
            assert "sensors found copying another's feed (their reports not fused): s9 of s1 at t=2.00\n" in err
        else:
            assert f"{algorithm}: 0 reports of a sensor copying" in err and "found copying" not in err
    assert [t["sensors"] for t in last["copy"]] == [["s1", "s2"]] * 2
    for a, b in zip(last["copy"], last["none"]):
        assert np.allclose(a["P"], b["P"], rtol=1e-5) and np.allclose(a["x"], b["x"], atol=0.01)  # with s9: 0.29, 1.1 m


@pytest.mark.parametrize("copied, found, reports", [
    ((5, 19), "s9 of s1 at t=7.00", 12), ((0, 9), "s1 of s9 at t=2.00", 11)])
def test_a_copy_sent_first_takes_the_original_only_from_the_start_and_while_it_lasts(
        tmp_path: Path, capsys: pytest.CaptureFixture, copied: tuple[int, int], found: str, reports: int) -> None:
    """s1's scans copied as s9 at ``copied`` times, each s9 line before its s1 line, beside an honest s2:
    a copier joining at t = 5 had s1 taken for the copy (``s1 of s9 at t=7.00``); now s9 is, forgotten by
    the centre at s1's report (its local tracks leave: none in the last picture). One there from the start
    still takes s1 for the copy; when it stops after t = 9, s1 is fused again from its report at t = 13
    (it was from t = 16, once s9 had left: 13 and 14 reports not fused before, 12 and 11 now)."""
    s1, s2 = noisy_scans("s1", 1), noisy_scans("s2", 2)
    lines = [[{**a, "sensor": "s9"}] * (copied[0] <= a["t"] <= copied[1]) + [a, b] for a, b in zip(s1, s2)]
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(s) + "\n" for group in lines for s in group))
    (tmp_path / "c.toml").write_text("[mtt]\nclutter_density = 1e-9\n")
    assert cli(["replay", "--algorithm", "mtt-federated", "--config", str(tmp_path / "c.toml"), "--measurements",
                str(tmp_path / "m.jsonl"), "--out", str(tmp_path / "t.jsonl")]) == 0
    err = capsys.readouterr().err
    assert f"mtt-federated: {reports} reports of a sensor copying another's feed" in err
    assert f"sensors found copying another's feed (their reports not fused): {found}\n" in err
    last = json.loads((tmp_path / "t.jsonl").read_text().splitlines()[-1])["tracks"]
    assert [t["sensors"] for t in last] == [["s1", "s2"]] * 2


def seen(z: np.ndarray, radar: bool = False) -> Observations:
    """Observations ``z`` of 10 m noise, each its detection (position updates), or a radar's linearized
    updates (``radar``: compared with nothing)."""
    k, m = z.shape
    H = np.tile(np.full((m, 2 * m), 0.5) if radar else np.eye(m, 2 * m), (k, 1, 1))
    return Observations(z, np.tile(100.0 * np.eye(m), (k, 1, 1)), H, np.zeros(k, dtype=bool))


def test_feed_copies_rules() -> None:
    """The copy test on observations alone: equal within 1e-3 of their sigma, not beyond; quantized honest
    detections sharing one value of ten each scan are no copy; the sensor heard from later is the copy, whichever
    report arrives first; three comparisons in a row that disagree release it, and so does the original's departure;
    a radar's updates (linearized about its track, which a federated copy's resets move) are left out
    and its starts compared; a radar's 3-D observations beside a position sensor's at the same time
    are compared with nothing (they raised ValueError, ending a replay of a radar and position
    sensors scanning together)."""
    rng = np.random.default_rng(5)
    z, tol = rng.uniform(-5e3, 5e3, (10, 2)), np.full((10, 2), 0.01)  # 1e-3 of 10 m
    assert equal_rows(z, tol, z * (1 + 4e-16)) == 10 and equal_rows(z, tol, z + [0.0, 0.011]) == 0
    assert equal_rows(z, tol, np.flipud(z)[:4] + 0.009) == 4 and equal_rows(z, tol, np.zeros((0, 2))) == 0
    quantized = FeedCopies(max_lag=3.0)
    for t in range(10):
        a, b = np.round(rng.uniform(-5e3, 5e3, (2, 10, 2)))
        b[0] = a[3]  # one detection of ten in common every scan
        assert not quantized.is_copy("s1", float(t), seen(a)) and not quantized.is_copy("s2", float(t), seen(b))
    feeds = FeedCopies(max_lag=3.0)
    for t in range(3):  # both there from the start, s9's reports first: s1 is taken for the copy (s9 heard first)
        z = rng.uniform(-5e3, 5e3, (6, 2))
        assert not feeds.is_copy("s9", float(t), seen(z))
        assert feeds.is_copy("s1", float(t), seen(z)) == (t == 2)
    z = rng.uniform(-5e3, 5e3, (6, 2))
    assert feeds.is_copy("s1", 3.0, seen(z)) and not feeds.is_copy("s9", 3.0, seen(z))  # either order
    assert feeds.drain() == [Found(2.0, "s1", "s9", True)]
    for t in range(4, 7):  # three comparisons that disagree release s1
        assert not feeds.is_copy("s9", float(t), seen(rng.uniform(-5e3, 5e3, (6, 2))))
        assert feeds.is_copy("s1", float(t), seen(rng.uniform(-5e3, 5e3, (6, 2)))) == (t < 6)
    assert feeds.drain() == [Found(6.0, "s1", "s9", False)]
    for t in range(7, 10):  # s1's reports now arrive first, but s9 was heard from first: s1 is the copy again
        z = rng.uniform(-5e3, 5e3, (6, 2))
        assert not feeds.is_copy("s1", float(t), seen(z))
        assert not feeds.is_copy("s9", float(t), seen(z))
    assert feeds.is_copy("s1", 10.0, seen(z))
    feeds.drop("s9")  # the original left: its copy is fused again
    assert not feeds.copy_of and feeds.drain() == [Found(9.0, "s1", "s9", True)]
    federated = FeedCopies(max_lag=3.0)  # a radar copy's linearized updates differ (1 m), its starts do not
    for t in range(3):
        r1 = seen(rng.uniform(-5e3, 5e3, (6, 3)), radar=True)
        r9 = r1._replace(z=r1.z + np.repeat([[0.0], [1.0]], [2, 4], axis=0), started=np.arange(6) < 2)
        assert not federated.is_copy("r1", float(t), r1) and federated.is_copy("r9", float(t), r9) == (t == 2)
    mixed = FeedCopies(max_lag=3.0)  # a radar's observations beside a position sensor's at one time
    assert not mixed.is_copy("r1", 0.0, seen(np.zeros((3, 3))))
    assert not mixed.is_copy("s2", 0.0, seen(np.zeros((3, 2))))


def test_a_copier_joining_later_is_the_copy_and_a_silent_original_releases_it() -> None:
    """A sender that joins s1's feed later and gets each copy to the centre first: s1, arriving second, was
    taken for the copy and dropped while s9 copied; now the sensor heard from later (s9) is. One there from
    the start and heard first is kept (what it can still do); when it goes silent, s1 is released at its
    third report after one s9 did not match (it was released only on s9's departure: ``central_timeout``
    and four intervals after it stopped), taken again at the pair's first agreeing comparison when s9
    resumes (not three: fewer reports of both fused); a sensor with an empty report first is heard from then."""
    rng = np.random.default_rng(7)
    feeds = FeedCopies(max_lag=3.0)
    assert not feeds.is_copy("s1", 0.0, seen(np.zeros((0, 2))))  # heard from, with nothing detected
    for t in range(1, 5):
        z = rng.uniform(-5e3, 5e3, (6, 2))
        assert feeds.is_copy("s9", float(t), seen(z)) == (t == 4) and not feeds.is_copy("s1", float(t), seen(z))
        assert feeds.copy_of == ({"s9": "s1"} if t >= 3 else {})  # found at s1's third report
    assert feeds.drain() == [Found(3.0, "s9", "s1", True)]
    early = FeedCopies(max_lag=3.0)  # s9 there first: s1 the copy until s9 stops after t = 3, and once it resumes
    for t in range(11):
        z = rng.uniform(-5e3, 5e3, (6, 2))
        if t <= 3 or t >= 9:
            assert not early.is_copy("s9", float(t), seen(z))
        assert early.is_copy("s1", float(t), seen(z)) == (2 <= t <= 6 or t >= 9)
    assert early.drain() == [Found(2.0, "s1", "s9", True), Found(7.0, "s1", "s9", False), Found(9.0, "s1", "s9", True)]


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-centralized"])
def test_a_sensor_sending_its_own_scans_again_under_new_stamps_is_fused_once(
        tmp_path: Path, capsys: pytest.CaptureFixture, algorithm: str) -> None:
    """From its fourth scan on, s1 sends each scan again a quarter period later, its detections reversed (its
    own authentic detections under a fresh stamp, off its schedule) beside an honest s2: each copy was fused as
    a new scan, s1 weighing twice (seed 1 of ``simulate multitarget``, s1's scans from t = 100 s sent again at a
    quarter, a half and three quarters of its period: ``mtt-federated`` 74.32 -> 122.57 m, the honest s2 and s3
    flagged inconsistent). Now the copies are duplicates: the pictures are those without them, and counted. The
    same scans on s1's schedule (a standing scene a noise-free sensor repeats) stay scans:
    :func:`test_repeated_detections_on_the_sensors_schedule_are_tracked`."""
    s1, s2 = noisy_scans("s1", 1), noisy_scans("s2", 2)
    again = [{**scan, "t": scan["t"] + 0.25, "detections": scan["detections"][::-1]} for scan in s1[3:-1]]
    (tmp_path / "c.toml").write_text("[mtt]\nclutter_density = 1e-9\n")
    pictures = {}
    for name, scans in (("again", [*zip(s1[:3], s2[:3]), *zip(s1[3:], s2[3:], again), (s1[-1], s2[-1])]),
                        ("once", zip(s1, s2))):
        (tmp_path / f"{name}.jsonl").write_text("".join(json.dumps(s) + "\n" for group in scans for s in group))
        assert cli(["replay", "--algorithm", algorithm, "--config", str(tmp_path / "c.toml"), "--measurements",
                    str(tmp_path / f"{name}.jsonl"), "--out", str(tmp_path / f"{name}.out.jsonl")]) == 0
        pictures[name] = (tmp_path / f"{name}.out.jsonl").read_text()
        err = capsys.readouterr().err
        assert f"{algorithm}: {len(again) if name == 'again' else 0} duplicate scans" in err
    assert pictures["again"] == pictures["once"]


def test_repeated_detections_on_the_sensors_schedule_are_tracked(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    """A noise-free sensor of two standing targets sends the same detections every second: every scan is
    tracked (none a duplicate) and the targets are confirmed (the check on the detections alone, reverted,
    dropped every repeat within ``max_lag``, and the tracks never confirmed)."""
    scans = [{"t": float(k), "sensor": "s1", "R": [[25.0, 0.0], [0.0, 25.0]],
              "detections": [{"z": [0.0, y]} for y in (0.0, 500.0)]} for k in range(10)]
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(s) + "\n" for s in scans))
    (tmp_path / "c.toml").write_text("[mtt]\nclutter_density = 1e-9\n")
    assert cli(["replay", "--algorithm", "mtt-centralized", "--config", str(tmp_path / "c.toml"), "--measurements",
                str(tmp_path / "m.jsonl"), "--out", str(tmp_path / "p.jsonl")]) == 0
    assert "mtt-centralized: 0 duplicate scans" in capsys.readouterr().err
    last = json.loads((tmp_path / "p.jsonl").read_text().splitlines()[-1])
    assert sum(track["status"] == "confirmed" for track in last["tracks"]) == 2


class Untouchable(np.ndarray):
    """An observation array the copy test must not read (indexing it fails)."""

    def __getitem__(self, key: object) -> np.ndarray:
        raise AssertionError("gathered")


def test_feed_copies_gather_a_sub_reports_rows_only_to_compare() -> None:
    """A region's sub-report (its rows ``rows`` of the report's observations): only ``z`` of the rows is gathered
    while no other sensor reported at the time (``R``, ``H`` and ``started`` are read only to compare, perf60), and
    a comparison of the rows finds the copy as the rows' own observations do."""
    rng = np.random.default_rng(6)
    z = rng.uniform(-5e3, 5e3, (12, 2))
    rows = np.array([1, 2, 4, 7, 8, 11])
    full = seen(z)
    untouchable = Observations(z, *(a.view(Untouchable) for a in full[1:]))
    assert not FeedCopies(5.0).is_copy("s1", 1.0, untouchable, rows)  # alone at t = 1: nothing compared
    by_rows, gathered = FeedCopies(5.0), FeedCopies(5.0)
    for t in (1.0, 2.0, 3.0):
        for copies, obs, sub in ((by_rows, full, rows), (gathered, seen(z[rows]), None)):
            assert not copies.is_copy("s1", t, seen(z[rows]))
            copies.is_copy("s2", t, obs, sub)
    assert by_rows.copy_of == gathered.copy_of == {"s2": "s1"}
