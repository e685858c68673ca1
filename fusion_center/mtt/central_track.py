"""Central tracks as arrays, each with an out-of-sequence buffer: exact fusion in time order.

Every central track has a slot in a table of arrays. A slot keeps the observations its track
fused during the last ``max_lag`` seconds, each with the posterior after it, in a ring buffer
(oldest first; the oldest entry is the checkpoint: the posterior before the kept observations,
older ones folded into it). An observation at or after the newest is one batched prediction
and update over every such track of a report. An older one is inserted in time order and the
observations after it are fused again from the posterior before it (buffer and reprocess):
the result equals fusing the time-sorted observations, to round-off. An observation older than
``max_lag`` (or than the checkpoint) is late and not fused. Why this and not a retrodiction
method: see docs/multitarget.md.

The maths is :func:`predict_batch` and the Joseph-form :func:`update` (and, with a maneuver
detector, :func:`fedtrack.local_filters.vdie.input_bank.input_step`, whose bank is kept per entry as the posterior
is); this module only gathers their inputs from the slots and scatters the results back, so that
the centre's cost per report is a handful of array operations, not a walk over Python objects
per track.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, update
from fedtrack.local_filters.linear.tracking import rounded_interval
from fedtrack.local_filters.mtt.history import (
    MAX_ENTRIES,  # kept observations per central track (the ring's largest depth)
)
from fedtrack.local_filters.mtt.models import ModeRates, Modes, modes_predict, modes_update, predict_batch, start_modes
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.local_filters.vdie.input_bank import (
    InputBank,
    InputDetection,
    input_step,
    new_banks,
    no_detection,
)

# one step's result beside the posterior: the maneuver detector's banks and detection, if any
DetectorStep = tuple[InputBank, InputDetection] | None


class Later(NamedTuple):
    """The observations a re-fusion fuses again (:meth:`CentralTracks._later`): the tracks' ``rank``
    (most observations first), ``k[j]`` tracks in step ``j``, and per observation, step after step,
    its ring index after the move one position later (``moved``) and its fields ``t``, ``m``, ``H``,
    ``R``, ``z`` (padded to the ring's size)."""

    rank: np.ndarray
    k: list[int]
    moved: np.ndarray
    t: np.ndarray
    m: np.ndarray
    H: np.ndarray
    R: np.ndarray
    z: np.ndarray


def padded(a: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``a`` in the corner of a zero array of ``shape`` (each axis at least ``a``'s)."""
    if a.shape == shape:
        return a
    out = np.zeros(shape, a.dtype)
    out[tuple(slice(0, n) for n in a.shape)] = a
    return out


class CentralTracks:
    """The central tracks of dimension ``dim``: ids, confirmation, states and buffers by slot.

    Ring entry ``j`` (0 = oldest) of slot ``s`` is at ``(head[s] + j) % depth``; ``count[s]``
    entries are live. Per entry: time ``t``, posterior ``x``, ``P``, and the observation fused
    there (``m`` rows of ``H``, ``R``, ``z``; ``m = 0`` for a track's starting state). With a
    maneuver ``detector``, also the input estimator's bank after the entry (``bank_*``, the
    fields of :class:`InputBank`) and its detection (``det_*``). With two motion ``modes``
    (``process_noise = "imm"``), also each mode's posterior and probability (``mode_*``, the
    fields of :class:`Modes`); ``x``, ``P`` are then their combination. Every ring field is
    C-contiguous (made by ``np.zeros``, :func:`padded` or ``take_along_axis``), so that reshaping it
    to one axis of slots and entries is a view: :meth:`_at` reads and :meth:`_write` writes by one
    index ``slot * depth + position``.
    """

    def __init__(self, dim: int, q: float, noise_model: str, max_lag: float, capacity: int = 64, depth: int = 8,
                 detector: VdieParams | None = None, modes: ModeRates | None = None):
        self.dim, self.q, self.noise_model, self.max_lag, self.modes = dim, q, noise_model, max_lag, modes
        self.reprocessed = 0  # observations fused again after an older one was inserted before them
        self.detector = detector
        mmax = dim // 2  # a position (2 or 3) or a radar's (range, azimuth, elevation)
        self.slot: dict[int, int] = {}  # central track id -> slot
        self.free: list[int] = list(range(capacity - 1, -1, -1))
        self.ids = np.full(capacity, -1, dtype=np.int64)
        self.confirmed = np.zeros(capacity, dtype=bool)
        # when the track began and was confirmed (a picture at an earlier time shows it as it was then)
        self.since = np.zeros(capacity)
        self.confirmed_t = np.zeros(capacity)
        self.head = np.zeros(capacity, dtype=np.int64)
        self.count = np.zeros(capacity, dtype=np.int64)
        self.t = np.zeros((capacity, depth))
        self.x = np.zeros((capacity, depth, dim))
        self.P = np.zeros((capacity, depth, dim, dim))
        self.m = np.zeros((capacity, depth), dtype=np.int64)
        self.H = np.zeros((capacity, depth, mmax, dim))
        self.R = np.zeros((capacity, depth, mmax, mmax))
        self.z = np.zeros((capacity, depth, mmax))
        self._ring = self._RING
        if detector is not None:
            for name, a in zip(InputBank._fields, new_banks(capacity * depth, detector.window, dim, 0.0)):
                setattr(self, "bank_" + name, a.reshape((capacity, depth) + a.shape[1:]))
            for name, a in zip(InputDetection._fields, no_detection(capacity * depth)):
                setattr(self, "det_" + name, a.reshape((capacity, depth) + a.shape[1:]))
            self._ring += tuple("bank_" + n for n in InputBank._fields) + tuple(
                "det_" + n for n in InputDetection._fields)
        if modes is not None:
            self.mode_x = np.zeros((capacity, depth, 2, dim))
            self.mode_P = np.zeros((capacity, depth, 2, dim, dim))
            self.mode_mu = np.zeros((capacity, depth, 2))
            self._ring += tuple("mode_" + n for n in Modes._fields)

    _RING = ("t", "x", "P", "m", "H", "R", "z")
    _PER_SLOT = ("ids", "confirmed", "since", "confirmed_t", "head", "count")

    @property
    def capacity(self) -> int:
        return self.ids.shape[0]

    @property
    def depth(self) -> int:
        return self.t.shape[1]

    def __contains__(self, cid: object) -> bool:
        return cid in self.slot

    def __len__(self) -> int:
        return len(self.slot)

    def __iter__(self) -> Iterator[int]:
        """The ids of every track, increasing."""
        return iter(self.ids[self.live()].tolist())

    def live(self) -> np.ndarray:
        """The slots of every track, in increasing id (the order the tracks were started)."""
        slots = (self.ids >= 0).nonzero()[0]
        return slots[np.argsort(self.ids[slots], kind="stable")]

    def slots_of(self, cids: list[int] | np.ndarray) -> np.ndarray:
        """The slots of the live tracks ``cids``."""
        ids = cids.tolist() if isinstance(cids, np.ndarray) else cids
        return np.fromiter(map(self.slot.__getitem__, ids), dtype=np.int64, count=len(ids))

    def _grow(self, capacity: int, depth: int) -> None:
        """Re-allocate to ``capacity`` slots of ``depth`` entries (ring entries unrolled to 0..)."""
        old = self.capacity
        if depth != self.depth:
            order = (self.head[:, None] + np.arange(self.depth)) % self.depth
            for name in self._ring:
                a = getattr(self, name)
                setattr(self, name, np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1))
            self.head[:] = 0
        for name in self._ring:
            a = getattr(self, name)
            setattr(self, name, padded(a, (capacity, depth) + a.shape[2:]))
        for name in self._PER_SLOT:
            a = getattr(self, name)
            setattr(self, name, padded(a, (capacity,) + a.shape[1:]))
        self.ids[old:] = -1
        self.free = list(range(capacity - 1, old - 1, -1)) + self.free

    def start(self, cid: int, t: float, x: np.ndarray, P: np.ndarray) -> int:
        """A tentative track ``cid`` from the estimate ``(x, P)`` at ``t``; returns its slot."""
        if not self.free:
            self._grow(2 * self.capacity, self.depth)
        s = self.free.pop()
        self.slot[cid] = s
        self.ids[s], self.confirmed[s], self.head[s], self.count[s] = cid, False, 0, 1
        self.since[s], self.confirmed_t[s] = t, np.inf
        self.t[s, 0], self.x[s, 0], self.P[s, 0], self.m[s, 0] = t, x, P, 0
        if self.modes is not None:  # head 0: position 0
            for name, a in zip(Modes._fields, start_modes(x[None], P[None], self.modes)):
                getattr(self, "mode_" + name)[s, 0] = a[0]
        if self.detector is not None:
            self._write_detector(np.array([s * self.depth]),  # head 0: position 0
                                 (new_banks(1, self.detector.window, self.dim, t), no_detection(1)))
        return s

    def entries(self, cid: int) -> tuple[np.ndarray, ...]:
        """Track ``cid``'s live ring entries in time order, one array per field of ``_ring`` (the
        checkpoint first): its out-of-sequence buffer and maneuver detector, as a hand-over carries them."""
        s = self.slot[cid]
        order = self._pos(np.full(int(self.count[s]), s), np.arange(int(self.count[s])))
        return tuple(getattr(self, name)[s, order] for name in self._ring)  # indexing by ``order`` copies

    def ring_of(self, entries: tuple[np.ndarray, ...]) -> dict[str, np.ndarray]:
        """``entries`` (as :meth:`entries` gives them, or a hand-over carries them) by field name."""
        return dict(zip(self._ring, entries))

    def place(self, cid: int, confirmed: bool, entries: tuple[np.ndarray, ...]) -> int:
        """Track ``cid`` from another table's :meth:`entries` (a hand-over); returns its slot."""
        if not self.free:
            self._grow(2 * self.capacity, self.depth)
        count = entries[0].shape[0]
        if count > self.depth:
            self._grow(self.capacity, max(2 * self.depth, count))
        s = self.free.pop()
        self.slot[cid] = s
        self.ids[s], self.confirmed[s], self.head[s], self.count[s] = cid, confirmed, 0, count
        self.since[s], self.confirmed_t[s] = -np.inf, -np.inf if confirmed else np.inf  # as old as its owner's
        for name, a in zip(self._ring, entries):
            getattr(self, name)[s, :count] = a
        return s

    def as_of(self, slots: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
        """Which of the tracks ``slots`` existed at ``T`` (began by then: started, or fused an
        out-of-sequence observation, at or before ``T``) and which were confirmed by then: a picture
        made ``picture_delay`` after ``T`` shows the tracks as they were at ``T``."""
        began = np.minimum(self.since[slots], self.t[slots, self.head[slots]]) <= T
        return began, self.confirmed[slots] & (self.confirmed_t[slots] <= T)

    def merge_life(self, keep: int, drop: int) -> None:
        """Slot ``keep`` takes over slot ``drop``'s track (a duplicate merged into it): the earlier start
        and confirmation of the two."""
        self.confirmed[keep] |= self.confirmed[drop]
        self.since[keep] = min(self.since[keep], self.since[drop])
        self.confirmed_t[keep] = min(self.confirmed_t[keep], self.confirmed_t[drop])

    def delete(self, cid: int) -> None:
        s = self.slot.pop(cid)
        self.ids[s], self.count[s] = -1, 0
        self.free.append(s)

    def _pos(self, slots: np.ndarray, j: np.ndarray) -> np.ndarray:
        return (self.head[slots] + j) % self.depth

    def newest(self, slots: np.ndarray) -> np.ndarray:
        """The ring position of each slot's newest entry."""
        return (self.head[slots] + self.count[slots] - 1) % self.depth

    def newest_t(self, slots: np.ndarray) -> np.ndarray:
        """The time of each slot's newest observation."""
        return self.t[slots, self.newest(slots)]

    def latest(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time, state and covariance after each slot's newest observation."""
        p = self.newest(slots)
        return self._at("t", slots, p), self._at("x", slots, p), self._at("P", slots, p)

    def _newer_than(self, slots: np.ndarray, t: float | np.ndarray, or_at: bool = False) -> np.ndarray:
        """Per slot, how many live entries are newer than ``t`` (or at it, with ``or_at``): a suffix
        of the ring, whose entries are in time order."""
        rel = (np.arange(self.depth) - self.head[slots][:, None]) % self.depth
        live = rel < self.count[slots][:, None]
        times, t = self.t[slots], np.asarray(t).reshape(-1, 1)
        return np.count_nonzero(live & (times >= t if or_at else times > t), axis=1)

    def _entry_at(self, slots: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The ring position of each slot's newest entry up to ``t`` (the checkpoint if none): its
        newest entry, unless that is after ``t`` (an out-of-sequence time); and that entry's time."""
        p = self.newest(slots)
        t_p = self.t.reshape(-1)[slots * self.depth + p]
        after = (t_p > t).nonzero()[0]
        if after.size:
            s = slots[after]
            p[after] = self._pos(s, np.maximum(self.count[s] - 1 - self._newer_than(s, t), 0))
            t_p[after] = self.t[s, p[after]]
        return p, t_p

    def states_at(self, slots: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimates (N, D), (N, D, D) of ``slots`` at ``t`` from their observations up to ``t``
        (a track whose checkpoint is newer than ``t`` gives its checkpoint), one batched prediction."""
        p, t_p = self._entry_at(slots, t)
        dt = np.maximum(t - t_p, 0.0)
        if self.modes is not None:
            return modes_predict(self._modes_at(slots, p), dt, self.q, self.noise_model, self.modes)[1]
        return predict_batch(self._at("x", slots, p), self._at("P", slots, p), dt, self.q, self.noise_model)

    def _at(self, name: str, slots: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Ring field ``name`` at position ``p`` of each slot (a copy): one ``take`` over the flattened
        slot and ring axes, a third of indexing by ``[slots, p]`` at a thousand tracks."""
        a = getattr(self, name)
        return a.reshape((-1,) + a.shape[2:]).take(slots * self.depth + p, axis=0)

    def _modes_at(self, slots: np.ndarray, p: np.ndarray) -> Modes | None:
        if self.modes is None:
            return None
        return Modes(*(self._at("mode_" + n, slots, p) for n in Modes._fields))

    def _state_at(self, slots: np.ndarray, p: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The posterior at ring position ``p`` of each slot, which :meth:`_step` predicts from: with
        modes it predicts the modes, and their combination is not gathered (None, None)."""
        if self.modes is not None:
            return None, None
        return self._at("x", slots, p), self._at("P", slots, p)

    def maneuvers_at(self, slots: np.ndarray, t: float) -> InputDetection:
        """The maneuver detector's result after each slot's newest observation up to ``t`` (the
        entry :meth:`states_at` predicts from); no estimate without a detector."""
        if self.detector is None:
            return no_detection(slots.size)
        p = self._entry_at(slots, t)[0]
        return InputDetection(*(getattr(self, "det_" + n)[slots, p] for n in InputDetection._fields))

    def _bank_at(self, slots: np.ndarray, p: np.ndarray) -> InputBank | None:
        if self.detector is None:
            return None
        return InputBank(*(getattr(self, "bank_" + n)[slots, p] for n in InputBank._fields))

    def _step(self, t0: np.ndarray, x: np.ndarray | None, P: np.ndarray | None, t: float | np.ndarray, H: np.ndarray,
              R: np.ndarray, z: np.ndarray, bank: InputBank | None, modes: Modes | None = None,
              prior: tuple[np.ndarray, np.ndarray] | None = None
              ) -> tuple[np.ndarray, np.ndarray, DetectorStep, Modes | None]:
        """Posteriors after predicting each ``(x, P)`` (or its ``modes``) from ``t0`` to ``t`` and
        fusing ``(H, R, z)``, the maneuver detector's step from ``bank`` (None without a
        detector) and the modes after (None without; with them ``x``, ``P`` are not read).
        ``prior``: that prediction, when the caller made it (:meth:`states_at`; ``x``, ``P`` not read)."""
        # the interval (rounded here for the modes and the detector; predict_batch rounds its own)
        dt = t - t0 if modes is None and bank is None else rounded_interval(t - t0)
        if modes is None:
            if prior is not None:
                xp, Pp = prior
            else:
                assert x is not None and P is not None
                xp, Pp = predict_batch(x, P, dt, self.q, self.noise_model)
            post = update(GaussianState(xp, Pp), z, H, R)[0]
        else:
            pred, (xp, Pp) = modes_predict(modes, dt, self.q, self.noise_model, self.modes)
            modes, post = modes_update(pred, z - np.einsum("kmd,kd->km", H, xp), H, R, xp)
        return post.x, post.P, None if bank is None else input_step(bank, dt, xp, Pp, H, R, z, t), modes

    def _write(self, slots: np.ndarray, p: np.ndarray, t: float | np.ndarray, x: np.ndarray, P: np.ndarray,
               H: np.ndarray, R: np.ndarray, z: np.ndarray, step: DetectorStep, modes: Modes | None = None) -> None:
        """Ring position ``p`` of each slot: the observation ``(H, R, z)`` at ``t`` and the posterior
        (and detector step, and modes) after it."""
        self._write_at(slots * self.depth + p, t, x, P, H, R, z, step, modes)

    def _write_at(self, at: np.ndarray, t: float | np.ndarray, x: np.ndarray, P: np.ndarray, H: np.ndarray,
                  R: np.ndarray, z: np.ndarray, step: DetectorStep, modes: Modes | None = None) -> None:
        """:meth:`_write` by one index ``slot * depth + position`` over the flattened slot and ring axes."""
        self.t.reshape(-1)[at], self.m.reshape(-1)[at] = t, H.shape[1]
        for name, a in (("x", x), ("P", P), ("H", H), ("R", R), ("z", z)):
            ring = getattr(self, name)
            flat = ring.reshape((-1,) + ring.shape[2:])
            if a.shape[1:] == flat.shape[1:]:
                flat[at] = a
            else:  # a smaller observation in the first rows and columns
                flat[(at,) + tuple(slice(0, k) for k in a.shape[1:])] = a
        if step is not None:
            self._write_detector(at, step)
        for name, a in () if modes is None else zip(Modes._fields, modes):
            self._flat("mode_" + name)[at] = a

    def _flat(self, name: str) -> np.ndarray:
        """Ring field ``name`` with its slot and ring axes as one (a view)."""
        a = getattr(self, name)
        return a.reshape((-1,) + a.shape[2:])

    def _write_detector(self, at: np.ndarray, step: tuple[InputBank, InputDetection]) -> None:
        """The detector's banks and detection at ``at`` (:meth:`_write_at`'s index)."""
        for prefix, record in zip(("bank_", "det_"), step):
            for name, a in zip(record._fields, record):
                self._flat(prefix + name)[at] = a

    def _trim(self, slots: np.ndarray, t_newest: float | np.ndarray) -> None:
        """Fold the entries older than ``max_lag`` before each slot's newest (at ``t_newest``) into
        its checkpoint (the last entry before that horizon becomes the oldest); ``slots`` distinct."""
        head, count = self.head[slots], self.count[slots]
        live = (np.arange(self.depth) - head[:, None]) % self.depth < count[:, None]
        kept = np.count_nonzero(live & (self.t[slots] >= np.asarray(t_newest).reshape(-1, 1) - self.max_lag), axis=1)
        first = count - kept - 1  # the newest entry before the horizon is the checkpoint
        fold = (first > 0).nonzero()[0]
        if fold.size:
            s, f = slots[fold], first[fold]
            self.head[s] = (head[fold] + f) % self.depth
            self.count[s] = count[fold] - f

    def _room_for(self, entries: int) -> bool:
        """Make the ring hold ``entries`` per slot (doubling its depth at least); whether it grew
        (the ring positions then moved)."""
        if entries <= self.depth:
            return False
        self._grow(self.capacity, max(2 * self.depth, entries))
        return True

    def fuse(self, slots: np.ndarray, t: float, H: np.ndarray, R: np.ndarray, z: np.ndarray,
             prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fuse observation ``(H[i], R[i], z[i])`` (one size ``m``), taken at ``t``, into distinct
        ``slots[i]``; returns which were fused (False: late) and each posterior at ``t``.

        Each observation is fused in one batched step with the others: after its track's newest, or,
        for a track with newer ones, inserted before them; those are then fused again in time order
        from the posterior at ``t``, step by step over all those tracks at once (one batched
        prediction and update per step and observation size: :meth:`_refuse`). ``prior``: each slot's
        :meth:`states_at` ``t``, if the caller has it (without motion modes): the prediction the first
        step makes, not made again.
        """
        if H.shape[1] > self.H.shape[2]:
            raise ValueError(f"observations of size {H.shape[1]} in a {self.dim}-D central state")
        count = self.count[slots]
        if slots.size and count.max() >= MAX_ENTRIES:  # fold the oldest kept observation into the checkpoint
            f = slots[count >= MAX_ENTRIES]  # (memory stays bounded)
            self.head[f] = (self.head[f] + 1) % self.depth
            self.count[f] -= 1
            count = self.count[slots]
        head = self.head[slots]
        p = (head + count - 1) % self.depth  # each slot's newest entry
        t_new = self.t[slots, p]
        ahead = t >= t_new
        if slots.size and ahead.all():  # every observation after its track's newest (in order): one step
            # (each is fused: the ring is in time order and max_lag >= 0)
            if self._room_for(int(count.max()) + 1):
                p = (self.head[slots] + count - 1) % self.depth
            x_out, P_out, step, modes = self._step(t_new, *(self._state_at(slots, p) if prior is None else (None, None)),
                                                   t, H, R, z, self._bank_at(slots, p), self._modes_at(slots, p), prior)
            self._write(slots, (p + 1) % self.depth, t, x_out, P_out, H, R, z, step, modes)
            self.count[slots] = count + 1
            self._trim(slots, t)
            return ahead, x_out, P_out
        ok = (t >= self.t[slots, head]) & (t >= t_new - self.max_lag)
        n = slots.shape[0]
        if not ok.any():
            return ok, np.zeros((n, self.dim)), np.zeros((n, self.dim, self.dim))
        i: slice | np.ndarray = slice(None) if ok.all() else ok.nonzero()[0]  # none late (the usual): no subsets
        self._room_for(int(count[i].max()) + 1)
        x_i, P_i = self._reprocess(slots[i], t, H[i], R[i], z[i], t_new[i],
                                   None if prior is None else (prior[0][i], prior[1][i]))
        if isinstance(i, slice):
            return ok, x_i, P_i
        x_out, P_out = np.zeros((n, self.dim)), np.zeros((n, self.dim, self.dim))
        x_out[i], P_out[i] = x_i, P_i
        return ok, x_out, P_out

    def _reprocess(self, slots: np.ndarray, t: float, H: np.ndarray, R: np.ndarray, z: np.ndarray,
                   t_newest: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Fuse each observation at ``t`` into its track (:meth:`fuse` made room for one more entry in
        each; ``prior`` as there; the track's newest entry at ``t_newest``): after the newest, or inserted
        before the later ones, which are fused again (:meth:`_refuse`). One step for all of them: a track
        whose newest entry is not after ``t`` fuses nothing again."""
        n_after = self._newer_than(slots, t)
        self.reprocessed += int(n_after.sum())
        keep = self.count[slots] - n_after  # entries up to t stay (>= 1: the checkpoint is not after t)
        later = self._later(slots, keep, n_after)  # gathered before the ring is rewritten
        p = self._pos(slots, keep - 1)
        x, P = self._state_at(slots, p) if prior is None else (None, None)
        x_at, P_at, step, modes = self._step(self.t[slots, p], x, P, t, H, R, z, self._bank_at(slots, p),
                                             self._modes_at(slots, p), prior)
        self._write(slots, self._pos(slots, keep), t, x_at, P_at, H, R, z, step, modes)
        if later is not None:
            self._refuse(later, t, (x_at, P_at, step, modes))
        self.count[slots] = keep + n_after + 1
        self._trim(slots, np.maximum(t_newest, t))
        return x_at, P_at

    def _later(self, slots: np.ndarray, keep: np.ndarray, n_after: np.ndarray) -> Later | None:
        """The observations after the first ``keep`` entries of each slot (``n_after`` of them), to fuse
        again, or None (none)."""
        steps = int(n_after.max())
        if not steps:
            return None
        rank = np.argsort(-n_after, kind="stable")
        ranked = slots[rank]
        k = np.bincount(n_after, minlength=steps + 1)[:0:-1].cumsum()[::-1]  # tracks with more than j
        pos = (self.head[ranked] + keep[rank] + np.arange(steps)[:, None]) % self.depth  # (steps, tracks)
        runs = np.arange(slots.size) < k[:, None]
        at = (ranked * self.depth + pos)[runs]  # step-major: step j's are k[j] consecutive ones
        moved = (ranked * self.depth + (pos + 1) % self.depth)[runs]
        return Later(rank, k.tolist(), moved, *(self._flat(name)[at] for name in ("t", "m", "H", "R", "z")))

    def _refuse(self, later: Later, t: float, first: tuple[np.ndarray, np.ndarray, DetectorStep, Modes | None]
                ) -> None:
        """Fuse the ``later`` observations again, step by step from each track's posterior after the
        inserted observation at ``t`` (``first``: its posteriors, detector step and modes), and write
        them each one position later in the ring.

        The tracks are ranked by how many observations they fuse again, most first, so that step
        ``j``'s tracks are the first ``k_j`` of them: its inputs are leading rows of the step before's
        results and a run of the observations gathered once; the ring is written once, at the end.
        A batched step treats each track as alone, so each track's arithmetic is the one of fusing its
        observations one by one."""
        rank, k = later.rank, later.k
        x_at, P_at, step, modes = first
        t_prev, x_prev, P_prev = t, x_at[rank], P_at[rank]
        bank = None if step is None else InputBank(*(a[rank] for a in step[0]))
        modes = None if modes is None else modes.take(rank)
        one_size = bool((later.m == later.m[0]).all())
        results: list[tuple[np.ndarray, np.ndarray, DetectorStep, Modes | None]] = []
        off = 0
        for kj in k:
            run = slice(off, off + kj)
            args = (t_prev if np.ndim(t_prev) == 0 else t_prev[:kj], x_prev[:kj], P_prev[:kj],
                    None if bank is None else InputBank(*(a[:kj] for a in bank)),
                    None if modes is None else Modes(*(a[:kj] for a in modes)))
            if one_size:
                m = int(later.m[0])
                out = self._step(*args[:3], later.t[run], later.H[run, :m], later.R[run, :m, :m], later.z[run, :m],
                                 *args[3:])
            else:
                out = self._step_by_size(args, later.t[run], later.m[run], later.H[run], later.R[run], later.z[run])
            results.append(out)
            t_prev, (x_prev, P_prev, step, modes) = later.t[run], out
            bank = None if step is None else step[0]
            off += kj
        x_all, P_all = np.concatenate([r[0] for r in results]), np.concatenate([r[1] for r in results])
        steps = None if step is None else tuple(type(part)(*map(np.concatenate, zip(*(r[2][i] for r in results))))
                                                for i, part in enumerate(step))
        modes_all = None if modes is None else Modes(*map(np.concatenate, zip(*(r[3] for r in results))))
        for m, e in [(int(later.m[0]), slice(None))] if one_size else [
                (m, (later.m == m).nonzero()[0]) for m in np.unique(later.m).tolist()]:
            self._write_at(later.moved[e], later.t[e], x_all[e], P_all[e], later.H[e, :m], later.R[e, :m, :m],
                           later.z[e, :m],
                           None if steps is None else tuple(type(part)(*(a[e] for a in part)) for part in steps),
                           None if modes_all is None else Modes(*(a[e] for a in modes_all)))

    def _step_by_size(self, args: tuple, t: np.ndarray, m: np.ndarray, H: np.ndarray, R: np.ndarray, z: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, DetectorStep, Modes | None]:
        """One re-fusion step over observations of several sizes ``m`` (padded to the ring's): a
        :meth:`_step` per size, the results in the observations' order."""
        t0, x, P, bank, modes = args
        n = m.size
        x_out, P_out = np.empty(x.shape), np.empty(P.shape)
        step_out: DetectorStep = None
        modes_out = None if modes is None else Modes(*(np.empty(a.shape, a.dtype) for a in modes))
        for size in np.unique(m).tolist():
            g = (m == size).nonzero()[0]
            xg, Pg, step, mode_g = self._step(
                t0 if np.ndim(t0) == 0 else t0[g], x[g], P[g], t[g], H[g, :size], R[g, :size, :size],
                z[g, :size], None if bank is None else InputBank(*(a[g] for a in bank)),
                None if modes is None else modes.take(g))
            x_out[g], P_out[g] = xg, Pg
            if step is not None:
                if step_out is None:
                    step_out = tuple(type(part)(*(np.empty((n,) + a.shape[1:], a.dtype) for a in part))
                                     for part in step)
                for part, new in zip(step_out, step):
                    for a, b in zip(part, new):
                        a[g] = b
            if mode_g is not None:
                for a, b in zip(modes_out, mode_g):
                    a[g] = b
        return x_out, P_out, step_out, modes_out


class DepartedTracks:
    """Confirmed central tracks deleted by the life rules, kept ``max_lag`` seconds for the pictures
    made after them: a picture at ``T`` made ``picture_delay`` later shows a track deleted since
    while ``T`` is at most its last supported time (the target was there; after its last detection
    the deletion says it was gone), as a tracker of scans's picture shows the tracks it had at
    ``T`` (docs/multitarget.md#pictures). Their buffers are kept as a hand-over carries them."""

    def __init__(self, like: CentralTracks):
        self.tracks = CentralTracks(like.dim, like.q, like.noise_model, like.max_lag, capacity=8,
                                    depth=like.depth, detector=like.detector, modes=like.modes)
        self.last: dict[int, float] = {}  # id -> its last supported time
        self.sensors: dict[int, list[str]] = {}  # id -> the sensors that tracked it

    def keep(self, cid: int, table: CentralTracks, last: float, sensors: list[str]) -> None:
        """Track ``cid`` of ``table`` (before its deletion there), last supported at ``last``."""
        s = table.slot[cid]
        slot = self.tracks.place(cid, True, table.entries(cid))
        self.tracks.since[slot], self.tracks.confirmed_t[slot] = table.since[s], table.confirmed_t[s]
        self.last[cid], self.sensors[cid] = last, sensors

    def expire(self, now: float) -> None:
        """Forget the tracks last supported more than ``max_lag`` before ``now``."""
        for cid in [c for c, last in self.last.items() if last < now - self.tracks.max_lag]:
            self.tracks.delete(cid)
            del self.last[cid], self.sensors[cid]

    def shown_at(self, T: float) -> np.ndarray:
        """The slots of the tracks a picture at ``T`` shows (begun and confirmed by ``T``, last
        supported at or after it), in increasing id."""
        slots = self.tracks.live()
        if not slots.size:
            return slots
        last = np.array([self.last[c] for c in self.tracks.ids[slots].tolist()])
        began, confirmed = self.tracks.as_of(slots, T)
        return slots[began & confirmed & (last >= T)]
