"""The track-to-track fusion centre (``mtt-federated``, ``mtt-decentralized``): its state, fusion,
feedback and hand-over (:mod:`.track_to_track`), the association of local tracks with central tracks
and the duplicate merge (:mod:`.association`), the life rules (:mod:`.track_life`), the search for
candidate pairs of the chi-square test (:mod:`.candidates`), and each sensor's consistency test
against the others (:mod:`.consistency`)."""

from fedtrack.fusion_center.mtt.centre.track_to_track import Counters, HandOver, TrackToTrackCentre

__all__ = ["Counters", "HandOver", "TrackToTrackCentre"]
