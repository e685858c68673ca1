"""What sensors joining and leaving did to a track-to-track run, measured on its recording.

The recorded scans, in the centre's processing order with its departures, replay to the live
pictures exactly (docs/multitarget.md), so the replay's centre is the live one. This module
replays them and looks inside it:

* a **joining** sensor: for each of its local tracks that came to share a central track with
  another sensor, the number of the joiner's own scans from the local track's first report to
  that association (1: associated on arrival); and how many of its confirmed local tracks never
  shared a central track (targets no other sensor tracked, or its false tracks);
* a **departure**: the central tracks that another sensor supported when the sensor was
  dropped, and those of them that were lost: gone once every remaining sensor has reported
  again, while a remaining sensor still holds the local track that supported it (a target that
  died, or a merge into another central track, is not a loss).
"""

from __future__ import annotations

from typing import NamedTuple

from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
from fedtrack.fusion_center.mtt.centre.association import LocalKey
from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
from fedtrack.geodetic import RadarSite
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import SensorLeft, SensorScan, TrackerRestarted


class Joined(NamedTuple):
    sensor: str
    first_t: float  # data time of its first scan
    scans_to_associate: list[int]  # per local track that came to share a central track
    never_associated: int  # its confirmed local tracks that never did


class Left(NamedTuple):
    sensor: str
    t: float  # data time of the last scan before the departure
    supported: int  # central tracks another sensor supported at the departure
    lost: list[int]  # of those, the ones lost (see the module docstring)


class _Departure(NamedTuple):
    left: Left
    support: dict[int, set[LocalKey]]  # central id -> the remaining sensors' keys mapped to it
    waiting: set[str]  # remaining sensors that have not reported since


def _shared(centre: TrackToTrackCentre, key: LocalKey) -> bool:
    cid = centre.mapping.get(key)
    return cid is not None and any(s != key[0] for s, _ in centre.members.get(cid, ()))


def _lost(engine: TrackToTrackEngine, support: dict[int, set[LocalKey]]) -> list[int]:
    centre = engine.centre
    assert centre is not None
    held = {(s, int(i)) for s, tr in engine.local.items() for i in tr.tracker.state.tracks.ids.tolist()}
    return sorted(cid for cid, keys in support.items()
                  if cid not in centre.tracks and any(k in held and centre.mapping.get(k) not in centre.tracks
                                                      for k in keys))


def membership(scans: list[SensorScan | SensorLeft | TrackerRestarted], cfg: MttConfig, dim: int, feedback: bool,
               joiners: set[str], sites: dict[str, RadarSite] | None = None) -> tuple[list[Joined], list[Left]]:
    """Replay ``scans`` (a recording's ``measurements.jsonl``, parsed) through the track-to-track
    engine (``sites``: the config's ``[frame.sites]``, as the live centre's) and measure the joins of
    ``joiners`` and every departure."""
    engine = TrackToTrackEngine(cfg, dim, feedback=feedback, sites=sites or {})
    done: dict[str, int] = {}  # scans of each joiner so far
    first_t: dict[str, float] = {}
    first_seen: dict[LocalKey, int] = {}
    delay: dict[LocalKey, int] = {}
    confirmed: set[LocalKey] = set()
    departures: list[_Departure] = []
    left: list[Left] = []
    last_t = float("nan")
    for item in scans:
        centre = engine.centre
        if isinstance(item, SensorLeft):
            support: dict[int, set[LocalKey]] = {}
            if centre is not None:
                for cid, keys in centre.members.items():
                    others = {k for k in keys if k[0] != item.sensor}
                    if others and cid in centre.tracks:
                        support[cid] = others
            engine.leave(item.sensor)
            remaining = set(engine.centre.sensor_seen) if engine.centre is not None else set()
            departures.append(_Departure(Left(item.sensor, last_t, len(support), []), support, remaining))
            continue
        if isinstance(item, TrackerRestarted):
            engine.restart(item.sensor)
            continue
        engine.ingest(item)
        last_t, s, centre = item.t, item.sensor, engine.centre
        assert centre is not None
        if s in joiners and s in engine.local:
            done[s] = done.get(s, 0) + 1
            first_t.setdefault(s, item.t)
            tracks = engine.local[s].tracker.state.tracks
            for lid, conf in zip(tracks.ids.tolist(), tracks.confirmed.tolist()):
                key = (s, int(lid))
                first_seen.setdefault(key, done[s])
                if conf:
                    confirmed.add(key)
                if key not in delay and _shared(centre, key):
                    delay[key] = done[s] - first_seen[key] + 1
        for dep in list(departures):
            dep.waiting.discard(s)
            if not dep.waiting:
                left.append(dep.left._replace(lost=_lost(engine, dep.support)))
                departures.remove(dep)
    left += [dep.left._replace(lost=_lost(engine, dep.support)) for dep in departures if engine.centre is not None]
    joined = [Joined(s, first_t[s], [delay[k] for k in sorted(delay) if k[0] == s],
                     sum(1 for k in confirmed if k[0] == s and k not in delay)) for s in sorted(first_t)]
    return joined, left
