"""``fedtrack replay --algorithm pda-ai|hpda``: the track manager over recorded sonar scans.

Input (JSON Lines, one scan a line; ``z`` (empty), ``kind``, ``seq``, ``stamp_ns`` and ``truth``
may be present and are ignored; any other field is an error naming ``file:line``)::

    {"t": float, "sensor": str, "detections": [{"z": [x, y], "amplitude": a}, ...], "R": [[..]]}

Output, one line per live track per scan plus one line when a track is deleted::

    {"t", "sensor", "track", "x" (CA order), "P", "existence", "status"}

``status`` is ``tentative``, ``confirmed`` or ``deleted``. Detections weaker than the
tracker's threshold ``tau = -(1 + snr) ln(pd)`` are ignored (the amplitude model holds
above it only). A scan at the time of its sensor's last scan taken is left out and counted, as
``serve hpda`` rejects it (``time_jump``: :class:`~fedtrack.jsonl.RepeatedTimes`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Iterator, NamedTuple

import numpy as np

from fedtrack.config import ConfigError
from fedtrack.deployment import max_time_jump
from fedtrack.jsonl import (
    SONAR_FIELDS,
    InputError,
    NumericalRefusals,
    RepeatedTimes,
    as_covariance,
    as_float,
    as_vector,
    check_fields,
    output_file,
    read_jsonl,
    require,
)
from fedtrack.local_filters.pda.config import load_config
from fedtrack.local_filters.pda.tracks import (
    ScanReport,
    TrackerSpec,
    TrackSet,
    initial_manager,
    manager_step,
    tracker_spec,
)
from fedtrack.services.rejections import NUMERICAL_ERRORS, Numerical, require_covariances, require_finite


class Scan(NamedTuple):
    """One validated input line."""

    t: float
    sensor: str
    z: np.ndarray  # (M, 2)
    amplitude: np.ndarray  # (M,)
    R: np.ndarray  # (2, 2)


def parse_scan(obj: dict[str, Any], where: str) -> Scan:
    """Validate one line: known fields, finite numbers, shapes, symmetric PD ``R``, positive amplitudes."""
    check_fields(obj, SONAR_FIELDS, "sonar", where)
    t = as_float(require(obj, "t", where), "t", where)
    sensor = require(obj, "sensor", where)
    if not isinstance(sensor, str) or not sensor:
        raise InputError(f"{where}: sensor must be a non-empty string, got {sensor!r}")
    dets = require(obj, "detections", where)
    if not isinstance(dets, list):
        raise InputError(f"{where}: detections must be a list")
    z = np.zeros((len(dets), 2))
    amp = np.zeros(len(dets))
    for i, d in enumerate(dets):
        name = f"detections[{i}]"
        if not isinstance(d, dict):
            raise InputError(f"{where}: {name} must be an object with z and amplitude")
        z[i] = as_vector(require(d, "z", f"{where}: {name}"), f"{name}.z", where, size=2)
        amp[i] = as_float(require(d, "amplitude", f"{where}: {name}"), f"{name}.amplitude", where)
        if amp[i] <= 0.0:
            raise InputError(f"{where}: {name}.amplitude must be positive, got {amp[i]}")
    R = as_covariance(require(obj, "R", where), "R", where, size=2)
    return Scan(t, sensor, z, amp, R)


def read_scans(path: Path) -> Iterator[Scan]:
    """Validated scans with non-decreasing timestamps; errors name ``file:line``."""
    last = -np.inf
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        s = parse_scan(obj, where)
        if s.t < last:
            raise InputError(f"{where}: t = {s.t} is earlier than the previous scan's {last}")
        last = s.t
        yield s


def _rows(t: float, sensor: str, tracks: TrackSet, status: np.ndarray) -> list[dict[str, Any]]:
    return [{"t": t, "sensor": sensor, "track": int(tracks.ids[i]), "x": tracks.state.x[i].tolist(),
             "P": tracks.state.P[i].tolist(), "existence": float(tracks.existence[i]),
             "status": str(status[i])} for i in range(len(tracks))]


def report_rows(t: float, sensor: str, rep: ScanReport) -> list[dict[str, Any]]:
    """Output lines of one scan: live tracks, then the ones deleted by it."""
    live = np.where(rep.tracks.confirmed, "confirmed", "tentative")
    return (_rows(t, sensor, rep.tracks, live)
            + _rows(t, sensor, rep.deleted, np.full(len(rep.deleted), "deleted")))


STATUSES = ("all", "confirmed")


def run(spec: TrackerSpec, scans: Iterator[Scan], max_gap: float = np.inf,
        repeats: RepeatedTimes | None = None,
        numerical: NumericalRefusals | None = None) -> Iterator[dict[str, Any]]:
    """Track-manager output lines for a stream of scans. After a gap longer than ``max_gap``
    seconds the manager starts again: its tracks are reported deleted at the next scan. A scan at
    the time of its sensor's last one taken is left out, counted in ``repeats``; one whose tracks
    come out non-finite or not positive definite is left out with the manager kept, counted in
    ``numerical`` (as ``serve hpda`` rejects it, ``rejected_numerical``)."""
    ms, repeats = initial_manager(), RepeatedTimes() if repeats is None else repeats
    numerical = NumericalRefusals() if numerical is None else numerical
    for s in scans:
        if not repeats.taken(s.sensor, s.t):
            continue
        restart = ms.t is not None and s.t - ms.t > max_gap
        start = initial_manager()._replace(next_id=ms.next_id) if restart else ms
        keep = s.amplitude >= spec.c.tau
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # checked below
                after, rep = manager_step(spec, start, s.t, s.z[keep], s.amplitude[keep], s.R)
            require_finite("the tracks", rep.tracks.state.x, rep.tracks.state.P, rep.tracks.existence)
            require_covariances("the tracks", rep.tracks.state.P)
        except (Numerical, *NUMERICAL_ERRORS):
            repeats.refused(s.sensor, ms.t)
            numerical.left_out += 1
            continue
        if restart:
            yield from _rows(s.t, s.sensor, ms.tracks, np.full(len(ms.tracks), "deleted"))
        ms = after
        yield from report_rows(s.t, s.sensor, rep)


def replay_pda(algorithm: str, measurements: Path, config: Path | None, out: Path, status: str = "all") -> int:
    """Replay ``measurements`` with ``algorithm`` (``pda-ai`` or ``hpda``); returns lines written.

    ``status = "confirmed"`` writes the confirmed tracks only (and not the tentative or deleted ones).
    """
    if status not in STATUSES:
        raise ConfigError(f"--status: one of {', '.join(STATUSES)}, got {status!r}")
    cfg = load_config(config)
    spec = tracker_spec(algorithm, cfg.tracker, cfg.existence)
    n, repeats, numerical = 0, RepeatedTimes(), NumericalRefusals()
    with output_file(out) as fh:
        for row in run(spec, read_scans(measurements), max_time_jump(config), repeats, numerical):
            if status == "all" or row["status"] == status:
                fh.write(json.dumps(row) + "\n")
                n += 1
    print(repeats.line(algorithm, "scans", "time_jump"), file=sys.stderr)
    if numerical.left_out:
        print(numerical.line(algorithm, "scans"), file=sys.stderr)
    return n
