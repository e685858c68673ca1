"""The durable recorder: SQLite schema, dedupe, export, and a SIGKILL + restart mid-run."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import random
import shutil
import sqlite3
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from support import Deployment, cli_in_process, wait_until

from fedtrack import cli
from fedtrack.fusion_center.replay import replay_fusion
from fedtrack.jsonl import InputError
from fedtrack.recording import CONFLICT, DB_NAME, DUPLICATE, RECORDED, TABLE_OF, Recording
from fedtrack.wire import Detection, FusedTrack, Measurement, TrackPicture, encode, parts


def meas(sensor: str, seq: int, t: float, z0: float = 1.0) -> Measurement:
    return Measurement(sensor=sensor, seq=seq, t=t, kind="position", z=np.array([z0, 2.0]), R=np.eye(2), stamp_ns=7)


def scan(sensor: str, seq: int, n: int) -> Measurement:
    """A multi-target scan of ``n`` detections."""
    return Measurement(sensor=sensor, seq=seq, t=float(seq), kind="scan", z=np.zeros(0), R=np.eye(2),
                       detections=tuple(Detection(z=np.array([float(i), 0.0]), amplitude=0.0) for i in range(n)))


def test_rows_are_stored_once_and_export_in_scan_order(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    db = tmp_path / "r.db"
    rec = Recording(db)
    late = meas("b", 0, 0.0)
    for m in (meas("a", 1, 1.0), meas("a", 0, 0.0), late):  # scan 0 of b arrives after scan 1 of a
        assert rec.add(m, encode(m)) == RECORDED
    assert rec.add(late, encode(late)) == DUPLICATE
    other = meas("b", 0, 0.0, z0=9.0)
    assert rec.add(other, encode(other)) == CONFLICT
    track = FusedTrack(seq=0, t=0.0, model="cv", x=np.ones(4), P=np.eye(4), maneuver=False, degraded=False,
                       sensors=("a", "b"), stamp_ns=7)
    assert rec.add(track, encode(track)) == RECORDED
    rec.close()

    con = sqlite3.connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    indexes = {row[1] for row in con.execute("SELECT * FROM sqlite_master WHERE type = 'index'")}
    assert {"measurements_t", "estimates_t", "tracks_t", "events_t"} <= indexes
    assert con.execute("SELECT sensor, seq FROM measurements ORDER BY id").fetchall() == [("a", 1), ("a", 0),
                                                                                           ("b", 0)]
    con.close()

    out, tracks = tmp_path / "m.jsonl", tmp_path / "t.jsonl"
    cli = [sys.executable, "-m", "fedtrack.cli", "export", "--db", str(db)]
    done = subprocess.run([*cli, "--out", str(out), "--tracks", str(tracks)], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [(r["sensor"], r["t"]) for r in rows] == [("a", 0.0), ("b", 0.0), ("a", 1.0)]
    assert rows[1]["z"] == [1.0, 2.0]  # the first of the conflicting pair stays
    assert json.loads(tracks.read_text())["sensors"] == ["a", "b"]

    # the refusals in this process (the exit code as a shell sees it: the export above)
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(db, run / DB_NAME)
    for args, what in ((["--db", str(db), "--out", str(tmp_path / "missing" / "m.jsonl")], "does not exist"),
                       (["--db", str(tmp_path / "none.db"), "--out", str(out)], "no such recording database"),
                       # a folder was "no such recording database" (before tour62)
                       (["--db", str(tmp_path), "--out", str(out)], f"{tmp_path}: is a folder, not a recording"),
                       (["--db", str(run), "--out", str(out)], f"(its recording: --db {run / DB_NAME})"),
                       (["--db", str(out), "--out", str(tmp_path / "x.jsonl")], "not a fedtrack recording")):
        bad = cli_in_process(["export", *args], capsys, monkeypatch)
        assert bad.returncode == 2 and what in bad.stderr and "Traceback" not in bad.stderr, bad.stderr


@pytest.mark.faults
def test_recorder_killed_and_restarted_mid_run_records_every_track_once(tmp_path: Path) -> None:
    """SIGKILL the recorder at a random point of a lockstep run, restart it on the same database:
    every fused track published is in the database exactly once, and the exported measurements
    replay to the tracks seen live."""
    seed = int(os.environ.get("FEDTRACK_FAULT_SEED", random.randrange(10**6)))
    rng = random.Random(seed)
    dep = Deployment(tmp_path, pacing="realtime", speed=12.0)  # 101 scans in about 8.5 s
    try:
        dep.start()
        assert wait_until(lambda: len(dep.tracks) >= 1, 30.0)
        time.sleep(rng.uniform(0.0, 3.0))  # the restart must be up before the sensors end (their caches go)
        dep.kill("recorder/recorder")
        killed_at = len(dep.tracks)
        time.sleep(rng.uniform(0.2, 0.8))
        restarted_at = len(dep.tracks)
        dep.spawn("recorder/recorder")
        assert dep.wait_sensors_done(90.0)
        db = tmp_path / "recording.db"

        def tracks_in_db() -> int:
            con = sqlite3.connect(db)
            try:
                return int(con.execute("SELECT COUNT(*) FROM tracks").fetchone()[0])
            finally:
                con.close()
        assert wait_until(lambda: tracks_in_db() >= len(dep.tracks), 10.0)
        assert dep.stop("recorder/recorder") == 0
    finally:
        dep.close()
    print(f"seed {seed}: recorder killed after {killed_at} tracks, restarted after {restarted_at}, "
          f"{len(dep.tracks)} tracks published")
    assert len(dep.tracks) == 101
    con = sqlite3.connect(db)
    seqs = [row[0] for row in con.execute("SELECT seq FROM tracks ORDER BY seq")]
    assert seqs == sorted({t.seq for t, _ in dep.tracks}) == list(range(101))
    stored = dict(con.execute("SELECT seq, payload FROM tracks"))
    assert all(bytes(stored[t.seq]) == payload for t, payload in dep.tracks)
    assert con.execute("SELECT COUNT(*), COUNT(DISTINCT sensor || '/' || seq) FROM measurements").fetchone() \
        == (202, 202)
    assert con.execute("SELECT COUNT(*) FROM estimates").fetchone()[0] == 202
    con.close()

    exported = tmp_path / "export.jsonl"
    done = subprocess.run([sys.executable, "-m", "fedtrack.cli", "export", "--db", str(db), "--out", str(exported)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert exported.read_text() == (tmp_path / "measurements.jsonl").read_text()
    replay_fusion("fvdie", exported, dep.config, tmp_path / "replay.jsonl")
    replayed = [json.loads(line) for line in (tmp_path / "replay.jsonl").read_text().splitlines()]
    live = sorted((t for t, _ in dep.tracks), key=lambda t: t.seq)
    assert len(replayed) == len(live)
    # a realtime run on a loaded machine may fuse a scan at its deadline without a late local estimate
    # (marked degraded); the replay fuses every sensor, so the two agree up to the first such scan
    undegraded = next((k for k, t in enumerate(live) if t.degraded), len(live))
    print(f"compared with the replay: {undegraded} scans before the first degraded one")
    for tr, rp in zip(live[:undegraded], replayed):
        assert tr.model == rp["model"] and tr.t == rp["t"]
        np.testing.assert_allclose(tr.x, rp["x"], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(tr.P, rp["P"], rtol=1e-9, atol=1e-6)


WRITER = """
import sys
import numpy as np
from pathlib import Path
from fedtrack.recording import Recording
from fedtrack.wire import Measurement, encode
rec = Recording(Path(sys.argv[1]))
for seq in range(100000):
    m = Measurement(sensor="a", seq=seq, t=float(seq), kind="position", z=np.zeros(2), R=np.eye(2), stamp_ns=1)
    rec.add(m, encode(m))
    print(seq, flush=True)  # committed
"""


@pytest.mark.faults
def test_a_committed_row_survives_sigkill(tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(db)], stdout=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(random.randrange(50, 300))]
        proc.kill()
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    committed = int(lines[-1])
    con = sqlite3.connect(db)
    stored = con.execute("SELECT MAX(seq), COUNT(*) FROM measurements").fetchone()
    con.close()
    assert stored[0] >= committed and stored[1] == stored[0] + 1


def picture(seq: int, t: float, fused: tuple[tuple[str, int], ...], closing: bool = False, **extra: object) -> TrackPicture:
    n = 0 if closing else 1
    return TrackPicture(seq=seq, t=t, ids=tuple(range(n)), x=np.ones((n, 4)), P=np.tile(np.eye(4), (n, 1)),
                        confirmed=(True,) * n, sensors=(("a", "b"),) * n, fused_sensors=tuple(s for s, _ in fused),
                        fused_seqs=tuple(q for _, q in fused), stamp_ns=7, closing=closing, **extra)


def test_the_launcher_exports_a_picture_recording_in_the_centres_order_after_everything_stopped(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack launch`` plans its recorder without ``--out`` and writes the JSON Lines itself once
    every service has stopped, from the database alone (here no recorder process ran at all, as
    after one was killed): the scans in the order the pictures list them (a region run's scan once
    per region, tagged), a departure, the scans no picture lists in unprocessed.jsonl, no closing
    record among the pictures."""
    from fedtrack.deploy.launcher import Launcher
    from fedtrack.deploy.plan import service_plan
    from fedtrack.deploy.settings import load_settings

    db = tmp_path / "recording.db"
    rec = Recording(db)
    scans = [meas("a", 0, 0.0), meas("b", 0, 0.2), meas("a", 1, 1.0), meas("b", 1, 1.2), meas("a", 2, 2.0)]
    pictures = [picture(0, 1.0, (("b", 0), ("a", 0), ("a", 0)), regions=("r1", "r1", "r2")),
                picture(1, 2.0, (("a", 1), ("b", 0)), left=(1,), regions=("r2", "r2")),
                picture(2, 2.0, (("b", 1),), closing=True, regions=("r1",))]
    for msg in [*scans, *pictures]:
        assert rec.add(msg, encode(msg)) == RECORDED
    rec.close()
    config = Path(__file__).resolve().parents[1] / "deploy" / "local.toml"
    settings = load_settings(config)
    plan = service_plan(settings, config, tmp_path, tmp_path / "logs", recorder_exports=False)
    recorder = next(sp for sp in plan if sp.role == "recorder")
    assert "--out" not in recorder.argv and recorder.argv[recorder.argv.index("--db") + 1] == str(db)
    Launcher(settings, [recorder], title="fedtrack demo")._export_recording()
    assert f"fedtrack demo: exported 6 measurement lines and 2 track lines from {db} in" in capsys.readouterr().err

    lines = [json.loads(x) for x in (tmp_path / "measurements.jsonl").read_text().splitlines()]
    assert [(x.get("sensor"), x["t"], x.get("region"), x.get("left", False)) for x in lines] == [
        ("b", 0.2, "r1", False), ("a", 0.0, "r1", False), ("a", 0.0, "r2", False), ("a", 1.0, "r2", False),
        ("b", 2.0, "r2", True), ("b", 1.2, "r1", False)]
    assert lines[0]["z"] == [1.0, 2.0] and lines[0]["seq"] == 0
    unprocessed = [json.loads(x) for x in (tmp_path / "unprocessed.jsonl").read_text().splitlines()]
    assert [(x["sensor"], x["t"]) for x in unprocessed] == [("a", 2.0)]
    tracks = [json.loads(x) for x in (tmp_path / "tracks.jsonl").read_text().splitlines()]
    assert [x["t"] for x in tracks] == [1.0, 2.0] and tracks[0]["tracks"][0]["sensors"] == ["a", "b"]


def test_fedtrack_export_names_the_unprocessed_scans_file_it_writes(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack export`` of a picture recording writes ``unprocessed.jsonl`` beside ``--out`` and says so."""
    db = tmp_path / "recording.db"
    rec = Recording(db)
    for msg in (meas("a", 0, 0.0), meas("b", 0, 0.2), picture(0, 1.0, (("a", 0),))):
        assert rec.add(msg, encode(msg)) == RECORDED
    rec.close()
    out = tmp_path / "m.jsonl"
    assert cli.main(["export", "--db", str(db), "--out", str(out)]) == 0
    unprocessed = tmp_path / "unprocessed.jsonl"
    assert capsys.readouterr().out == f"wrote 1 measurements to {out}, the scans no picture lists to {unprocessed}\n"
    assert [json.loads(x)["sensor"] for x in (tmp_path / "unprocessed.jsonl").read_text().splitlines()] == ["b"]

def test_a_version_1_recording_is_exported_as_before_and_never_written(tmp_path: Path) -> None:
    """A recording made before messages in parts (schema 1: no ``part`` column, whole messages)
    still exports (``fedtrack export``, ``verify_run``); a recorder refuses to append to it."""
    db = tmp_path / "v1.db"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
    con.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    con.execute("CREATE TABLE measurements (id INTEGER PRIMARY KEY, sensor TEXT NOT NULL, seq INTEGER NOT NULL, "
                "t REAL NOT NULL, kind TEXT NOT NULL, stamp_ns INTEGER NOT NULL, received_ns INTEGER NOT NULL, "
                "payload BLOB NOT NULL, UNIQUE (sensor, seq))")
    con.execute("CREATE TABLE pictures (id INTEGER PRIMARY KEY, seq INTEGER NOT NULL, t REAL NOT NULL, "
                "stamp_ns INTEGER NOT NULL, received_ns INTEGER NOT NULL, payload BLOB NOT NULL, UNIQUE (seq))")
    for m in (meas("a", 0, 0.0), meas("b", 0, 0.5)):
        con.execute("INSERT INTO measurements VALUES (NULL, ?, ?, ?, ?, ?, 0, ?)", (m.sensor, m.seq, m.t, m.kind, 7,
                                                                                   encode(m)))
    pic = picture(0, 1.0, (("a", 0),))
    con.execute("INSERT INTO pictures VALUES (NULL, 0, 1.0, 7, 0, ?)", (encode(pic),))
    con.commit()
    con.close()
    rec = Recording(db, readonly=True)
    try:
        assert rec.export(tmp_path / "m.jsonl", tmp_path / "t.jsonl") == (1, 1)
    finally:
        rec.close()
    assert [json.loads(x)["sensor"] for x in (tmp_path / "unprocessed.jsonl").read_text().splitlines()] == ["b"]
    with pytest.raises(InputError, match=r"v1.db: recording schema version 1, expected 2 \(written before messages "
                                         r"in parts: export or verify it, but record into a new one\)"):
        Recording(db)
    con = sqlite3.connect(db)
    assert [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")] == [
        "measurements", "meta", "pictures"]  # the refusal changed nothing
    con.close()


def test_parts_that_never_complete_cost_an_export_nothing_to_hold(tmp_path: Path) -> None:
    """A sender's flood of first parts whose other parts never come (here 20 of a 4,096-detection
    scan, 140 kB each): reading the recording decoded and held each of them until the end, 0.5 MB
    of memory and up to seconds of decoding each (200 of them: 103 MB and 31 s; measured with
    tracemalloc), so that a large enough flood ended the export after the run. A part is now read
    when its message is complete: the whole messages come out as before, the others are counted."""
    rec = Recording(tmp_path / "rec.db")
    rec.db.execute("PRAGMA synchronous = OFF")  # test speed only
    rng = np.random.default_rng(0)
    detections = tuple(Detection(z=rng.uniform(-1e4, 1e4, 2), amplitude=0.0) for _ in range(4096))
    honest = []
    for k in range(20):
        first = parts(Measurement(sensor="s1", seq=k, t=float(k), kind="scan", z=np.zeros(0), R=np.eye(2),
                                  detections=detections))[0]
        assert first.parts == 2 and rec.add(first, encode(first)) == RECORDED
        honest.append(Measurement(sensor="s2", seq=k, t=k + 0.5, kind="position", z=np.ones(2), R=np.eye(2),
                                  stamp_ns=k))
        rec.add(honest[-1], encode(honest[-1]))
    tracemalloc.start()
    try:
        got = list(rec.messages(Measurement, "t, id"))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        rec.close()
    assert [encode(m) for m in got] == [encode(m) for m in honest] and rec.incomplete == 20
    assert peak < 1e6, peak  # before: 10.7 MB


def test_a_picture_of_many_departures_and_restarts_exports_in_linear_time(tmp_path: Path) -> None:
    """A picture listing 65,536 departures and 65,536 restarts (what any ``fusion`` identity may publish,
    in 32 parts): the export looked each of its entries up in the picture's tuples, 13 s for a picture of
    32,768 entries and 160 s for this one (tour47 session; quadratic), so that a few such pictures held
    the launcher's export after the run for hours. Now 0.6 s; every entry is written as before."""
    rec = Recording(tmp_path / "rec.db")
    rec.db.execute("PRAGMA synchronous = OFF")  # test speed only
    n = 65536
    pic = TrackPicture(seq=1, t=1.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(),
                       fused_sensors=("s1",) * n, fused_seqs=(0,) * n, left=tuple(range(0, n, 2)),
                       restarted=tuple(range(1, n, 2)), stamp_ns=1, closing=False)
    for part in parts(pic):
        assert rec.add(part, encode(part)) == RECORDED
    start = time.thread_time()  # the export's CPU time: the wall time took 7.3 s at a load of 30
    assert rec.export(tmp_path / "m.jsonl", tmp_path / "t.jsonl") == (n, 1)
    took = time.thread_time() - start
    rec.close()
    lines = (tmp_path / "m.jsonl").read_text().splitlines()
    assert [json.loads(line) for line in lines[:2]] == [{"t": 1.0, "sensor": "s1", "left": True},
                                                      {"t": 1.0, "sensor": "s1", "restarted": True}]
    assert sum('"left"' in line for line in lines) == n // 2 == sum('"restarted"' in line for line in lines)
    assert took < 5.0, took  # before: 160 s (two other runs on the two cores)


def test_a_full_store_ends_the_recorder_and_what_it_committed_stays_exportable(tmp_path: Path) -> None:
    """A row the database cannot take (here SQLite's page limit: the disk full) is no rejection of the
    message: the recorder's handler raises ServiceFault, which ends the service (exit 1) for the
    launcher to restart it; before 2026-11-27 it was counted ``rejected_handler_error`` and every later
    message lost the same way, the recorder exiting 0. The rows committed before are exported whole."""
    from fedtrack.keys import Keys
    from fedtrack.recording import StorageError
    from fedtrack.services.dispatch import ServiceFault
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    db = tmp_path / "r.db"
    rec = Recording(db)
    for seq in range(5):
        m = meas("a", seq, float(seq))
        assert rec.add(m, encode(m)) == RECORDED
    rec.db.execute(f"PRAGMA max_page_count = {rec.db.execute('PRAGMA page_count').fetchone()[0]}")
    big = scan("a", 5, 200)
    with pytest.raises(StorageError, match=f"{db}: cannot record: database or disk is full"):
        rec.add(big, encode(big))
    svc = Recorder(db=db, service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="t")
    svc.recording, svc._subscriptions = rec, svc.subscriptions()
    with pytest.raises(ServiceFault, match="database or disk is full"):
        svc._dispatch(("sample", 0, Keys("t").sensor_meas("a"), encode(big)))
    assert svc.counters.get("rejected", 0) == 0
    rec.close()
    readonly = Recording(db, readonly=True)
    assert readonly.export(tmp_path / "m.jsonl") == (5, 0)
    readonly.close()


def test_a_recording_removed_or_replaced_under_the_recorder_ends_it(tmp_path: Path) -> None:
    """SQLite writes on into the file it opened: removed mid-run, a launch recorded 128 scans and 40
    pictures into it, exported nothing and exited 0 (before 2026-11-27). The recorder's tick (every
    second) now finds the file gone or replaced and stops (ServiceFault: exit 1, restarted by the
    launcher on a new file, recovering from the caches)."""
    from fedtrack.recording import StorageError
    from fedtrack.services.dispatch import ServiceFault
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    db = tmp_path / "r.db"
    svc = Recorder(db=db, service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="t")
    svc.recording = Recording(db)
    svc.on_tick()  # the file it opened: nothing to say
    db.unlink()
    with pytest.raises(ServiceFault, match=f"{db}: removed or replaced while recording"):
        with svc.guarded("on_tick"):
            svc.on_tick()
    svc.recording.close()
    other = Recording(db)  # another file at the path
    db.rename(tmp_path / "elsewhere.db")
    db.write_bytes((tmp_path / "elsewhere.db").read_bytes())
    with pytest.raises(StorageError, match="removed or replaced"):
        other.check_file()
    other.close()


def test_a_recording_damaged_on_disk_is_refused_in_one_line_naming_it(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack export`` of a recording whose pages were overwritten: exit 2, one line naming the file,
    no output written (before 2026-11-27: a DatabaseError traceback)."""
    from fedtrack.cli import main

    db = tmp_path / "r.db"
    rec = Recording(db)
    rec.db.execute("PRAGMA synchronous = OFF")  # no fsync a row: this test is about reading
    for seq in range(400):
        m = scan("a", seq, 20)
        rec.add(m, encode(m))
    rec.close()
    data = bytearray(db.read_bytes())
    data[len(data) // 2:len(data) // 2 + 8192] = b"\xab" * 8192  # pages in the middle, the header intact
    db.write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["export", "--db", str(db), "--out", str(tmp_path / "m.jsonl")]) == 2
    expected = f"fedtrack: error: {db}: a damaged recording, cannot be read (database disk image is malformed)"
    assert capsys.readouterr().err.splitlines() == [expected]
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith("r.db")] == []  # nothing half-written


@pytest.mark.faults
def test_a_recorder_past_its_file_size_limit_exits_1_naming_its_database(tmp_path: Path) -> None:
    """A live recorder under RLIMIT_FSIZE (the disk full for it alone) stops at the first row it cannot
    write: exit 1 within seconds, one line naming the database, no traceback; the rows it committed
    stay readable (before 2026-11-27 it ran on, every later message rejected, and exited 0 when stopped)."""
    from support import free_port

    from fedtrack.keys import Keys
    from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive

    endpoint, keys, db, log = f"tcp/127.0.0.1:{free_port()}", Keys("fsize"), tmp_path / "r.db", tmp_path / "rec.log"
    router = open_session(SessionOptions(mode="router", connect=(), listen=(endpoint,)))
    client = open_session(SessionOptions(connect=(endpoint,)))
    limit = 256 * 1024  # the database's first pages and some 100 scans of its write-ahead log
    limited = (f"import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.RLIM_INFINITY)); "
               "from fedtrack.cli import main; sys.exit(main())")  # set in the child itself: no preexec_fn
    with log.open("wb") as out:
        proc = subprocess.Popen([sys.executable, "-c", limited, "serve", "recorder", "--db", str(db),
                                 "--connect", endpoint, "--deployment", keys.deployment], stdout=out,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        assert not wait_alive(client, [keys.alive("recorder", "recorder")], 30.0), log.read_text()
        sent = 0
        while proc.poll() is None and sent < 600:  # about 3 times what fits
            client.put(keys.sensor_meas("a"), encode(scan("a", sent, 100)))
            sent += 1
            time.sleep(0.002)
        assert wait_until(lambda: proc.poll() is not None, 10.0), "the recorder ran on past its file size limit"
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
        close_session(client)
        close_session(router)
    text = log.read_text()
    assert proc.returncode == 1 and "Traceback" not in text, text
    assert f"ERROR: {db}: cannot record: disk I/O error (SQLITE_IOERR_WRITE): stopping" in text, text
    rec = Recording(db, readonly=True)
    assert 0 < rec.count(Measurement) < sent
    rec.close()


def test_an_export_onto_a_full_disk_names_its_file_and_leaves_nothing(tmp_path: Path) -> None:
    """A multi-target export's writes refused (here by RLIMIT_FSIZE, set for a moment in this process: EFBIG, as
    ENOSPC on a full disk) end in an InputError naming the file written, no part of it left (before
    2026-11-27 the launcher said 'could not export the recording: None: cannot write: ...')."""
    import resource

    db = tmp_path / "r.db"
    rec = Recording(db)
    rec.db.execute("PRAGMA synchronous = OFF")  # no fsync a row: this test is about the export
    for seq in range(100):
        m, pic = scan("a", seq, 50), picture(seq, float(seq), (("a", seq),))
        rec.add(m, encode(m))
        rec.add(pic, encode(pic))
    out = tmp_path / "out"
    out.mkdir()
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, hard))
    try:
        with pytest.raises(InputError) as caught:
            rec.export(out / "m.jsonl")
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        rec.close()
    assert str(caught.value) == f"{out / 'm.jsonl'}: cannot write: File too large"
    assert list(out.iterdir()) == []


def test_a_memory_error_in_a_handler_rejects_its_message_and_the_service_goes_on(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A MemoryError in a handler (numpy's, refused an allocation as under RLIMIT_AS) rejects its message
    (``rejected_handler_error``, the state put back) and the next message is taken: a message may ask for a
    bounded but large allocation that a small host refuses, and stopping there would let that message, sent
    again, restart the service again and again (a stop was tried in the faults6 session and reverted)."""
    from fedtrack.keys import Keys
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    svc = Recorder(db=tmp_path / "r.db", service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)),
                   deployment="t")
    svc.recording, svc._subscriptions = Recording(tmp_path / "r.db"), svc.subscriptions()
    add = svc.recording.add
    monkeypatch.setattr(svc.recording, "add", lambda msg, payload: np.empty(2**62, dtype=np.uint8))
    key = Keys("t").sensor_meas("a")
    svc._dispatch(("sample", 0, key, encode(meas("a", 0, 0.0))))
    assert svc.counters.get("rejected_handler_error", 0) == 1
    monkeypatch.setattr(svc.recording, "add", add)
    svc._dispatch(("sample", 0, key, encode(meas("a", 1, 1.0))))
    assert svc.counters.get("rejected", 0) == 1
    svc.recording.close()


def test_the_scans_a_sensor_published_that_the_recording_lacks_are_counted_per_sensor(tmp_path: Path) -> None:
    """A multi-target launch compares the scenario's scans of each sensor it ran with the recording's
    complete scans (a scan in parts counts once all its parts are in): a router frozen past its lease
    until the run's end lost 91 of 128 scans live, which the summary did not say (11 of 39 pictures,
    exit 0)."""
    from fedtrack.deploy.multitarget import SCENARIO_DIR, unrecorded_scans
    from fedtrack.deploy.settings import load_settings

    config = tmp_path / "c.toml"
    config.write_text('[multitarget]\nsensors = "pos:1.0,pos:0.7,pos:1.3"\nkill_at = {s3 = 1.0}\n')
    settings = load_settings(config)
    (tmp_path / SCENARIO_DIR).mkdir()
    (tmp_path / SCENARIO_DIR / "measurements.jsonl").write_text(
        "".join(json.dumps({"t": float(k), "sensor": s}) + "\n" for s, n in (("s1", 3), ("s2", 2), ("s3", 4))
                for k in range(n)))
    assert unrecorded_scans(tmp_path, settings) == {"s1": 3, "s2": 2}  # the recording gone: every scan
    rec = Recording(tmp_path / "recording.db")
    for m in (meas("s1", 0, 0.0), meas("s1", 1, 1.0), meas("s2", 0, 0.0), meas("s2", 1, 1.0)):
        rec.add(m, encode(m))
    first = parts(scan("s1", 2, 8000))[0]  # scan 2 of s1 in parts, one of them recorded
    assert first.parts > 1
    rec.add(first, encode(first))
    rec.close()
    assert unrecorded_scans(tmp_path, settings) == {"s1": 1}  # s3, killed by the schedule, is not judged
    config.write_text('[multitarget]\nsensors = "pos:1.0,pos:0.7,pos:1.3"\njoin_at = {s3 = 2.0}\n')
    assert unrecorded_scans(tmp_path, load_settings(config)) == {"s1": 1, "s3": 2}  # a joiner: its scans from 2 s on


def test_a_launch_summary_onto_a_full_disk_names_its_file_and_leaves_nothing_half_written(tmp_path: Path) -> None:
    """The disk full at the run's end (RLIMIT_FSIZE here, EFBIG as ENOSPC): the copy of the truth raises an
    InputError naming OUT/truth.jsonl and leaves none of it (before 2026-11-27: 'fedtrack: error:
    OUT/scenario/truth.jsonl: No space left on device', the copy's source, exit 2, half a truth.jsonl)."""
    import resource

    from fedtrack.deploy.multitarget import SCENARIO_DIR, finish_multitarget
    from fedtrack.deploy.report import LaunchReport
    from fedtrack.deploy.settings import load_settings

    config = tmp_path / "c.toml"
    config.write_text('[multitarget]\nsensors = "pos:1.0"\n')
    (tmp_path / SCENARIO_DIR).mkdir()
    (tmp_path / SCENARIO_DIR / "truth.jsonl").write_text(json.dumps({"t": 0.0, "pad": "x" * 200_000}) + "\n")
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, hard))
    try:
        with pytest.raises(InputError, match=f"^{tmp_path / 'truth.jsonl'}: cannot write: File too large$"):
            finish_multitarget(tmp_path, LaunchReport(), "fedtrack launch", load_settings(config))
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", SCENARIO_DIR]


def test_a_stopped_recorder_commits_its_whole_backlog_before_it_says_stopped(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Stopped with fused tracks still queued, the recorder commits all of them (a row an fsync, slow on a
    loaded host) within the launcher's grace: with the base's 2 s drain, at CI load 11, 32 of a lockstep
    run's 101 fused tracks were counted ``dropped`` and missing from tracks.jsonl, exit 0. Here a row
    takes 25 ms and 100 are queued: 2.5 s of work (before: 31 of them dropped)."""
    from fedtrack.deploy.launcher import RECORDER_GRACE_S
    from fedtrack.keys import Keys
    from fedtrack.services.base import CLOSE_DEADLINE_S
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    svc = Recorder(db=tmp_path / "r.db", service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)),
                   deployment="t")
    svc.recording, svc._subscriptions = Recording(tmp_path / "r.db"), svc.subscriptions()
    add = svc.recording.add

    def slow_add(msg: object, payload: bytes, table: object = None) -> str:
        time.sleep(0.025)
        return add(msg, payload, table)

    monkeypatch.setattr(svc.recording, "add", slow_add)
    index = next(i for i, sub in enumerate(svc._subscriptions) if sub.msg_type is FusedTrack)
    key = Keys("t").fusion_track()
    for seq in range(100):
        track = FusedTrack(seq=seq, t=float(seq), model="cv", x=np.ones(4), P=np.eye(4), maneuver=False,
                           degraded=False, sensors=("a",), stamp_ns=7)
        assert svc._queue.put(("sample", index, key, encode(track)), timeout=0.0)
    svc._drain()
    assert svc.counters["dropped"] == 0 and svc.counters["tracks_recorded"] == 100
    assert svc.recording.count(FusedTrack) == 100
    svc.recording.close()
    assert svc.drain_deadline_s + CLOSE_DEADLINE_S < RECORDER_GRACE_S  # its final Health goes out before a SIGKILL


def test_a_restarted_sensors_scans_sent_again_are_duplicates_and_a_conflict_is_said(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A sensor started by hand, stopped and started again numbers its scans from 0 again: the same scans,
    stamped anew. The recorder counted each a ``conflict`` (tour59: 38 of them on a by-hand run at 10x, where
    the services count the same ``duplicate``) and said nothing; now they are duplicates, and a scan that
    really differs (a sensor given another --seed or file) is a conflict said once for its sensor."""
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    svc = Recorder(db=tmp_path / "r.db", service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)),
                   deployment="t")
    svc.on_start()
    table = TABLE_OF[Measurement]
    first, again = scan("s1", 0, 3), dataclasses.replace(scan("s1", 0, 3), stamp_ns=99)
    with caplog.at_level(logging.WARNING):
        svc.on_message(table, first, encode(first))
        svc.on_message(table, again, encode(again))  # the restart's scan 0: only its stamp differs
        assert svc.counters.get("duplicate") == 1 and not svc.counters.get("conflict")
        for n in (4, 5):  # two scans that differ: one line for the sensor
            other = scan("s1", 0, n)
            svc.on_message(table, other, encode(other))
    assert svc.counters.get("conflict") == 2
    said = [r.getMessage() for r in caplog.records if "not stored" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("measurements s1 0: a different message") and "--start-at" in said[0]
    svc.recording.close()


def test_verify_run_names_a_run_folder_that_is_not_there(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``verify_run --run`` of a folder that does not exist says so; before (tour57) it named the first file it
    looked for in it, ``RUN/tracks.jsonl: file does not exist``, as if the run had been cut short."""
    from fedtrack.deploy.verify_run import main as verify_main

    config = Path(__file__).resolve().parents[1] / "deploy" / "local.toml"
    assert verify_main(["--config", str(config), "--run", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert f"--run {tmp_path / 'nope'}: no such folder" in err and "tracks.jsonl" not in err


def replayed_run(tmp_path: Path, algorithm: str) -> tuple[Path, Path]:
    """A 3-target, 8 s scenario simulated into ``tmp_path/sim`` and a run folder ``tmp_path/run`` holding its
    measurements and their replay by ``algorithm`` as the run's tracks (a run equal to its replay)."""
    sim, run = tmp_path / "sim", tmp_path / "run"
    run.mkdir()
    assert cli.main(["simulate", "multitarget", "--targets", "3", "--duration", "8", "--out", str(sim)]) == 0
    (run / "measurements.jsonl").write_bytes((sim / "measurements.jsonl").read_bytes())
    assert cli.main(["replay", "--algorithm", algorithm, "--config", str(sim / "config.toml"),
                     "--measurements", str(run / "measurements.jsonl"), "--out", str(run / "tracks.jsonl")]) == 0
    return sim, run


def test_verify_run_of_a_multitarget_run_started_by_hand(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The services started by hand (``serve mtt-centre --algorithm ... --config C``) leave a config without
    ``[multitarget]``: ``verify_run --algorithm mtt-*`` checks their pictures against the replay, and without it
    the line says what to give. Before (tour58) the paper replay read the scans: ``measurements.jsonl:1: unknown
    field 'detections'``, and no option could say which centre ran."""
    from fedtrack.deploy.verify_run import main as verify_main

    sim, run = replayed_run(tmp_path, "mtt-federated")
    capsys.readouterr()
    assert verify_main(["--config", str(sim / "config.toml"), "--run", str(run)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"verify_run: error: {run / 'tracks.jsonl'}: multi-target pictures, but {sim / 'config.toml'} has no "
        "[multitarget] table naming the centre's algorithm: give --algorithm (mtt-federated, mtt-decentralized or "
        "mtt-centralized)")
    assert verify_main(["--config", str(sim / "config.toml"), "--run", str(run), "--algorithm", "mtt-federated"]) == 0
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["ok"] and verdict["pictures"] == verdict["replayed"] == 8 and verdict["max_replay_diff"] == 0.0


def test_verify_run_that_agrees_prints_its_verdict_alone(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A run equal to its replay: the verdict on stdout and nothing on stderr (before, tour59: the replay's
    counter and stage-timing lines, noise in ``netns-demo.sh``); a run that disagrees: the replay's lines on
    stderr after the verdict, where they help explain it."""
    from fedtrack.deploy.verify_run import main as verify_main

    sim, run = replayed_run(tmp_path, "mtt-centralized")
    capsys.readouterr()
    verify = ["--config", str(sim / "config.toml"), "--run", str(run), "--algorithm", "mtt-centralized"]
    assert verify_main(verify) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["ok"] and err == ""
    lines = (run / "tracks.jsonl").read_text().splitlines()
    (run / "tracks.jsonl").write_text("\n".join(lines[:-1]) + "\n")  # the last picture lost
    assert verify_main(verify) == 1
    out, err = capsys.readouterr()
    assert json.loads(out)["pictures"] == len(lines) - 1 and "mtt-centralized: seconds per input scan" in err


def test_a_recorder_with_out_says_pictures_of_a_multitarget_recording(tmp_path: Path,
                                                                     caplog: pytest.LogCaptureFixture) -> None:
    """``serve recorder --out`` of a multi-target run says how many pictures it wrote, as ``fedtrack export``
    does; before (tour58) its line said ``wrote 379 measurements and 119 tracks`` of 119 pictures."""
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    svc = Recorder(db=tmp_path / "r.db", out=tmp_path, service_id="recorder",
                   options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="t")
    svc.recording = Recording(tmp_path / "r.db")
    picture = TrackPicture(seq=0, t=0.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(),
                           fused_sensors=(), fused_seqs=(), stamp_ns=1)
    svc.recording.add(picture, encode(picture))
    with caplog.at_level("INFO"):
        svc.on_stop()
    assert f"wrote 0 measurements and 1 pictures to {tmp_path}" in caplog.text


@pytest.mark.security
@pytest.mark.parametrize("track", ["", 1e80, 2.5, [1.0]])
def test_a_tracker_track_whose_id_no_integer_column_holds_is_rejected_and_counted(tmp_path: Path, track: object
                                                                                   ) -> None:
    """A single-sensor tracker's track (``tracker/<tracker>/<sensor>/track``) whose ``extra.track`` is not a whole
    number the ``tracker_tracks`` table holds is refused (``rejected_track``); before, ``int("")`` or ``int(1e80)``
    in the table's row failed the handler (found by test_fuzz_services), and a good one after it is recorded."""
    from fedtrack.keys import Keys
    from fedtrack.services.recorder import Recorder
    from fedtrack.zsession import SessionOptions

    svc = Recorder(db=tmp_path / "r.db", service_id="recorder", options=SessionOptions(connect=("tcp/127.0.0.1:1",)),
                   deployment="t")
    svc.recording, svc._subscriptions = Recording(tmp_path / "r.db"), svc.subscriptions()
    key = Keys("t").tracker_track("hpda", "sonar1")
    sub = next(i for i, s in enumerate(svc._subscriptions) if s.msg_type is FusedTrack and "tracker" in s.key)

    def hpda_track(seq: int, track_id: object) -> bytes:
        return encode(FusedTrack(seq=seq, t=float(seq), model="hpda", x=np.zeros(6), P=np.eye(6), maneuver=False,
                                 degraded=False, sensors=("sonar1",), stamp_ns=1, extra={"track": track_id}))

    svc._dispatch(("sample", sub, key, hpda_track(0, track)))
    assert svc.counters.get("rejected_track", 0) == 1, svc.counters
    assert svc.counters.get("rejected_handler_error", 0) == 0
    svc._dispatch(("sample", sub, key, hpda_track(1, 3.0)))
    assert svc.counters.get("tracker_tracks_recorded", 0) == 1
    svc.recording.close()


def test_verify_run_scales_a_difference_by_the_largest_entry_of_its_estimate() -> None:
    """Round-off is mixed across a state's entries, so a difference counts against the largest entry: the
    seed-5 decentralized demo's 1.5e-9 on an acceleration below 1 in a state up to 1e5 is round-off (before,
    scaled by the entry itself: 1.5e-9 > 1e-9, a correct run failed), while 1e-3 m on that state is not."""
    from fedtrack.deploy.verify_run import TOLERANCE, scaled_diff

    replay = [95645.39671752996, 2532.7995085022308, 0.5, -1200.0, 3.0, -0.25]
    live = list(replay)
    live[2] += 1.5e-9
    assert scaled_diff(live, replay) <= TOLERANCE
    live[0] += 1e-3
    assert scaled_diff(live, replay) > TOLERANCE
    assert scaled_diff([1e-12, 0.0], [0.0, 2e-9]) == pytest.approx(2e-9)  # small states: absolute
    assert scaled_diff([1.0, 2.0], [1.0]) == float("inf")
