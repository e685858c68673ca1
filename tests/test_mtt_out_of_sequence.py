"""A sensor's own out-of-sequence scans (issue 28 items 1, 2): the local trackers of ``mtt-local``,
``mtt-federated`` and ``mtt-decentralized`` fuse them exactly within ``max_lag``, and the
counters say what they count.

Scenario: five targets on straight lines 2 km apart, two position sensors (1.0 s and 0.7 s),
every target detected, no clutter. Sensor ``a``'s scans arrive, 20 % of them (never the
first), up to two of its periods late, behind its own later scans.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from support import route_reports

from fedtrack.fusion_center.mtt.replay import replay_mtt

R_POS = [[100.0, 20.0], [20.0, 64.0]]
PERIODS = {"a": 1.0, "b": 0.7}


def scans(seed: int, late_fraction: float = 0.2, duration: float = 40.0) -> tuple[list[dict], list[dict]]:
    """The scans in arrival order and in time order."""
    rng = np.random.default_rng(seed)
    x0 = np.array([[2000.0 * k, 10.0 - 4 * k, -1000.0 * k, 6.0 + k] for k in range(5)])
    rows, arrive = [], []
    for sensor, period in PERIODS.items():
        times = rng.uniform(0, period) + period * np.arange(int(duration / period))
        for k, t in enumerate(times):
            pos = x0[:, [0, 2]] + t * x0[:, [1, 3]] + rng.multivariate_normal([0, 0], R_POS, size=5)
            rows.append({"t": float(t), "sensor": sensor, "R": R_POS, "detections": [{"z": z.tolist()} for z in pos]})
            late = sensor == "a" and k > 0 and rng.uniform() < late_fraction
            arrive.append(t + (rng.uniform(0, 2 * period) if late else 0.01))
    by_arrival = [rows[i] for i in np.argsort(arrive, kind="stable")]
    return by_arrival, sorted(rows, key=lambda r: r["t"])


def replay(tmp_path: Path, name: str, rows: list[dict], algorithm: str, **mtt: object) -> list[dict]:
    meas = tmp_path / f"{name}.jsonl"
    meas.write_text("".join(json.dumps(r) + "\n" for r in rows))
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text("[mtt]\n" + "".join(f"{k} = {v!r}\n" for k, v in mtt.items()))
    out = tmp_path / f"{name}-{algorithm}.jsonl"
    replay_mtt(algorithm, meas, cfg, out, sensor="a" if algorithm == "mtt-local" else None)
    return [json.loads(line) for line in out.read_text().splitlines()]


def own_scans_out_of_sequence(rows: list[dict], sensor: str) -> int:
    times = [r["t"] for r in rows if r["sensor"] == sensor]
    return sum(t < max(times[:k]) for k, t in enumerate(times) if k)


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-federated", "mtt-decentralized"])
def test_own_out_of_sequence_scans_equal_time_sorted_delivery(tmp_path: Path, algorithm: str,
                                                              capsys: pytest.CaptureFixture) -> None:
    """Pictures from the scans as they arrived equal those from the time-sorted scans to 1e-9
    (``picture_delay`` covers the two periods of lateness)."""
    arrived, in_time = scans(seed=7)
    assert own_scans_out_of_sequence(arrived, "a") >= 5
    cfg = {"max_lag": 3.0, "picture_delay": 2.5, "pd": 0.95, "clutter_density": 1e-9}
    got = replay(tmp_path, "arrived", arrived, algorithm, **cfg)
    assert "0 scans late" in capsys.readouterr().err
    want = replay(tmp_path, "sorted", in_time, algorithm, **cfg)
    assert [p["t"] for p in got] == [p["t"] for p in want] and len(got) >= 35
    for g, w in zip(got, want):
        assert [tr["id"] for tr in g["tracks"]] == [tr["id"] for tr in w["tracks"]], f"t = {g['t']}"
        assert [tr["status"] for tr in g["tracks"]] == [tr["status"] for tr in w["tracks"]]
        for a, b in zip(g["tracks"], w["tracks"]):
            for key in ("x", "P"):
                np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-9 * np.max(np.abs(b[key])))
    assert sum(tr["status"] == "confirmed" for tr in got[-1]["tracks"]) == 5


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized"])
def test_a_second_scan_of_a_sensor_at_a_time_it_has_is_left_out(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                  algorithm: str) -> None:
    """A second, different scan of one sensor at a time it already has a scan of (as a scan sent again
    under a new number is, which the live services refuse as ``rejected_conflict``) is counted and left
    out: the pictures are those without it, so that a replay equals the live run."""
    arrived, _ = scans(seed=7, duration=20.0)
    again = []
    for r in arrived:
        again.append(r)
        if r["sensor"] == "a" and 5.0 < r["t"] < 9.0:
            moved = json.loads(json.dumps(r))
            for det in moved["detections"]:
                det["z"][0] += 5.0
            again.append(moved)
    extra = len(again) - len(arrived)
    assert extra >= 3
    want = replay(tmp_path, "clean", arrived, algorithm, max_lag=3.0)
    capsys.readouterr()
    got = replay(tmp_path, "again", again, algorithm, max_lag=3.0)
    assert f": {extra} scans at a time their sensor has another scan of, not fused" in capsys.readouterr().err
    assert got == want


def test_counters_say_what_they_count(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A scan of ``a`` more than ``max_lag`` behind its newest is a late scan; a repeated line a
    duplicate; the out-of-sequence ones are fused (and the later scans run again); the centre
    re-processes observations, and counts none of them late."""
    arrived, _ = scans(seed=7, duration=20.0)
    of_a = [r for r in arrived if r["sensor"] == "a"]
    rows = arrived + [of_a[-2], of_a[0]]  # a duplicate, and a scan 19 s late
    replay(tmp_path, "c", rows, "mtt-local", max_lag=3.0)
    err = capsys.readouterr().err
    assert f"mtt-local: {len(of_a)} scans fused\n" in err
    assert "mtt-local: 1 scans late (older than max_lag before their tracker's newest), not fused\n" in err
    assert "mtt-local: 1 duplicate scans" in err
    rerun = int(err.split(" scans run again")[0].rsplit("mtt-local: ", 1)[1])
    assert rerun >= own_scans_out_of_sequence(arrived, "a")
    replay(tmp_path, "c", rows, "mtt-federated", max_lag=3.0)
    err = capsys.readouterr().err
    assert f"mtt-federated: {len(arrived)} scans fused\n" in err
    assert "mtt-federated: 1 scans late (older than max_lag before their tracker's newest), not fused\n" in err
    assert "mtt-federated: 1 duplicate scans" in err
    assert "mtt-federated: 0 centre observations late (older than max_lag), not fused\n" in err
    reprocessed = int(err.split("centre observations re-processed")[0].rsplit(": ", 1)[1])
    assert reprocessed > 0


def test_the_formats_doc_shows_the_counter_lines_replay_prints(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """docs/multitarget-formats.md quotes ``replay``'s counters on the default scenario: the same lines, in the same
    order, as ``replay`` prints (numbers aside)."""
    def shape(lines: list[str]) -> list[str]:
        return [re.sub(r"\d+(\.\d+)?(e-?\d+)?", "N", line) for line in lines]

    doc = (Path(__file__).resolve().parents[1] / "docs" / "multitarget-formats.md").read_text()
    quoted = [line.strip() for line in doc.splitlines() if line.startswith("    mtt-federated: ")]
    replay(tmp_path, "c", scans(seed=7, duration=10.0)[0], "mtt-federated")
    printed = capsys.readouterr().err.splitlines()
    assert quoted and shape(quoted) == shape(printed)

@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_live_local_trackers_fuse_own_out_of_sequence_scans_as_the_replay(tmp_path: Path, algorithm: str) -> None:
    """The live local services and centre, driven in-process through their own dispatch (the
    path of a Zenoh sample; resets answered before the next scan), publish the pictures that
    ``replay`` gives on the scans in that order, and count the re-runs."""
    from fedtrack.fusion_center.mtt.service import MttCentreService
    from fedtrack.keys import Keys
    from fedtrack.local_filters.mtt.config import MttConfig
    from fedtrack.local_filters.mtt.scan import parse_scan, scan_to_measurement
    from fedtrack.local_filters.mtt.service import MttLocalService
    from fedtrack.wire import TrackPicture, encode
    from fedtrack.zsession import SessionOptions

    arrived, _ = scans(seed=7, duration=25.0)
    mtt = {"max_lag": 3.0, "picture_delay": 2.5, "pd": 0.95, "clutter_density": 1e-9}
    keys, opts = Keys("oos"), SessionOptions(connect=("tcp/127.0.0.1:1",))
    federated = algorithm == "mtt-federated"
    published: list[object] = []
    centre = MttCentreService(algorithm, MttConfig(**mtt), 4, service_id="centre", options=opts, deployment="oos")
    local = {s: MttLocalService(s, federated, MttConfig(**mtt), 5.0, service_id=s, options=opts, deployment="oos")
             for s in PERIODS}
    for svc in (centre, *local.values()):
        svc._subscriptions = svc.subscriptions()
        svc.publish = lambda key, msg: published.append(msg)  # type: ignore[method-assign]
    seq, done = dict.fromkeys(PERIODS, 0), 0
    for row in arrived:
        s = row["sensor"]
        meas = scan_to_measurement(parse_scan(row, "test"), seq[s], 1)
        seq[s] += 1
        local[s]._dispatch(("sample", 0, keys.sensor_meas(s), encode(meas)))
        done = route_reports(centre, local, published, keys, done)
    centre.on_stop()
    live = [m for m in published if isinstance(m, TrackPicture) and not m.closing]
    assert local["a"].counters.get("rerun", 0) >= own_scans_out_of_sequence(arrived, "a")
    assert local["a"].counters.get("late", 0) == 0 and local["a"].counters.get("rejected", 0) == 0
    want = replay(tmp_path, "arrived", arrived, algorithm, **mtt)
    assert [p.t for p in live] == [p["t"] for p in want]
    for got, w in zip(live, want):
        assert list(got.ids) == [tr["id"] for tr in w["tracks"]]
        want_x = np.array([tr["x"] for tr in w["tracks"]]).reshape(-1, 4)
        np.testing.assert_allclose(np.asarray(got.x).reshape(-1, 4), want_x, rtol=1e-12, atol=1e-9)


def test_simulate_non_fifo_links_reorder_a_sensors_own_scans_and_mtt_local_fuses_them(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``simulate multitarget --non-fifo``: late scans arrive behind their own sensor's later ones
    (the default keeps each link in order); mtt-local fuses every one of them within max_lag, and
    its pictures equal those of the same scans in time order."""
    from fedtrack.cli import main

    runs = {}
    for name, extra in (("fifo", []), ("non-fifo", ["--non-fifo"])):
        out = tmp_path / name
        assert main(["simulate", "multitarget", "--targets", "6", "--duration", "40", "--seed", "4",
                     "--late", "0.3", "--out", str(out), *extra]) == 0
        runs[name] = [json.loads(line) for line in (out / "measurements.jsonl").read_text().splitlines()]
    assert own_scans_out_of_sequence(runs["fifo"], "s1") == 0
    arrived = runs["non-fifo"]
    assert own_scans_out_of_sequence(arrived, "s1") >= 3
    assert sorted(map(json.dumps, arrived)) == sorted(map(json.dumps, runs["fifo"]))  # the same scans
    capsys.readouterr()
    cfg = tmp_path / "non-fifo" / "config.toml"
    text = cfg.read_text().replace("[mtt]\n", "[mtt]\npicture_delay = 2.9\n", 1)
    cfg.write_text(text)
    sorted_meas = tmp_path / "sorted.jsonl"
    sorted_meas.write_text("".join(json.dumps(r) + "\n" for r in sorted(arrived, key=lambda r: r["t"])))
    pictures = {}
    for name, meas in (("arrived", tmp_path / "non-fifo" / "measurements.jsonl"), ("sorted", sorted_meas)):
        out = tmp_path / f"{name}-pictures.jsonl"
        replay_mtt("mtt-local", meas, cfg, out, sensor="s1")
        pictures[name] = [json.loads(line) for line in out.read_text().splitlines()]
        if name == "arrived":
            assert "mtt-local: 0 scans late" in capsys.readouterr().err
    assert [p["t"] for p in pictures["arrived"]] == [p["t"] for p in pictures["sorted"]]
    for g, w in zip(pictures["arrived"], pictures["sorted"]):
        assert [tr["id"] for tr in g["tracks"]] == [tr["id"] for tr in w["tracks"]], f"t = {g['t']}"
        for a, b in zip(g["tracks"], w["tracks"]):
            for key in ("x", "P"):
                np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-9 * np.max(np.abs(b[key])))


@pytest.mark.parametrize("algorithm", ["mtt-federated", "mtt-decentralized"])
def test_a_late_scan_does_not_map_again_a_local_track_that_later_scans_deleted(tmp_path: Path, algorithm: str) -> None:
    """One target; sensor ``b`` sees it every 0.7 s, sensor ``a`` at 0.5 and 1.5 s, not at 2.5 and 3.5
    (its tentative track then deleted), and again from 4.5 s (a new track). ``a``'s 1.5 s scan arrives
    after its 3.5 s one: the re-run's report holds the first track, which the later scans deleted
    again. It was mapped to the central track again and never retired, so ``a``'s new track could
    not join that central track (it had a track of ``a``) and started a second one, in every
    picture to the end (untuned5)."""
    rng = np.random.default_rng(3)
    x0 = np.array([100.0, 12.0, -200.0, 5.0])

    def scan(sensor: str, t: float, seen: bool) -> dict:
        z = x0[[0, 2]] + t * x0[[1, 3]] + rng.multivariate_normal([0, 0], R_POS)
        return {"t": t, "sensor": sensor, "R": R_POS, "detections": [{"z": z.tolist()}] if seen else []}

    a = {t: scan("a", t, not 2.0 < t < 4.0) for t in np.arange(0.5, 20.0, 1.0).tolist()}
    rows = [(t + 0.01, row) for t, row in a.items() if t != 1.5] + [(3.6, a[1.5])]
    rows += [(t + 0.01, scan("b", t, True)) for t in (0.2 + 0.7 * np.arange(28)).tolist()]
    arrived = [row for _, row in sorted(rows, key=lambda r: r[0])]
    assert own_scans_out_of_sequence(arrived, "a") == 1
    pictures = replay(tmp_path, "late", arrived, algorithm, max_lag=3.0, pd=0.95, clutter_density=1e-9)
    for p in pictures[-8:]:
        assert [tr["status"] for tr in p["tracks"]] == ["confirmed"], f"t = {p['t']}: {p['tracks']}"
        assert p["tracks"][0]["sensors"] == ["a", "b"]
