"""The recorder's SQLite database (WAL mode) and ``fedtrack export``.

Schema (version 2; ``id`` is the arrival order, ``received_ns`` the recorder's wall
clock at arrival, ``payload`` the message's msgpack bytes exactly as received, so
every row decodes back to the message with :func:`fedtrack.wire.decode`):

================  ==============================================  =========================
table             columns besides id, received_ns, payload        unique (one row per ...)
================  ==============================================  =========================
``measurements``  sensor, seq, t, kind, stamp_ns, part, parts     (sensor, seq, part)
``estimates``     sensor, seq, t, model, stamp_ns                 (sensor, seq)
``tracks``        seq, t, model, degraded, sensors, stamp_ns      (seq)
``events``        seq, t, kind                                    (seq, kind)
``pictures``      seq, t, stamp_ns, part, parts (``TrackPicture``)  (seq, part)
``tracker_tracks``  tracker, sensor, seq, t, track, stamp_ns        (tracker, sensor, seq, track)
``meta``          key, value (``schema_version``)                 (key)
================  ==============================================  =========================

A message sent in parts (beyond a per-message bound of the wire: docs/wire.md, "Messages in
parts") is stored as its parts, a row each as received (``part`` its index, ``parts`` their
number; 0 and 1 for a whole message); :meth:`Recording.messages`, and so ``export``, give it
joined, in the place of its last part in the order asked for, and leave out a message whose parts
are not all recorded or do not join (counted in ``Recording.incomplete``). Version 1 (before
2026-11-27) had no ``part`` column and only whole messages: it is read (``export``, ``verify_run``)
as before, and a recorder refuses to write into it, naming its version.

``tracker_tracks`` holds the single-sensor trackers' tracks (``serve imm`` and ``serve hpda``, key
``tracker/<tracker>/<sensor>/track``; ``tracker`` their algorithm, the message's ``model``; ``track``
hpda's track id, -1 for an IMM's one track): a ``FusedTrack`` like the fused tracks, in a table of its own
(tour58: before, the recorder did not subscribe to them). A version-2 database written before gets the
table when a recorder opens it; read only, it has none (no rows).

Every table with a ``t`` has an index on ``t``; the unique keys double as the index
on ``sensor``. A message whose unique key is already stored is not stored again: a
copy (a redelivery from Zenoh's history or recovery; the same message stamped anew, as a restarted
sensor sends its scans again) counts as a duplicate, a different one as a conflict (the first row
stays; the recorder says so in its log). Before the tour59 session a copy differing only in its
``stamp_ns`` counted as a conflict, which the services call a duplicate (``admission.digest``).

Durability: ``journal_mode=WAL``, ``synchronous=FULL``, and every row is its own
transaction, committed (and fsynced) before the next message is handled: a row that
was committed survives SIGKILL of the recorder and a power loss. A row that cannot be
written (the disk full, the file size limit reached, the file or its folder made read-only,
an I/O error) raises :class:`StorageError` naming the file, the rows committed before
staying readable; a database damaged on disk (cut or overwritten) is refused by the readers
in one line (InputError naming the file), never half-exported.

``fedtrack export --db PATH --out FILE.jsonl [--tracks FILE.jsonl] [--tracker-tracks FILE.jsonl]`` writes the
measurements in the ``replay`` input format, in scan order (``t``, then arrival), so
that ``fedtrack replay`` always accepts what was recorded, and optionally the fused
tracks in the replay output format (``seq`` order), and optionally the single-sensor trackers' tracks in
the same format (arrival order; ``model`` the tracker's algorithm, ``sensors`` its sensor). A multi-target
recording (one with pictures) is written in the centre's processing order instead (the scans and departures each
picture lists, picture by picture): the order ``replay --algorithm mtt-*`` must follow to give
the recorded pictures, which are the tracks file (one picture a line). Scans the centre never
processed (no local tracker took them, or it dropped them as late) go to
``unprocessed.jsonl`` beside the measurements file, in arrival order. A region run's merged
pictures (``TrackPicture.regions``: docs/multitarget.md#regions) give one line per region entry,
tagged ``"region"`` (scans with their ``"seq"``; hand-overs as ``{"t", "region", "handover": N,
"from": region}``; a region centre's start afresh as ``{"t", "region", "began": true, "next_id": N,
"serial": S}``), each region's in its processing order.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Callable, Iterator

import orjson

from fedtrack.jsonl import InputError, check_outputs, output_file
from fedtrack.services.admission import digest
from fedtrack.wire import (
    FusedTrack,
    LocalEstimate,
    ManeuverEvent,
    Measurement,
    Message,
    TrackPicture,
    WireError,
    decode,
    join,
    measurement_to_replay,
    picture_to_replay,
    track_to_replay,
)

SCHEMA_VERSION = 2
DB_NAME = "recording.db"  # a run's recording database in its output folder
RECORDED, DUPLICATE, CONFLICT = "recorded", "duplicate", "conflict"
# SQLite's primary result codes of a store that cannot take a row (not a fault of the row itself)
STORAGE_FAULTS = frozenset({sqlite3.SQLITE_FULL, sqlite3.SQLITE_IOERR, sqlite3.SQLITE_READONLY, sqlite3.SQLITE_CANTOPEN,
                            sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB, sqlite3.SQLITE_PERM, sqlite3.SQLITE_BUSY,
                            sqlite3.SQLITE_LOCKED})
SCANS_KEPT = 256  # decoded scans an export keeps: a region run lists a scan in every region it reached, pictures apart


class StorageError(OSError):
    """The recording database cannot take a row; the message names the file and SQLite's reason."""


@contextlib.contextmanager
def _read_of(path: Path) -> Iterator[None]:
    """A database error while reading ``path`` (a page cut or overwritten on disk) as one InputError
    naming it; before 2026-11-27 ``export`` of such a file ended in a traceback."""
    try:
        yield
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{path}: a damaged recording, cannot be read ({exc})") from None


def _file_id(path: Path) -> tuple[int, int] | None:
    """The device and inode of ``path``, None when it does not exist."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino


@dataclass(frozen=True)
class Table:
    """One message type's table: its columns (taken from the message) and its unique key."""

    name: str
    msg_type: type
    columns: dict[str, str]  # column -> SQL type
    unique: tuple[str, ...]
    values: Callable[[Any], tuple[Any, ...]]

    def ddl(self) -> list[str]:
        cols = ", ".join(f"{c} {sql} NOT NULL" for c, sql in self.columns.items())
        stmts = [f"CREATE TABLE IF NOT EXISTS {self.name} (id INTEGER PRIMARY KEY, {cols}, "
                 f"received_ns INTEGER NOT NULL, payload BLOB NOT NULL, UNIQUE ({', '.join(self.unique)}))"]
        if "t" in self.columns:
            stmts.append(f"CREATE INDEX IF NOT EXISTS {self.name}_t ON {self.name} (t)")
        return stmts


# the single-sensor trackers' tracks (serve imm, serve hpda): FusedTracks on keys of their own (module docstring)
TRACKER_TRACKS = Table("tracker_tracks", FusedTrack,
                       {"tracker": "TEXT", "sensor": "TEXT", "seq": "INTEGER", "t": "REAL", "track": "INTEGER",
                        "stamp_ns": "INTEGER"},
                       ("tracker", "sensor", "seq", "track"),
                       lambda f: (f.model, ",".join(f.sensors), f.seq, f.t, int(f.extra.get("track", -1)), f.stamp_ns))
TABLES: tuple[Table, ...] = (
    Table("measurements", Measurement,
          {"sensor": "TEXT", "seq": "INTEGER", "t": "REAL", "kind": "TEXT", "stamp_ns": "INTEGER", "part": "INTEGER",
           "parts": "INTEGER"},
          ("sensor", "seq", "part"), lambda m: (m.sensor, m.seq, m.t, m.kind, m.stamp_ns, m.part, m.parts)),
    Table("estimates", LocalEstimate,
          {"sensor": "TEXT", "seq": "INTEGER", "t": "REAL", "model": "TEXT", "stamp_ns": "INTEGER"},
          ("sensor", "seq"), lambda e: (e.sensor, e.seq, e.t, e.model, e.stamp_ns)),
    Table("tracks", FusedTrack,
          {"seq": "INTEGER", "t": "REAL", "model": "TEXT", "degraded": "INTEGER", "sensors": "TEXT",
           "stamp_ns": "INTEGER"},
          ("seq",), lambda f: (f.seq, f.t, f.model, int(f.degraded), ",".join(f.sensors), f.stamp_ns)),
    Table("events", ManeuverEvent, {"seq": "INTEGER", "t": "REAL", "kind": "TEXT"},
          ("seq", "kind"), lambda e: (e.seq, e.t, e.kind)),
    Table("pictures", TrackPicture,
          {"seq": "INTEGER", "t": "REAL", "stamp_ns": "INTEGER", "part": "INTEGER", "parts": "INTEGER"},
          ("seq", "part"), lambda p: (p.seq, p.t, p.stamp_ns, p.part, p.parts)),
    TRACKER_TRACKS,
)
# a message type's table: a FusedTrack's is the fused tracks'
TABLE_OF: dict[type, Table] = {table.msg_type: table for table in TABLES if table is not TRACKER_TRACKS}


class Recording:
    """An open recording database (created with the schema if new)."""

    def __init__(self, path: Path, readonly: bool = False) -> None:
        self.path = path
        if readonly:
            if path.is_dir():  # was "no such recording database" (before tour62)
                inside = path / DB_NAME
                hint = f" (its recording: --db {inside})" if inside.is_file() else ""
                raise InputError(f"{path}: is a folder, not a recording database{hint}")
            if not path.is_file():
                raise InputError(f"{path}: no such recording database")
            self.db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, isolation_level=None)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(path, isolation_level=None)  # autocommit: one transaction per row
        self.file_id = _file_id(path)  # the file opened (check_file)
        self.incomplete = 0  # messages in parts left out by :meth:`messages` (not all recorded, or not joining)
        try:
            self.db.execute("PRAGMA busy_timeout = 5000")
            if not readonly:
                self.db.execute("PRAGMA journal_mode = WAL")
                self.db.execute("PRAGMA synchronous = FULL")
                self._create()
            self.version = self._check_version(readonly)
        except sqlite3.DatabaseError as exc:
            self.db.close()
            raise InputError(f"{path}: not a fedtrack recording ({exc})") from None

    def _create(self) -> None:
        """The schema, in one transaction; nothing is changed in a database of another version."""
        self.db.execute("BEGIN")
        try:
            self.db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            self.db.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            self._check_version(readonly=False)
            for table in TABLES:
                for stmt in table.ddl():
                    self.db.execute(stmt)
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.db.execute("COMMIT")

    def _check_version(self, readonly: bool) -> int:
        """The database's schema version: this one, or version 1 when only read (its rows are whole
        messages); InputError naming the version otherwise."""
        row = self.db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        version = None if row is None else row[0]
        if version == str(SCHEMA_VERSION) or readonly and version == "1":
            return int(version)
        older = " (written before messages in parts: export or verify it, but record into a new one)" \
            if version == "1" else ""
        raise InputError(f"{self.path}: recording schema version {version}, expected {SCHEMA_VERSION}{older}")

    def add(self, msg: Message, payload: bytes, table: Table | None = None) -> str:
        """Store ``msg`` (received as ``payload``) in ``table`` (None: its type's) and commit; returns RECORDED,
        DUPLICATE or CONFLICT."""
        table = table or TABLE_OF[type(msg)]
        values = table.values(msg)
        cols = list(table.columns)
        try:
            cur = self.db.execute(
                f"INSERT INTO {table.name} ({', '.join(cols)}, received_ns, payload) "
                f"VALUES ({', '.join('?' * (len(cols) + 2))}) ON CONFLICT DO NOTHING",
                (*values, time.time_ns(), payload))
            if cur.rowcount == 1:
                return RECORDED
            key = {c: v for c, v in zip(cols, values) if c in table.unique}
            where = " AND ".join(f"{c} = ?" for c in key)
            stored = self.db.execute(f"SELECT payload FROM {table.name} WHERE {where}", tuple(key.values())).fetchone()
        except sqlite3.Error as exc:
            if getattr(exc, "sqlite_errorcode", 0) & 0xFF not in STORAGE_FAULTS:
                raise
            raise StorageError(f"{self.path}: cannot record: {exc} ({exc.sqlite_errorname})") from None
        if stored is None:
            return CONFLICT
        kept = bytes(stored[0])
        # the same message sent again (a restarted sensor's scan, stamped anew) is a duplicate, as at the services
        return DUPLICATE if kept == payload or digest(decode(kept, type(msg))) == digest(msg) else CONFLICT

    def check_file(self) -> None:
        """StorageError when the database file is no longer the one opened (removed, or replaced by
        another): SQLite writes on into the file it opened, which nothing will read. Removed mid-run,
        a launch recorded 128 scans and 40 pictures into a removed file and exported nothing, exit 0,
        before 2026-11-27."""
        if _file_id(self.path) != self.file_id:
            raise StorageError(f"{self.path}: removed or replaced while recording (rows written since are lost)")

    def count(self, of: type | Table) -> int:
        """Rows of a message type's table or of a :class:`Table` (0 for a table an older recording, opened
        read-only, does not have)."""
        table = of if isinstance(of, Table) else TABLE_OF[of]
        with _read_of(self.path):
            try:
                return int(self.db.execute(f"SELECT COUNT(*) FROM {table.name}").fetchone()[0])
            except sqlite3.OperationalError as exc:
                if exc.sqlite_errorcode != sqlite3.SQLITE_ERROR:  # no such table: SQLITE_ERROR; a read fault: others
                    raise
                return 0

    def scans(self) -> dict[str, int]:
        """The measurements recorded per sensor, a message in parts counted once all its parts are in."""
        parts = "MAX(parts)" if self.version > 1 else "1"
        with _read_of(self.path):
            return dict(self.db.execute(
                f"SELECT sensor, COUNT(*) FROM (SELECT sensor FROM measurements GROUP BY sensor, seq "
                f"HAVING COUNT(*) = {parts}) GROUP BY sensor").fetchall())

    def pictures(self) -> set[int]:
        """The numbers of the pictures recorded (a closing record's too), one in parts once all its parts are in."""
        parts = "MAX(parts)" if self.version > 1 else "1"
        with _read_of(self.path):
            return {seq for seq, in self.db.execute(f"SELECT seq FROM pictures GROUP BY seq HAVING COUNT(*) = {parts}")}

    def messages(self, of: type | Table, order: str) -> Iterator[Any]:
        """The stored messages of a message type's table or of a :class:`Table` in ``order`` (an ORDER BY
        clause of the table's columns); a message stored in parts joined, in the place of its last part (module
        docstring)."""
        table = of if isinstance(of, Table) else TABLE_OF[of]
        if "parts" not in table.columns or self.version == 1:  # whole messages only
            for rowid, payload in self.db.execute(f"SELECT id, payload FROM {table.name} ORDER BY {order}"):
                yield _decoded(self.path, table, rowid, payload)
            return
        # a part is read when its message is complete: parts that never complete (a sender's flood of
        # first parts) held 0.5 MB each and took seconds each to decode before 2026-11-27
        key = ", ".join(c for c in table.unique if c != "part")
        # the rows of a message's parts so far, by its unique key but the part
        held: dict[tuple[Any, ...], list[int]] = {}
        for rowid, payload, parts, *unique in self.db.execute(
                f"SELECT id, CASE WHEN parts = 1 THEN payload END, parts, {key} FROM {table.name} ORDER BY {order}"):
            if parts == 1:
                yield _decoded(self.path, table, rowid, payload)
                continue
            rows = held.setdefault(tuple(unique), [])
            rows.append(rowid)
            if len(rows) == parts:
                whole = self._joined([self._row(table, i) for i in held.pop(tuple(unique))])
                if whole is not None:
                    yield whole
        self.incomplete += len(held)

    def _joined(self, parts: list[Any]) -> Any:
        """The message of ``parts`` (all of one message's rows), or None (counted) when they do not join."""
        try:
            return join(parts)
        except WireError:
            self.incomplete += 1
            return None

    def export(self, measurements: Path | None = None, tracks: Path | None = None) -> tuple[int, int]:
        """Write the replay-format measurements and tracks (see the module docstring); returns the line counts."""
        with _read_of(self.path):
            if self.count(TrackPicture):
                return self._export_pictures(measurements, tracks)
            return (_write_lines(measurements, (measurement_to_replay(m) for m in self.messages(Measurement, "t, id"))),
                    _write_lines(tracks, (_track_row(f) for f in self.messages(FusedTrack, "seq"))))

    def export_tracker_tracks(self, path: Path) -> int:
        """Write the single-sensor trackers' tracks (``tracker_tracks``) to ``path`` in the replay output format,
        in arrival order; returns the line count (0 of a recording without the table)."""
        with _read_of(self.path):
            rows = self.messages(TRACKER_TRACKS, "id") if self.count(TRACKER_TRACKS) else iter(())
            return _write_lines(path, (track_to_replay(f) for f in rows))

    def _export_pictures(self, measurements: Path | None, tracks: Path | None) -> tuple[int, int]:
        """A multi-target recording in one pass over the pictures (each decoded once): a picture's
        scans and departures to ``measurements`` in the centre's order, the picture to ``tracks``;
        then the recorded scans no picture lists to ``unprocessed.jsonl``, in arrival order. A
        scan is decoded when a picture lists it (a few recent ones kept), not held all at once."""
        rowid: dict[tuple[str, int], int] = {}  # a scan's row; of a scan in parts the last part's (all in)
        for i, sensor, seq, parts, n in self.db.execute(
                f"SELECT MAX(id), sensor, seq, {'MAX(parts)' if self.version > 1 else 1}, COUNT(*) FROM measurements "
                "GROUP BY sensor, seq ORDER BY MAX(id)"):
            if parts == n:
                rowid[(sensor, seq)] = i
            else:
                self.incomplete += 1
        used: set[int] = set()

        @functools.lru_cache(maxsize=SCANS_KEPT)
        def scan_line(i: int) -> dict[str, Any] | None:
            msg = self._message(Measurement, i)
            return None if msg is None else measurement_to_replay(msg)

        counts = [0, 0]

        def write(k: int, fh: IO[str] | None, row: dict[str, Any]) -> None:
            if fh is not None:
                fh.write(_line(row))
                counts[k] += 1

        try:
            with contextlib.ExitStack() as files:
                m_out, t_out = (None if path is None else files.enter_context(output_file(path))
                                for path in (measurements, tracks))
                for pic in self.messages(TrackPicture, "seq"):
                    # the positions as sets: a picture's tuples looked up for each of its up to 131,072 entries
                    # took minutes (32,768 departures and 32,768 restarts: 160 s for one picture, tour47)
                    left, restarted, handovers = set(pic.left), set(pic.restarted), set(pic.handovers)
                    began = dict(zip(pic.began, pic.began_serials))
                    for i, key in enumerate(zip(pic.fused_sensors, pic.fused_seqs)):
                        # a region run's merged picture: every entry of every region, tagged with it
                        # (a hand-over's entry names its sending region and its number: docs/multitarget.md#regions)
                        tag = {"region": pic.regions[i]} if pic.regions else {}
                        if i in left:
                            write(0, m_out, {"t": pic.t, "sensor": key[0], "left": True, **tag})
                        elif i in restarted:  # the sensor's tracker started afresh with its report key[1]
                            write(0, m_out, {"t": pic.t, "sensor": key[0], "restarted": True,
                                             **({"seq": key[1], **tag} if tag else {})})
                        elif i in handovers and tag:
                            write(0, m_out, {"t": pic.t, "handover": key[1], "from": key[0], **tag})
                        elif i in began and tag:  # the region's centre began afresh: its first numbers
                            write(0, m_out, {"t": pic.t, "began": True, "next_id": key[1], "serial": began[i], **tag})
                        elif (key in rowid and (tag or rowid[key] not in used)
                              and (line := scan_line(rowid[key])) is not None):
                            write(0, m_out, {**line, **({"seq": key[1], **tag} if tag else {})})
                            used.add(rowid[key])
                    if not pic.closing:
                        write(1, t_out, picture_to_replay(pic))
        except OSError as exc:
            raise InputError(f"{exc.filename}: cannot write: {exc.strerror or exc}") from None
        if measurements is not None:
            _write_lines(measurements.with_name("unprocessed.jsonl"),
                         (line for i in sorted(rowid.values()) if i not in used and (line := scan_line(i)) is not None))
        return counts[0], counts[1]

    def _message(self, msg_type: type, rowid: int) -> Any:
        """The stored message of ``msg_type`` in row ``rowid``; a part there: its message joined
        from every row of its unique key (None when they do not join)."""
        table = TABLE_OF[msg_type]
        msg = self._row(table, rowid)
        if getattr(msg, "parts", 1) == 1:
            return msg
        key = [c for c in table.unique if c != "part"]
        rows = self.db.execute(f"SELECT id, payload FROM {table.name} WHERE {' AND '.join(f'{c} = ?' for c in key)}",
                               tuple(getattr(msg, c) for c in key))
        return self._joined([_decoded(self.path, table, i, p) for i, p in rows])

    def _row(self, table: Table, rowid: int) -> Any:
        """The message (or part) stored in row ``rowid`` of ``table``."""
        payload = self.db.execute(f"SELECT payload FROM {table.name} WHERE id = ?", (rowid,)).fetchone()[0]
        return _decoded(self.path, table, rowid, payload)

    def close(self) -> None:
        self.db.close()


def _line(row: dict[str, Any]) -> str:
    """``row`` as one JSON line, by orjson (the values of decoded messages are finite: the wire
    rejects NaN and infinity, which orjson would write as null); 8x json's speed."""
    return orjson.dumps(row, option=orjson.OPT_APPEND_NEWLINE).decode()


def _decoded(path: Path, table: Table, rowid: int, payload: bytes) -> Any:
    """Row ``rowid``'s payload decoded; a row that does not decode is an input error naming it."""
    try:
        return decode(bytes(payload), table.msg_type)
    except WireError as exc:
        raise InputError(f"{path}: {table.name} row {rowid}: {exc}") from None


def _write_lines(path: Path | None, rows: Iterator[dict[str, Any]]) -> int:
    """``rows`` as JSON Lines, written whole or not at all (:func:`output_file`); 0 when ``path`` is None."""
    if path is None:
        return 0
    n = 0
    try:
        with output_file(path) as fh:
            for row in rows:
                fh.write(_line(row))
                n += 1
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return n


def _track_row(track: FusedTrack) -> dict[str, Any]:
    """``track_to_replay`` with ``event`` always present (null when the scan took no maneuver decision),
    as the fusion replay writes it."""
    row = track_to_replay(track)
    row.setdefault("event", None)
    return row


def main(argv: list[str]) -> int:
    """``fedtrack export``: a recording's measurements (and tracks) as replayable JSON Lines."""
    parser = argparse.ArgumentParser(prog="fedtrack export",
                                     description="write a recording's measurements as replay input (JSON Lines)",
                                     epilog="fedtrack export --geojson OUT.geojson --config C.toml [--tracks T.jsonl] "
                                            "[--truth U.jsonl] writes track pictures and truth on the Earth as "
                                            "GeoJSON instead (fedtrack export --geojson X --help)")
    parser.add_argument("--db", required=True, type=Path, metavar="PATH",
                        help="recording database (fedtrack serve recorder --db)")
    parser.add_argument("--out", required=True, type=Path, metavar="FILE.jsonl",
                        help="measurements, replay input format (its folder must exist); of a multi-target "
                        "recording, the scans no picture lists also go to unprocessed.jsonl beside it")
    parser.add_argument("--tracks", type=Path, metavar="FILE.jsonl", help="also write the fused tracks, or the "
                        "multi-target pictures, here (replay output format; default: the measurements only)")
    parser.add_argument("--tracker-tracks", type=Path, metavar="FILE.jsonl", help="also write the single-sensor "
                        "trackers' tracks (serve imm, serve hpda) here, in arrival order (replay output format, model "
                        "the tracker's algorithm; default: not written)")
    args = parser.parse_args(argv)
    check_outputs({"--out": args.out, "--tracks": args.tracks, "--tracker-tracks": args.tracker_tracks,
                   "unprocessed.jsonl beside --out": args.out.with_name("unprocessed.jsonl")}, {"--db": args.db})
    recording = Recording(args.db, readonly=True)
    try:
        n_meas, n_tracks = recording.export(args.out, args.tracks)
        unit = "pictures" if recording.count(TrackPicture) else "tracks"
        n_tracker = None if args.tracker_tracks is None else recording.export_tracker_tracks(args.tracker_tracks)
    finally:
        recording.close()
    print(f"wrote {n_meas} measurements to {args.out}" + (f", {n_tracks} {unit} to {args.tracks}" if args.tracks
                                                           else "")
          + (f", {n_tracker} single-sensor tracker tracks to {args.tracker_tracks}" if n_tracker is not None else "")
          + (f", the scans no picture lists to {args.out.with_name('unprocessed.jsonl')}" if unit == "pictures"
             else ""))
    return 0
