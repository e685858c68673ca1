"""The associator interface of the multi-target tracker (:mod:`.tracker`): what ``gnn``,
``jipda`` and ``mht`` (``[mtt] associator``) each provide, and what the tracker gives them.

The tracker runs one scan as a chain of roles, each a pure function over the batched track set:
predict -> gate -> **associate** -> **update** -> initiate -> **confirm / delete**. The bold ones
come from the :class:`Associator`; the others are shared.

* ``associate(AssociationInput) -> Association`` (required). The input is the scan's gated
  (track, detection) pairs with each pair's log-likelihood ``ln N(nu_ij; 0, S_i)`` (the gate's
  ``d2``, ``ln det S`` and the ``m ln 2 pi`` term together), the tracks' confirmation and
  existence probability, the sensor's ``P_D`` and clutter density, the detections' amplitudes
  and the associator's own memory from the previous scan. The output lists the pairs that carry
  weight (indices into the gated pairs) with their association probabilities: a **hard**
  associator (``gnn``, the best global hypothesis of ``mht``) gives each track at most one pair,
  with weight 1; a **soft** one (``jipda``) gives the marginal probability ``beta_ij`` of each
  pair (``1 - sum_j beta_ij`` is the probability that the track was not detected). It also says
  which detections may not start a track (``claimed``; ``jipda`` claims a detection whose
  probability of being some track's exceeds its initiation threshold), the tracks' posterior
  existence probabilities (None: the associator does not keep existence), and the memory it
  wants back at the next scan (``mht``'s hypotheses; kept in the track order of ``rows``: the
  tracker does not reorder it, so an associator with memory keeps it by track id).
* ``update`` (optional; None: :func:`~.roles.filtering.hard_update`, the EKF update in Joseph form of
  each track by its one pair, the hard case). A soft associator gives its mixture update (the
  PDA combination with the spread-of-means term; ``local_filters/pda`` holds the single-target
  form): ``update(tracks, pred, gating, association, scan, dt, params, q_scale) ->
  roles.filtering.Updated`` (``tracks`` arrive with their modes predicted to the scan,
  :func:`~.roles.filtering.predict_tracks`; it returns the tracks with their posterior ``x``, ``P``
  and existence, which tracks to report as detected, and their linearized observations
  ``(H, R, z)`` for a fusion centre, in track order). ``gating`` is None when the scan or the track set is empty.
* ``step`` (optional; None: the chain above): an associator that predicts, gates and updates
  its own branches rather than the tracks (``mht``: each track's alternative histories) takes
  the whole scan, ``step(state, scan, params, q_scale) -> ScanResult``; its memory holds the
  branches and the tracker's tracks are its best global hypothesis's.
* ``manage`` (optional; None: :func:`~.roles.life.m_of_n`, M-of-N confirmation and deletion after
  ``delete_misses`` misses): ``manage(tracks, detected, params, sees) -> (tracks, live)``, the
  tracks with their counts after the scan and which stay (``sees``: in a tracker of several
  sensors' scans, what the scan shows of each track's place, :func:`~.roles.life.scan_sees`,
  else None; such a tracker counts a scan for a track only where its sensor detected the track or
  sees there: :func:`~.roles.life.scan_counts`); ``jipda`` confirms and deletes by existence thresholds
  (``tracks.existence``). A new track's existence is ``params.initial_existence``.

Everything is batched over the tracks (N), the detections (M) and the gated pairs (K); an
associator never sees a track or detection outside the gated pairs except through these arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np


class AssociationInput(NamedTuple):
    """What an associator gets for one scan."""

    n_tracks: int
    n_detections: int
    rows: np.ndarray  # (K,) track of each gated pair
    cols: np.ndarray  # (K,) detection of each gated pair
    log_likelihood: np.ndarray  # (K,) ln N(nu_ij; 0, S_i)
    dim: int  # measurement size m
    confirmed: np.ndarray  # (N,) bool
    existence: np.ndarray | None  # (N,) existence probabilities (None: not kept)
    pd: float
    clutter_density: float
    amplitude: np.ndarray | None  # (M,) detection amplitudes, if the scan carries them
    memory: Any = None  # the associator's memory after the previous scan
    gate_d2: float = float("inf")  # the chi-square gate of the scan's measurement size
    dt: float = 0.0  # time since the tracker's previous scan (existence prediction)
    # (N,) bool: the tracks the scan does not count for (its sensor never detected them, or they
    # left its radar's view, and it does not show it sees them; a tracker of several sensors'
    # scans; None: one sensor's): its miss is no evidence against them (roles.life.scan_counts,
    # roles.life.scan_sees)
    blind: np.ndarray | None = None


class Association(NamedTuple):
    """An associator's answer for one scan."""

    pairs: np.ndarray  # (L,) indices into the gated pairs that carry weight
    weight: np.ndarray  # (L,) association probability of each (1.0 for a hard associator)
    claimed: np.ndarray  # (M,) bool: detections that start no track
    existence: np.ndarray | None = None  # (N,) posterior existence probabilities
    memory: Any = None  # given back at the next scan
    birth: np.ndarray | None = None  # (M,) existence of a track started on each detection (None: initial_existence)


class Associator(NamedTuple):
    """An association method as the tracker's pluggable roles (see the module docstring)."""

    name: str
    associate: Callable[[AssociationInput], Association]
    update: Callable[..., Any] | None = None  # None: one pair per track, Joseph form
    manage: Callable[..., Any] | None = None  # None: M-of-N confirmation, deletion after misses
    step: Callable[..., Any] | None = None  # the whole scan instead of the chain (mht: its branches)
