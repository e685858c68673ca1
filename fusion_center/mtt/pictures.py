"""The multi-target centres' picture messages: a picture's tracks as a ``TrackPicture`` and back
(:func:`picture_message`, :func:`picture_tracks`; a region centre's, the merger's and the one
centre's), how many tracks and fused entries one picture carries (``PICTURE_ITEMS``), and how many
region pictures a region centre keeps for a restarted merger (:func:`picture_window`)."""

from __future__ import annotations

import math
import time

import numpy as np

from fedtrack.fusion_center.mtt.engines import PictureTracks
from fedtrack.wire import MAX_PARTS, MAX_TRACKS, TrackPicture

# tracks, and entries of the fused lists, one picture can carry: MAX_PARTS messages of MAX_TRACKS each. A
# centre takes at most PICTURE_ITEMS - MAX_LIST_ITEMS reports, scans and hand-overs between two pictures
# (room left for the departures of its 64 live sensors; more are rejected too_large: a real period holds
# hundreds, 64 sensors at 10 Hz are 640), so that every picture can be sent: before, 131,073 reports
# within one picture period (a sensor counting its reports microseconds apart) made the picture
# unpublishable, and every report after them was rejected with it
PICTURE_ITEMS = MAX_PARTS * MAX_TRACKS
# A restarted ``serve picture`` merges the region pictures of its outage from the region centres' caches
# (docs/deploy.md, "serve picture dies"): the launcher has it back within about RESTART_WINDOW_S (three
# restarts: backoffs 0.5 + 1 + 2 s and a start of about 2 s each, as the recorder's publishing.CACHE_BYTES), and
# when it died it may have held a picture time for up to MERGE_WAIT_S (its --wait) waiting for a region
RESTART_WINDOW_S = 10.0
MERGE_WAIT_S = 2.0


def picture_window(period: float, speed: float) -> int:
    """The region pictures a region centre keeps for a restarted merger: those of the last
    RESTART_WINDOW_S + MERGE_WAIT_S seconds of wall time at ``speed`` times real time (its pictures
    come every ``period`` scenario seconds), and one more being merged."""
    return math.ceil((RESTART_WINDOW_S + MERGE_WAIT_S) * speed / period) + 1


def picture_message(seq: int, T: float, tracks: PictureTracks, order: list[tuple[str, int]], left: list[int],
                    contested: bool, closing: bool = False, handovers: list[int] | tuple[int, ...] = (),
                    regions: tuple[str, ...] = (), earth: tuple[np.ndarray | None, tuple[bool, ...]] = (None, ()),
                    flying: dict[int, float] | None = None,
                    restarted: list[int] | tuple[int, ...] = (), missing: tuple[str, ...] = (),
                    began: tuple[tuple[int, int], ...] = ()) -> TrackPicture:
    """The ``TrackPicture`` of ``tracks`` at ``T``, listing the entries ``order`` processed since the
    previous one (``left``, ``handovers``, ``restarted``: the positions that are departures, hand-overs
    taken over and trackers restarted; ``regions``: each entry's region, in a merged picture; ``earth``:
    the tracks on the Earth and whether their altitudes were measured (``fedtrack.geodetic.picture_geodetic``);
    ``flying``: the ids of a region centre's copies of tracks it handed over, with the hand-overs' times;
    ``missing``: the regions a merged picture lacks; ``began``: (position, first hand-over number) where a
    region's centre began afresh, its first track id that entry's seq)."""
    d = tracks.x.shape[1]
    ca = tuple(model == "ca" for model in tracks.models)
    maneuvering = tracks.maneuver_rows()
    return TrackPicture.unchecked(
        seq=seq, t=T, ids=tuple(tracks.ids), x=tracks.x, P=tracks.P.reshape(-1, d),
        confirmed=tuple(tracks.confirmed), sensors=tuple(tuple(s) for s in tracks.sensors),
        fused_sensors=tuple(s for s, _ in order), fused_seqs=tuple(q for _, q in order),
        stamp_ns=time.time_ns(), closing=closing, left=tuple(left), ca=ca if any(ca) else (),
        maneuvering=tuple(maneuvering), maneuver=None if tracks.maneuver is None else tracks.maneuver[maneuvering],
        contested=contested, existence=None if tracks.existence is None else np.array(tracks.existence), lla=earth[0],
        alt_measured=earth[1],
        handovers=tuple(handovers), regions=regions,
        in_flight=tuple(k for k, i in enumerate(tracks.ids) if flying and i in flying),
        in_flight_t=tuple(flying[i] for i in tracks.ids if flying and i in flying), restarted=tuple(restarted),
        missing=missing, began=tuple(i for i, _ in began), began_serials=tuple(s for _, s in began))


def picture_tracks(msg: TrackPicture) -> PictureTracks:
    """The tracks of a ``TrackPicture`` (inverse of :func:`picture_message`'s)."""
    n, d = len(msg.ids), msg.x.shape[1]
    maneuver = None
    if msg.maneuver is not None:
        maneuver = np.full((n, 4), np.nan)
        maneuver[list(msg.maneuvering)] = msg.maneuver
    models = ["ca" if ca else "cv" for ca in msg.ca] if msg.ca else ["cv"] * n
    return PictureTracks(list(msg.ids), np.array(msg.x), np.array(msg.P).reshape(n, d, d), list(msg.confirmed),
                         [list(s) for s in msg.sensors], models, maneuver,
                         None if msg.existence is None else msg.existence.tolist())
