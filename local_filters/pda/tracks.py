"""Track initiation, confirmation and deletion with IPDA-AI or HPDA existence (paper 001).

Pure functions over an immutable :class:`ManagerState`; every live track is updated in one
batched call (leading axis = tracks). Per scan:

1. every track is predicted (Singer model over the scan interval), gated and updated by
   its data association (PDA-AI or HPDA); its existence follows eq (8)/(9) (IPDA-AI) or
   eq (15)/(16) (HPDA);
2. a track whose existence exceeds ``confirm_threshold`` on ``confirm_scans`` consecutive
   updates, and whose evidence passes the false-track test below, is confirmed (with
   ``supported_streak`` only updates that raise its existence count, see below); one whose
   existence falls below ``delete_threshold`` is deleted; with ``one_track_per_detection``
   one detection supports one tentative track (:func:`shared_detection_losers`): the others
   are deleted;
3. detections outside the gates of all confirmed tracks are *unassociated*; pairs
   (unassociated detection of the previous scan, unassociated detection of this scan)
   closer than ``max_speed * dt`` plus the gated noise of their difference
   (:func:`birth_reach`) start tentative tracks by two-point differencing with
   existence ``initial_existence``, each detection in at most one pair (the pairing of
   least total distance, ``linear_sum_assignment``): a detection starts one hypothesis, not
   one per neighbour, so births grow with the clutter, not with its square;
4. at most ``max_tentative`` tentative tracks live: beyond that the least likely (lowest
   existence) are deleted, so that dense clutter cannot grow the track list without bound.

False-track test: a track's *evidence* is the sum, since its birth, of the log likelihood
ratio of eq (9) (amplitude-aided, all gated detections; for HPDA too). Under clutter alone its
exponential is a non-negative martingale of mean 1, so by Ville's inequality it ever reaches
``a`` with probability at most ``1/a``. A track born with ``B - 1`` others on its scan must
reach ``a = B / false_track_rate``: that scan's births then confirm at most
``false_track_rate`` clutter tracks on average, however dense the clutter. A target's
amplitudes give a likelihood ratio of ``e^10`` or more per detection at rho = 20, so the test
costs it little. The association also uses the larger of the configured clutter density and
the scans' own estimate (``clutter_from_scans``, :func:`scan_constants`): the bound needs the
clutter likelihood ratio to average 1. ``false_track_rate = 0``, ``one_track_per_detection =
false``, ``clutter_from_scans = false``, ``supported_streak = false`` and ``amplitude_existence = false`` give the
paper's rule alone.

Maneuver model: with ``[pda.tracker] max_accel`` > 0 every track runs an IMM of the paper's Singer model and
one of ``max_accel / sqrt(3)`` (:func:`_imm`); the paper's model alone loses a maneuver of ten times its
``sigma_a`` at the onset, and the tracks started again after it lose it too (docs/hpda.md).

Amplitude existence: the existence of an HPDA track follows eq (9)'s likelihood ratio, as IPDA-AI's does
(:func:`~fedtrack.local_filters.pda.association.scan_evidence`: every gated detection with its amplitude),
not eq (16)'s, which takes the selected detection's rank but not its amplitude and so raises a track that
caught one target detection to about 0.4 only (eq (9): 1.00). At P_D = 0.5, where three detections in a
row are rare, the paper's eq (16) confirmed the target 190 s later than IPDA-AI; with eq (9) HPDA confirms
it as IPDA-AI does. IPDA-AI's ratio is eq (9) already (the same number, to the bit).

Supported streak: the ``confirm_scans`` updates above ``confirm_threshold`` must each raise the
existence (eq (8): ``logit mu_k = log(1 - delta_k) + logit mu_bar``, so the update raises it iff the
scan's likelihood ratio exceeds 1); a miss while the existence stays above the threshold holds the
count. Without it, at low P_D a miss costs little (``1 - delta = 1 - P_D P_G``, 0.5 at P_D = 0.5):
a track that caught one target detection (its evidence then passes at once) stayed above the
threshold through the misses that followed and was confirmed while running away from the target.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from fedtrack.config import ConfigError
from fedtrack.local_filters.linear.kalman import GaussianState, logsumexp, predict, symmetrize
from fedtrack.local_filters.linear.models import LinearModel
from fedtrack.local_filters.pda.association import (
    ALGORITHMS,
    Constants,
    PDAParams,
    associate,
    candidates,
    constants,
    existence_update,
    gate,
    mahalanobis2,
    original_index,
    scan_evidence,
    singer_model,
    two_point_init,
)
from fedtrack.local_filters.pda.config import ExistenceConfig


class TrackerSpec(NamedTuple):
    """Everything fixed about a tracker: algorithm, its parameters and derived constants."""

    algorithm: str
    params: PDAParams
    existence: ExistenceConfig
    c: Constants


def tracker_spec(algorithm: str, params: PDAParams, existence: ExistenceConfig) -> TrackerSpec:
    if algorithm not in ALGORITHMS:
        raise ConfigError(f"algorithm: expected one of {ALGORITHMS}, got {algorithm!r}")
    return TrackerSpec(algorithm, params, existence, constants(params))


@functools.lru_cache(maxsize=256)
def _model(dt: float, sigma_a: float, tau_s: float) -> LinearModel:
    return singer_model(dt, sigma_a, tau_s)


class TrackSet(NamedTuple):
    """Tracks along a leading axis."""

    ids: np.ndarray  # (N,) int
    state: GaussianState  # (N, 6), (N, 6, 6)
    existence: np.ndarray  # (N,)
    streak: np.ndarray  # (N,) consecutive updates above the confirmation threshold
    confirmed: np.ndarray  # (N,) bool
    evidence: np.ndarray  # (N,) sum of eq (9) log likelihood ratios since birth
    evidence_needed: np.ndarray  # (N,) false-track test threshold on ``evidence``
    modes_x: np.ndarray = np.zeros((0, 0, 6))  # (N, r, 6) each Singer model's posterior (r = 0: one model)
    modes_P: np.ndarray = np.zeros((0, 0, 6, 6))  # (N, r, 6, 6)
    mode_prob: np.ndarray = np.zeros((0, 0))  # (N, r)

    def take(self, idx: np.ndarray) -> "TrackSet":
        return TrackSet(self.ids[idx], GaussianState(self.state.x[idx], self.state.P[idx]),
                        *(a[idx] for a in self[2:]))

    def __len__(self) -> int:  # type: ignore[override]
        return int(self.ids.shape[0])


def empty_tracks() -> TrackSet:
    return new_tracks(np.zeros(0, dtype=np.int64), GaussianState(np.zeros((0, 6)), np.zeros((0, 6, 6))),
                      0.0, -np.inf)


def new_tracks(ids: np.ndarray, state: GaussianState, existence: float,
               evidence_needed: float, models: int = 1) -> TrackSet:
    """Tentative tracks just born, with no streak and no evidence yet; with several Singer models each
    starts at the born state, all its probability on the first (the paper's) model."""
    n = ids.shape[0]
    r = 0 if models == 1 else models
    prob = np.zeros((n, r))
    prob[:, :1] = 1.0
    return TrackSet(ids, state, np.full(n, existence), np.zeros(n, dtype=np.int64),
                    np.zeros(n, dtype=bool), np.zeros(n), np.full(n, evidence_needed),
                    np.repeat(state.x[:, None], r, axis=1), np.repeat(state.P[:, None], r, axis=1), prob)


def join(a: TrackSet, b: TrackSet) -> TrackSet:
    if not len(a):  # (an empty set's model arrays may have another number of models)
        return b
    return TrackSet(np.concatenate([a.ids, b.ids]),
                    GaussianState(np.concatenate([a.state.x, b.state.x]),
                                  np.concatenate([a.state.P, b.state.P])),
                    *(np.concatenate([u, v]) for u, v in zip(a[2:], b[2:])))


class ManagerState(NamedTuple):
    """Live tracks, time of the last scan and its unassociated detections; the decayed sums of
    clutter counts and areas behind the scans' own clutter density estimate."""

    tracks: TrackSet
    t: float | None
    pending: np.ndarray  # (U, 2)
    next_id: int
    clutter_count: float = 0.0
    clutter_area: float = 0.0


CLUTTER_MEMORY = 0.8  # weight of the previous scans in the clutter density estimate
MIN_CLUTTER_SAMPLE = 20  # detections a scan needs to say something about the clutter density


def scan_clutter(z: np.ndarray) -> tuple[float, float]:
    """Clutter count and area of one scan: ``M - 1`` detections (one may be a target) over their
    bounding box, each side widened by ``(M + 1) / (M - 1)`` (the expected range of ``M``
    uniform points is ``(M - 1) / (M + 1)`` of the interval); ``(0, 0)`` for small scans."""
    m = z.shape[0]
    if m < MIN_CLUTTER_SAMPLE:
        return 0.0, 0.0
    sides = (np.max(z, axis=0) - np.min(z, axis=0)) * (m + 1) / (m - 1)
    return float(m - 1), float(np.prod(sides))


def scan_constants(spec: TrackerSpec, ms: ManagerState) -> Constants:
    """The association constants for the next scan: with ``clutter_from_scans`` the clutter
    density is the larger of the configured one and the scans' own estimate, so that a scene
    denser than configured cannot raise the likelihood ratios of clutter above 1 (which would
    void the false-track test and let clutter tracks confirm and live on)."""
    if not spec.existence.clutter_from_scans or ms.clutter_area <= 0.0:
        return spec.c
    return spec.c._replace(lam=max(spec.c.lam, ms.clutter_count / ms.clutter_area))


class ScanReport(NamedTuple):
    """Result of one scan: live tracks after the scan and those deleted by it."""

    tracks: TrackSet
    deleted: TrackSet
    newly_confirmed: np.ndarray  # (N,) bool over ``tracks``


def initial_manager() -> ManagerState:
    return ManagerState(empty_tracks(), None, np.zeros((0, 2)), 0)


class Updated(NamedTuple):
    """Tracks after one scan's update, with what the scan said about each."""

    tracks: TrackSet
    inside: np.ndarray  # (N, M) gate membership
    shared_losers: np.ndarray  # (N,) tentative tracks pruned by :func:`shared_detection_losers`


def shared_detection_losers(dominant: np.ndarray, evidence: np.ndarray, senior: np.ndarray) -> np.ndarray:
    """Tentative tracks whose dominant detection (association weight >= 1/2) is also another
    track's, where that other track ranks first: previously confirmed first, then the larger
    evidence (this scan's included). One detection supports one track, so a target's strong
    detections cannot confirm a swarm of tracks born around it."""
    strong = np.flatnonzero(dominant >= 0)
    order = strong[np.lexsort((-evidence[strong], ~senior[strong], dominant[strong]))]
    first = np.ones(order.size, dtype=bool)
    first[1:] = dominant[order][1:] != dominant[order][:-1]
    losers = np.zeros(dominant.shape[0], dtype=bool)
    losers[order[~first]] = True
    return losers & ~senior


class ScanTerms(NamedTuple):
    """What one scan's association gives every track, whatever its motion models."""

    post: GaussianState  # (N, 6) the (combined) posterior
    log_lr: np.ndarray  # (N,) the existence ratio: eq (9), or eq (16) for HPDA without amplitude_existence
    evidence_lr: np.ndarray  # (N,) eq (9)'s ratio, for the false-track test
    dominant: np.ndarray  # (N,) the detection holding half the association weight, -1 if none
    inside: np.ndarray  # (N, M) gate membership
    modes: tuple[np.ndarray, np.ndarray, np.ndarray]  # the models' posteriors and probabilities (r = 0: one)


def _scan_terms(spec: TrackerSpec, c: Constants, pred: GaussianState, z: np.ndarray, amplitude: np.ndarray,
                R: np.ndarray, H: np.ndarray) -> tuple[GaussianState, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gate, associate and update the predictions ``pred`` (K, 6): posterior, the existence ratio, eq (9)'s
    ratio, the dominant detection (an index of ``z``) and the gates' membership (K, M)."""
    index, valid = candidates(pred, z, H, R, c)
    aa = amplitude[index]
    g = gate(pred, z[index], valid, H, R, c)
    post, log_lr = associate(spec.algorithm, pred, g, aa, c)
    said = scan_evidence(g, aa, c)
    if spec.existence.amplitude_existence:  # HPDA too: eq (9)'s ratio of every gated detection and amplitude
        log_lr = said.log_lr
    inside = np.zeros((pred.x.shape[0], z.shape[0]), dtype=bool)
    rows, cols = np.nonzero(g.inside)
    inside[rows, index[rows, cols]] = True
    return post, log_lr, said.log_lr, original_index(said.dominant, index), inside


def _moments(w: np.ndarray, x: np.ndarray, P: np.ndarray) -> GaussianState:
    """The Gaussian matching the mixture of ``x`` (N, r, 6), ``P`` (N, r, 6, 6) with weights ``w`` (N, r)."""
    m = np.einsum("nr,nri->ni", w, x)
    d = x - m[:, None]
    return GaussianState(m, symmetrize(np.einsum("nr,nrij->nij", w, P + d[..., :, None] * d[..., None, :])))


def _single_model(spec: TrackerSpec, c: Constants, tracks: TrackSet, dt: float, z: np.ndarray,
                  amplitude: np.ndarray, R: np.ndarray) -> ScanTerms:
    """The paper's tracker: one Singer model."""
    model = _model(dt, spec.params.sigma_a, spec.params.tau_s)
    terms = _scan_terms(spec, c, predict(tracks.state, model.F, model.Q), z, amplitude, R, model.H)
    return ScanTerms(*terms, (tracks.modes_x, tracks.modes_P, tracks.mode_prob))


def _imm(spec: TrackerSpec, c: Constants, tracks: TrackSet, dt: float, z: np.ndarray,
         amplitude: np.ndarray, R: np.ndarray) -> ScanTerms:
    """An IMM of the Singer models of ``PDAParams.sigmas`` (IMM-PDA, Houles and Bar-Shalom 1989; IMM-IPDA,
    Musicki and Suvorova): each model stays with probability ``exp(-dt / tau_s)`` (the Singer correlation
    time), the others share the rest; mixing, each model's association, the model probabilities by eq (9)'s
    ratio of each (eq (16) is no likelihood ratio), the track's ratios the mixtures ``sum_m cbar_m L_m``."""
    sigmas = spec.params.sigmas
    n, r = len(tracks), len(sigmas)
    stay = np.exp(-dt / spec.params.tau_s)
    Pi = np.full((r, r), (1.0 - stay) / (r - 1))
    np.fill_diagonal(Pi, stay)
    cbar = tracks.mode_prob @ Pi
    live = cbar[:, None, :] > 0.0  # a model of probability 0 (dt = 0) keeps its own state
    mixing = np.where(live, tracks.mode_prob[:, :, None] * Pi[None] / np.where(live, cbar[:, None, :], 1.0),
                      np.eye(r)[None])  # (N, i, j)
    preds = []
    for j, sigma in enumerate(sigmas):
        model = _model(dt, sigma, spec.params.tau_s)
        preds.append(predict(_moments(mixing[:, :, j], tracks.modes_x, tracks.modes_P), model.F, model.Q))
    flat = GaussianState(np.stack([q.x for q in preds], 1).reshape(n * r, 6),
                         np.stack([q.P for q in preds], 1).reshape(n * r, 6, 6))
    post, log_lr, evidence_lr, dominant, inside = _scan_terms(spec, c, flat, z, amplitude, R, model.H)
    log_cbar = np.log(np.maximum(cbar, 1e-300))
    log_w = log_cbar + evidence_lr.reshape(n, r)
    log_l = logsumexp(log_w, axis=1)
    prob = np.exp(log_w - log_l[:, None])
    x, P = post.x.reshape(n, r, 6), post.P.reshape(n, r, 6, 6)
    best = np.argmax(prob, axis=1)
    return ScanTerms(_moments(prob, x, P), logsumexp(log_cbar + log_lr.reshape(n, r), axis=1), log_l,
                     dominant.reshape(n, r)[np.arange(n), best], inside.reshape(n, r, -1).any(axis=1),
                     (x, P, prob))


def _update_tracks(spec: TrackerSpec, c: Constants, tracks: TrackSet, dt: float, z: np.ndarray,
                   amplitude: np.ndarray, R: np.ndarray) -> Updated:
    """Predict, gate, associate and update every track, then confirm those that pass."""
    n = len(tracks)
    terms = (_imm if len(spec.params.sigmas) > 1 else _single_model)(spec, c, tracks, dt, z, amplitude, R)
    dominant, log_lr = terms.dominant, terms.log_lr
    evidence = tracks.evidence + terms.evidence_lr
    e = spec.existence
    losers = (shared_detection_losers(dominant, evidence, tracks.confirmed) if e.one_track_per_detection
              else np.zeros(n, dtype=bool))
    mu = existence_update(tracks.existence, log_lr, e.p11, e.p21)
    # a streak counts the updates that raise the existence (eq (8): log(1 - delta) > 0, the scan's data
    # support the track); with supported_streak a miss above the threshold holds the count, it adds nothing
    step = (log_lr > 0.0) if e.supported_streak else 1
    streak = np.where(mu > e.confirm_threshold, tracks.streak + step, 0)
    passed = (streak >= e.confirm_scans) & (evidence >= tracks.evidence_needed) & ~losers
    confirmed = tracks.confirmed | passed
    return Updated(TrackSet(tracks.ids, terms.post, mu, streak, confirmed, evidence, tracks.evidence_needed,
                            *terms.modes), terms.inside, losers)


def duplicates(tracks: TrackSet, senior: np.ndarray, R: np.ndarray, c: Constants) -> np.ndarray:
    """Confirmed tracks that duplicate a kept confirmed track: each position lies in the
    other's gate (mutual, so a diverged track with a huge gate prunes nothing).

    Confirmed tracks are kept greedily (previously confirmed first, then by existence).
    Tentative tracks are never pruned here: they cannot start inside a confirmed gate.
    """
    n = len(tracks)
    if not np.any(tracks.confirmed):
        return np.zeros(n, dtype=bool)
    pos = tracks.state.x[:, [0, 3]]
    S = tracks.state.P[:, [0, 3]][:, :, [0, 3]] + R
    diff = pos[None, :, :] - pos[:, None, :]  # (kept j, other i, 2)
    d2 = mahalanobis2(S[:, None], diff)
    mutual = (d2 <= c.gamma) & (d2.T <= c.gamma)
    dup = np.zeros(n, dtype=bool)
    order = np.lexsort((-tracks.existence, ~senior))
    for j in order[tracks.confirmed[order]]:
        if not dup[j]:
            near = mutual[j] & tracks.confirmed
            near[j] = False
            dup |= near
    return dup


def birth_reach(max_speed: float, dt: float, R: np.ndarray, gamma: float) -> float:
    """How far apart two detections ``dt`` apart may lie to start a track: ``max_speed * dt``
    plus the noise of their difference, ``n ~ N(0, 2R)``, at the gate probability.

    ``n' (2R)^-1 n <= gamma`` holds with probability P_G and implies
    ``|n| <= sqrt(gamma lambda_max(2R))``, so a target no faster than ``max_speed`` is paired
    with at least that probability at any scan rate. Paper 001 is silent; with its T = 25 s the
    speed term dominates (250 m beside 64 m), at 0.01 s the noise term (0.1 m beside 64 m)."""
    return max_speed * dt + float(np.sqrt(gamma * np.linalg.eigvalsh(2.0 * R)[-1]))


def pair_births(dist: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs (current, previous) within ``reach`` of least total distance."""
    close = dist <= reach
    rows, cols = np.flatnonzero(close.any(axis=1)), np.flatnonzero(close.any(axis=0))
    if not rows.size:
        return rows, cols
    sub = dist[np.ix_(rows, cols)]
    ri, ci = linear_sum_assignment(np.where(sub <= reach, sub, 1e12))
    ok = sub[ri, ci] <= reach
    return rows[ri[ok]], cols[ci[ok]]


def surplus_tentative(tracks: TrackSet, keep: np.ndarray, limit: int) -> np.ndarray:
    """Mask of the kept tentative tracks beyond the ``limit`` most likely ones."""
    tentative = np.flatnonzero(keep & ~tracks.confirmed)
    out = np.zeros(len(tracks), dtype=bool)
    if tentative.size > limit:
        order = tentative[np.argsort(-tracks.existence[tentative], kind="stable")]
        out[order[limit:]] = True
    return out


def manager_step(spec: TrackerSpec, ms: ManagerState, t: float, z: np.ndarray,
                 amplitude: np.ndarray, R: np.ndarray) -> tuple[ManagerState, ScanReport]:
    """Process one scan (detections ``z`` (M, 2), ``amplitude`` (M,), covariance ``R``)."""
    e = spec.existence
    c = scan_constants(spec, ms)
    dt = 0.0 if ms.t is None else float(t - ms.t)
    tracks = ms.tracks
    was_confirmed = tracks.confirmed
    claimed = np.zeros(z.shape[0], dtype=bool)
    losers = np.zeros(len(tracks), dtype=bool)
    if len(tracks):
        tracks, inside, losers = _update_tracks(spec, c, tracks, dt, z, amplitude, R)
        claimed = np.any(inside & tracks.confirmed[:, None], axis=0)
    newly = tracks.confirmed & ~was_confirmed
    keep = (tracks.existence >= e.delete_threshold) & ~losers
    keep &= ~duplicates(tracks, was_confirmed, R, c)
    keep &= ~surplus_tentative(tracks, keep, e.max_tentative)
    deleted = tracks.take(~keep)
    tracks, newly = tracks.take(keep), newly[keep]
    free = z[~claimed]
    if dt > 0.0 and len(ms.pending) and len(free):
        dist = np.linalg.norm(free[:, None, :] - ms.pending[None, :, :], axis=-1)
        i, j = pair_births(dist, birth_reach(e.max_speed, dt, R, c.gamma))
        if i.size:
            born = two_point_init(ms.pending[j], free[i], dt, R, spec.params.sigma_a)
            ids = ms.next_id + np.arange(i.size)
            tracks = join(tracks, new_tracks(ids, born, e.initial_existence, e.evidence_threshold(i.size),
                                             len(spec.params.sigmas)))
            newly = np.concatenate([newly, np.zeros(i.size, dtype=bool)])
            ms = ms._replace(next_id=ms.next_id + i.size)
    pending = free if dt > 0.0 or ms.t is None else np.concatenate([ms.pending, free])
    count, area = scan_clutter(z)
    return (ManagerState(tracks, float(t), pending, ms.next_id, CLUTTER_MEMORY * ms.clutter_count + count,
                         CLUTTER_MEMORY * ms.clutter_area + area),
            ScanReport(tracks, deleted, newly))
