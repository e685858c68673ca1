"""The records the local tracker's roles pass: its parameters for a scan (:class:`TrackParams`), the
live tracks, batched (:class:`TrackSet`), and what a detection says about its track, linearized
(:class:`Observation`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.geodetic import Frame
from fedtrack.local_filters.mtt import detector, maneuver
from fedtrack.local_filters.mtt.association import Associator
from fedtrack.local_filters.mtt.associators.gnn import GNN
from fedtrack.local_filters.mtt.config import MhtConfig
from fedtrack.local_filters.mtt.models import ModeRates, Modes
from fedtrack.local_filters.vdie.estimation import VdieParams, VdieState


class TrackParams(NamedTuple):
    """What one tracker needs per scan (built from ``[mtt]`` by :func:`..tracker.track_params`)."""

    dim: int
    q: float
    noise_model: str
    init_velocity_std: float
    init_z_std: float
    pd: float
    clutter_density: float
    gate: dict[int, float]
    confirm_hits: int
    confirm_window: int
    delete_misses: int
    maneuver: VdieParams | None = None  # per-track VDIE (2-D position trackers), None: CV only
    detector: VdieParams | None = None  # per-track maneuver events (3-D trackers), None: none
    associator: Associator = GNN
    initial_existence: float | None = None  # a new track's existence (associators that keep it)
    mht: MhtConfig | None = None  # [mtt.mht] (associator = "mht")
    modes: ModeRates | None = None  # two motion modes per track (process_noise = "imm"), None: CV with q
    # a tracker of several sensors' scans (mtt-centralized): the scan's sensor as a bit of
    # TrackSet.detected_by (0: one sensor's tracker, every scan counts), and the misses in a row
    # that delete a confirmed track: ``sensor_misses`` per sensor that detected it, at least
    # ``lone_misses``, at most ``delete_misses`` (:func:`.life.scan_counts`)
    sensor_bit: int = 0
    sensor_misses: int = 0
    lone_misses: int = 0
    max_speed: float = 0.0  # [m/s] two-point starts' speed bound (:mod:`..initiation`); 0: none
    frame: Frame | None = None  # [frame]: radars stand on the Earth, each with its own axes (:func:`.life.radar_view`)
    # the configured count and Wald's test on each scan's evidence confirm (:func:`.life.m_of_n`): mtt-centralized
    # gnn where a present sensor's clutter would raise the count (CentralizedEngine.params)
    weighed: bool = False


N_ARRAYS = 7  # TrackSet's per-track arrays before the optional per-track states


class TrackSet(NamedTuple):
    """Live tracks, batched: ``x`` (N, D), ``P`` (N, D, D) (with maneuver handling, the CV view
    of ``man``, every track's VDIE state: :mod:`fedtrack.local_filters.mtt.maneuver`; or, on a
    3-D tracker, ``inputs``, every track's maneuver detector: :mod:`..detector`; with an
    associator that keeps it, ``existence``, every track's existence probability; with
    ``process_noise = "imm"``, ``modes``, every track's two motion modes, of which ``x``, ``P``
    are the combination: :class:`~..models.Modes`; in a tracker of several sensors' scans,
    ``detected_by``, each track's sensors that detected it, as bits: :func:`.life.scan_counts`; and where
    the count rules its tracks (``gnn``), ``evidence``, each tentative track's Wald log-likelihood ratio since
    its start and the log of the tracks its scan started: :func:`.life.m_of_n`)."""

    ids: np.ndarray
    x: np.ndarray
    P: np.ndarray
    hits: np.ndarray
    age: np.ndarray  # scans since the start, the starting one included
    misses: np.ndarray  # consecutive misses
    confirmed: np.ndarray
    man: VdieState | None = None
    inputs: detector.TrackInputs | None = None
    existence: np.ndarray | None = None
    modes: Modes | None = None
    detected_by: np.ndarray | None = None  # (N,) int64
    evidence: np.ndarray | None = None  # (N, 2) float

    def take(self, idx: np.ndarray) -> TrackSet:
        """The tracks at ``idx`` (indices or a bool mask), every per-track state with them."""
        return TrackSet(*(a[idx] for a in self[:N_ARRAYS]),
                        None if self.man is None else maneuver.take(self.man, idx),
                        None if self.inputs is None else detector.take(self.inputs, idx),
                        None if self.existence is None else self.existence[idx],
                        None if self.modes is None else self.modes.take(idx),
                        None if self.detected_by is None else self.detected_by[idx],
                        None if self.evidence is None else self.evidence[idx])

    @property
    def models(self) -> list[str]:
        """Each track's motion model, ``"cv"`` or ``"ca"``."""
        if self.man is None:
            return ["cv"] * self.size
        return ["ca" if ca else "cv" for ca in self.man.is_ca.tolist()]

    @property
    def size(self) -> int:
        return int(self.ids.shape[0])


class Observation(NamedTuple):
    """What one detection says about its track, linearized: ``z ~ N(H x, R)`` (batched, K tracks).

    ``z = z_det - h(x0) + H x0`` at the linearization point ``x0``; exact for position sensors.
    """

    H: np.ndarray  # (K, m, D)
    R: np.ndarray  # (K, m, m)
    z: np.ndarray  # (K, m)


def empty_tracks(dim: int) -> TrackSet:
    """No tracks, of state dimension ``dim``."""
    return TrackSet(np.zeros(0, np.int64), np.zeros((0, dim)), np.zeros((0, dim, dim)), np.zeros(0, np.int64),
                    np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool))


def concat(a: TrackSet, b: TrackSet) -> TrackSet:
    """The tracks of ``a`` then ``b``, each per-track state joined (kept from the side that has tracks
    where the other's is None)."""
    extras = []  # the per-track states beside x, P (None on an empty side: its tracker had no tracks)
    for u, v, join in ((a.man, b.man, maneuver.concat), (a.inputs, b.inputs, detector.concat),
                       (a.existence, b.existence, lambda u, v: np.concatenate([u, v])),
                       (a.modes, b.modes, lambda u, v: Modes(*(np.concatenate([p, r]) for p, r in zip(u, v)))),
                       (a.detected_by, b.detected_by, lambda u, v: np.concatenate([u, v])),
                       (a.evidence, b.evidence, lambda u, v: np.concatenate([u, v]))):
        if u is None or v is None:
            extras.append(v if a.size == 0 else u if b.size == 0 else None)
        else:
            extras.append(join(u, v))
    return TrackSet(*(np.concatenate([u, v]) for u, v in zip(a[:N_ARRAYS], b[:N_ARRAYS])), *extras)
