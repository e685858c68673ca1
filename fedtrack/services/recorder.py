"""``fedtrack serve recorder --db PATH [--out DIR]``: record a deployment durably in SQLite.

Every measurement, local estimate, fused track, maneuver event and multi-target picture
is a row of the database (schema and durability: :mod:`fedtrack.recording`), committed before the next
message is handled, so a SIGKILL loses nothing that was committed. The recorder
subscribes with ``zenoh.ext`` advanced subscribers (history + recovery): restarted on
the same database it receives what the publishers still hold in their caches (what
was published while it was down) and stores each message once (a redelivered copy is
counted in ``duplicate``, a different message with the same key in ``conflict``, its first of each sensor
also said in the log: before the tour59 session only the counter held them).

With ``--out DIR`` it writes, on a clean stop, ``DIR/measurements.jsonl`` (replay
input, scan order) and ``DIR/tracks.jsonl`` (replay output) from the database, as
``fedtrack export`` does; ``--db`` defaults to ``DIR/recording.db``. It publishes only
its Health (counters ``<table>_recorded``, ``duplicate``, ``conflict``). A row the database cannot
take (the disk full, the file size limit, the file made unwritable) stops it at once, exit 1, with
one line naming the database and the reason: restarted by the launcher, it recovers from the
publishers' caches what it had not stored (before 2026-11-27 it rejected every later message and
exited 0, the run's recording silently cut short).
"""

from __future__ import annotations

from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any, Iterator

from fedtrack.deployment import deployment_of
from fedtrack.jsonl import check_output, check_output_folder
from fedtrack.recording import CONFLICT, DB_NAME, RECORDED, TABLES, Recording, StorageError, Table
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.dispatch import ServiceFault
from fedtrack.services.rejections import Rejected
from fedtrack.wire import Message, TrackPicture


@contextmanager
def storage_faults() -> Iterator[None]:
    """The database failing (:class:`StorageError`) ends the recorder: a :class:`ServiceFault`."""
    try:
        yield
    except StorageError as exc:
        raise ServiceFault(str(exc)) from None


def _check_track_id(msg: Any) -> None:
    """A tracker's track (``serve hpda``'s ``extra["track"]``, a whole number; none: an IMM's one track) whose
    id the table's integer column can hold; anything else is refused (``rejected_track``), before a hostile
    ``""`` or ``1e80`` failed the handler (test_fuzz_services)."""
    track = msg.extra.get("track", -1)
    if isinstance(track, bool) or not isinstance(track, (int, float)) or not abs(track) <= 2**53 \
            or track != int(track):
        raise Rejected("track", f"extra.track must be a whole number within 2^53, got {track!r}")


class Recorder(Service):
    """Subscribes to the measurements, estimates, fused tracks, events, pictures and the single-sensor trackers'
    tracks; stores them in SQLite."""

    role = "recorder"
    tick_period_s = 1.0  # how often it checks that its database file is still the one it writes (check_file)
    # stopped, it commits every row it still holds (a row an fsync): at CI load 11 the base's 2 s left a
    # third of a lockstep run's fused tracks unrecorded, with exit 0; the launcher's recorder grace outlasts this
    drain_deadline_s = 15.0

    def __init__(self, db: Path, out: Path | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.db_path = db
        self.out = out
        self.recording: Recording | None = None
        self.conflicted: set[str] = set()  # senders whose conflicts were said (the first of each)

    def subscriptions(self) -> list[Subscription]:
        keys = {"measurements": self.keys.sensor_meas(), "estimates": self.keys.local_estimate(),
                "tracks": self.keys.fusion_track(), "events": self.keys.fusion_event(),
                "pictures": self.keys.mtt_picture(), "tracker_tracks": self.keys.tracker_track()}
        return [Subscription(keys[t.name], t.msg_type, partial(self.on_message, t), history=True, raw=True)
                for t in TABLES]

    def on_start(self) -> None:
        if self.out is not None:
            self.out.mkdir(parents=True, exist_ok=True)
        self.recording = Recording(self.db_path)
        for table in TABLES:
            self.counters[f"{table.name}_recorded"] = self.recording.count(table)
        self.log.info("recording to %s", self.db_path)

    def on_message(self, table: Table, msg: Message, payload: bytes) -> None:
        """Store ``msg`` in ``table``, the table of the key it came on."""
        assert self.recording is not None
        if table.name == "tracker_tracks":
            _check_track_id(msg)
        with storage_faults():
            outcome = self.recording.add(msg, payload, table)
        if outcome == RECORDED:
            self.count(f"{table.name}_recorded")
            return
        self.count(outcome)
        sender = getattr(msg, "sensor", table.name)
        if outcome == CONFLICT and sender not in self.conflicted:  # said once a sender: a flood fills no log
            self.conflicted.add(sender)
            self.log.warning("%s %s %s: a different message than the one recorded under its number, not stored (the "
                             "first stays; a sensor restarted by hand numbers its scans from 0 again: give it "
                             "--start-at, the first start's time, to resume; counter conflict)", table.name, sender,
                             getattr(msg, "seq", "-"))

    def on_tick(self) -> None:
        assert self.recording is not None
        with storage_faults():
            self.recording.check_file()

    def on_stop(self) -> None:
        if self.recording is None:
            return
        try:
            if self.out is not None:
                n_meas, n_tracks = self.recording.export(self.out / "measurements.jsonl", self.out / "tracks.jsonl")
                unit = "pictures" if self.recording.count(TrackPicture) else "tracks"  # as fedtrack export says
                self.log.info("wrote %d measurements and %d %s to %s", n_meas, n_tracks, unit, self.out)
        finally:
            self.recording.close()


def main(argv: list[str]) -> int:
    parser = service_parser("recorder", "record measurements, estimates, fused tracks and events in SQLite")
    parser.add_argument("--db", type=Path, help=f"recording database (default: OUT/{DB_NAME})")
    parser.add_argument("--out", type=Path, help="on a clean stop, write measurements.jsonl and tracks.jsonl here "
                        "(default: deployment.out of --config)")
    parser.add_argument("--config", type=Path, help="configuration file; reads [deployment] (name, connect, out; "
                        "default: none)")
    args = parser.parse_args(argv)
    if args.out is not None:  # given here, not [deployment] out (which is created whole): checked before connecting
        check_output_folder(args.out)
    if args.db is not None:
        check_output(args.db)
    kwargs = service_kwargs(parser, args)
    dep = deployment_of(args.config)
    out = args.out or (Path(dep.out) if dep is not None else None)
    if args.db is None and out is None:
        parser.error("--db or --out is required (or --config with a [deployment] table)")
    db = args.db if args.db is not None else out / DB_NAME
    return Recorder(db=db, out=out, **kwargs).run()
