"""The ``[mtt]`` table: multi-target tracking, local trackers and the track-to-track centre."""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from fedtrack.config import ConfigError, require_finite_keys
from fedtrack.deployment import DeploymentConfig
from fedtrack.geodetic import FrameConfig
from fedtrack.keys import InvalidName, check_id
from fedtrack.local_filters.mtt.models import ModeRates, maneuver_visible
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.wire.limits import MAX_MAGNITUDE

NOISE_MODELS = ("continuous", "discrete")
MANEUVER_MODES = ("none", "vdie")  # per-track maneuver handling (local_filters/mtt/maneuver.py)
# [mtt] process_noise: CV with q, or two modes per track, CV without noise and CV with q (models.Modes);
# "auto" (the default) is each associator's own: two modes for jipda and mht (every branch carries them;
# better on every bench scenario's mtt-centralized: docs/mht.md, "Issue 25's dense bar, second round"), CV for gnn
# (its pictures kept as they were before the modes existed); docs/multitarget.md#parameters
PROCESS_NOISE = ("auto", "fixed", "imm")
AUTO_PROCESS_NOISE = {"gnn": "fixed", "jipda": "imm", "mht": "imm"}
# candidate onsets of a sensor's tracker (one per scan): 15 scans, where paper 004's 6 misses the
# gentle turns of the simulator's targets (docs/multitarget.md#maneuvers)
MTT_VDIE_WINDOW = 15
# candidate onsets of a central track's maneuver detector (one per fused observation): about 10 s
# of three sensors' scans, so that the true onset is still a candidate when the detection comes
# (5-7 s after it for a 3 m/s^2 maneuver under 10 m noise; docs/multitarget.md#maneuvers)
CENTRAL_MANEUVER_WINDOW = 30
MAX_CENTRAL_MANEUVER_WINDOW = 200  # its banks are kept per ring entry: memory grows with it
MIN_PERIOD = 1e-3  # [s] pictures at 1 kHz at most: beyond any display or consumer, and a shorter period
# makes the picture clock (replay, a live centre after a gap) spend its time making predictions
# [s] a picture predicts the tracks up to a period past their last scan: no further than the services predict
# (``[deployment] max_time_jump_s``' default); an infinite period wrote a picture at "t": null, 1e300 s tracks of
# infinite coordinates
MAX_PERIOD = 3600.0

# [mtt] associator: the association methods of the multi-target tracker (local_filters/mtt/association.py)
ASSOCIATORS = ("gnn", "jipda", "mht")
MHT_MANAGEMENTS = ("score", "counts")  # local_filters/mtt/associators/mht.py
# [m/s] [mtt] max_speed's default, the speed bound of two-point starts (local_filters/mtt/initiation.py): about
# Mach 3 at sea level (3 x 340 m/s), above every aircraft flown (the SR-71's 980 m/s, Mach 3.3 at altitude) and
# most cruise and air-defence missiles; a bound of what flies in air, not of any scenario's targets
# (docs/multitarget.md#fast-targets-two-point-starts-fastinit-session)
MAX_SPEED = 1000.0


# mht's window = "auto": the chance that a target is missed on every one of the window's later scans
MHT_WINDOW_MISS = 0.01


def auto_window(pd: float) -> int:
    """mht's ``window = "auto"``: ``N = 1 + max(1, ceil(ln eps / ln(1 - P_D)))``, ``eps`` =
    :data:`MHT_WINDOW_MISS`: the ``N - 1`` scans after an ambiguous one bring the target's next
    detection but with probability ``eps`` (3 at P_D 0.9, 4 at 0.8; docs/mht.md)."""
    later = math.ceil(math.log(MHT_WINDOW_MISS) / math.log1p(-pd) - 1e-9) if pd < 1 else 1
    return 1 + max(1, later)


@dataclass(frozen=True)
class MhtConfig:
    """``[mtt.mht]``: the track-oriented MHT (``associator = "mht"``; the defaults and their
    derivation: docs/mht.md)."""

    window: int | str = "auto"  # N: scans back to the branch N-scan pruning keeps; "auto": auto_window(P_D)
    k: int = 3  # global hypotheses kept
    max_branches: int = 3  # leaves kept per track
    management: str = "score"  # "score": the SPRT; "counts": gnn's M-of-N rules and likelihoods
    false_track: float = 1e-4  # alpha: probability of confirming a track started on clutter
    miss: float = 1e-2  # beta: probability of deleting a track on a real target

    def validate(self) -> None:
        if not (self.window == "auto" or isinstance(self.window, int) and self.window >= 1):
            raise ConfigError('window: must be >= 1 or "auto"')
        for key in ("k", "max_branches"):
            if not getattr(self, key) >= 1:
                raise ConfigError(f"{key}: must be >= 1")
        if self.management not in MHT_MANAGEMENTS:
            raise ConfigError(f"management: must be one of {', '.join(MHT_MANAGEMENTS)}")
        if not (0 < self.false_track < 1 and 0 < self.miss < 1 and self.false_track + self.miss < 1):
            raise ConfigError("false_track, miss: must be in (0, 1) with a sum below 1")


@dataclass(frozen=True)
class SensorOverride:
    """``[mtt.sensor.<id>]``: detection probability, clutter density and noise floor of one sensor."""

    pd: float | None = None
    clutter_density: float | None = None
    # the least noise standard deviation per measured coordinate its class has (2-D: [m, m]; radar: [m, rad,
    # rad]): a centre raises a claimed R below it (local_filters/linear/noise_floor.py)
    noise_floor: tuple[float, ...] | None = None


# delete_misses' rationale (3 misses at P_D 0.9: a live target lost by misses once in a thousand
# scans), kept at every P_D: a tracker's count is at least the fewest misses in a row whose chance
# for a live target is at most LOST (miss_count), and so is the centre's per tracking sensor.
LOST = 1e-3
# [s] the scan of that rationale ([mtt] q's and period's 1 s): a faster tracker keeps LOST a second
# as well as a scan, LOST dt / LOST_SCAN_S for a scan dt after its last (scan_lost)
LOST_SCAN_S = 1.0


def log_miss_of(pd: float) -> float:
    """``ln(1 - P_D)``: the log-probability that one scan misses a live target (finite at P_D 1)."""
    return math.log1p(-min(pd, 1.0 - 1e-12))


def miss_count(log_miss: np.ndarray | float, lost: float = LOST) -> np.ndarray:
    """The fewest misses ``m`` with ``exp(m log_miss) <= lost``, ``log_miss`` the log-probability
    of one miss (< 0; -inf gives 0; a rounding never adds a miss)."""
    return np.ceil(math.log(lost) / np.asarray(log_miss) - 1e-9)


def scan_lost(dt: float) -> float:
    """The chance a scan ``dt`` [s] after the last may give of losing a live target by misses:
    ``LOST``, and ``LOST`` a second for scans less than ``LOST_SCAN_S`` apart (at 10 Hz, 3 misses
    in a row at P_D 0.9 come once in 1,000 scans: a live target lost every 100 s); ``dt <= 0`` (a
    tracker's first scan, a scan at the last one's time) ``LOST``; never below the smallest
    normal float (scans 5e-324 s apart: a chance of 0 has no logarithm)."""
    return max(LOST * dt / LOST_SCAN_S, sys.float_info.min) if 0.0 < dt < LOST_SCAN_S else LOST


def clutter_hit(density: float, R: np.ndarray, interval: float, init_velocity_std: float, gate2: float) -> float:
    """The chance that a position scan (noise covariance ``R``, 2 x 2) puts a clutter detection into
    the gate of a track started on one of its clutter detections ``interval`` seconds before (at
    least 1 s): ``1 - exp(-lambda V)``, ``V = pi g sqrt(det S)`` the gate's area, ``S = 2 R +
    (sigma_v T)^2 I`` (the start's position noise, ``init_velocity_std`` over ``T = max(interval,
    1 s)``, the new detection's noise), ``g = gate2`` the 2-D gate's chi-square quantile, ``lambda =
    density`` the clutter density per m^2."""
    S = 2.0 * np.asarray(R, float) + (init_velocity_std * max(interval, 1.0)) ** 2 * np.eye(2)
    area = math.pi * gate2 * math.sqrt(max(float(np.linalg.det(S)), 0.0))
    return -math.expm1(-density * area)


def count_chance(hit: float, hits: int, window: int) -> float:
    """The chance that the ``hits``-of-``window`` count confirms a track started on one detection when
    each of the next ``window - 1`` scans hits it with probability ``hit``: it needs ``hits - 1`` of
    them (the binomial tail). With ``hit`` a clutter hit (:func:`clutter_hit`) the count's false
    confirmation, with P_D a real target's confirmation within the window."""
    n = window - 1
    return sum(math.comb(n, j) * hit**j * (1.0 - hit) ** (n - j) for j in range(hits - 1, n + 1))


def window_cap(pd: float, hits: int, most: int) -> int:
    """The longest window ``N`` in which a real target detected with ``pd`` meets ``max(hits, N - most)``
    hits (at most ``most`` misses) at least as often as not (jipda's ``SHOW``, 1/2); ``pd`` below 1."""
    from fedtrack.local_filters.mtt.associators.jipda import SHOW

    n = hits
    while count_chance(pd, max(hits, n + 1 - most), n + 1) >= SHOW:
        n += 1
    return n


# the P_D delete_misses' rationale is made for: 3 misses in a row lose a live target with LOST at 0.9 ([mtt] pd's
# and delete_misses' defaults)
RATIONALE_PD = 0.9
# The longest window a raised count takes (raised_count): the longest the count56 search reaches at RATIONALE_PD
# (misses allowed below its 3, a real target's even chance: 27 scans). A real target detected more often needs no
# longer; a longer window there only waits for a clutter track's rare misses (6,637 scans at P_D 1 and a gate hit
# of 0.999), so a real target waited for ever unseen and no warning told it.
COUNT_WINDOW_CAP = window_cap(RATIONALE_PD, 1, int(miss_count(log_miss_of(RATIONALE_PD))) - 1)


@lru_cache(maxsize=4096)
def raised_count(hit: float, pd: float, hits: int, window: int) -> tuple[int, int]:
    """The count of a tracker whose scans hit a clutter track with probability ``hit`` (:func:`clutter_hit`):
    the ``M``-of-``N`` count with ``M >= hits`` and ``N - M >= window - hits`` (never fewer hits or misses
    allowed than configured) of the smallest ``N``, then ``M``, that meets both bounds: the chance of
    confirming a track started on clutter, ``count_chance(hit, M, N)``, at most jipda's ``FALSE_CONFIRM``
    (0.01), and a real target (detected with ``pd``) confirming within the window at least as often as not
    (``count_chance(pd, M, N) >= SHOW``, 1/2). The misses allowed stay below the ``D`` in a row that delete a
    live target with at most ``LOST`` (:func:`miss_count` at ``pd``: 3 at P_D 0.9, 8 at 0.6), which with
    ``SHOW`` bounds the windows searched, and so does :data:`COUNT_WINDOW_CAP` (27 scans, never below the
    configured window) where P_D above 0.9 leaves the first bound loose (6,637 scans at P_D 1 and a hit of
    0.999). Where none meets the first bound: the searched count of the least false confirmations (the
    configured one where every scan hits, ``hit`` 1), and :meth:`MttConfig.count_note` warns. As given where
    the given count meets the bound (4-of-6 at P_D 0.6, 1e-6 m^-2 and 19.5 m).
    docs/multitarget.md#a-cluttered-sensors-count-any-m-of-n-count56-session,
    docs/multitarget.md#a-count-that-never-ends-the-windows-cap-untuned57-session"""
    from fedtrack.local_filters.mtt.associators.jipda import FALSE_CONFIRM, SHOW

    if count_chance(hit, hits, window) <= FALSE_CONFIRM or hit >= 1.0:
        return hits, window
    least = window - hits
    most = max(least, int(miss_count(log_miss_of(pd))) - 1)
    best = (count_chance(hit, hits, window), window, hits)
    n = window
    while n <= max(window, COUNT_WINDOW_CAP) and count_chance(pd, max(hits, n - most), n) >= SHOW:
        for m in range(max(hits, n - most), n - least + 1):
            if count_chance(pd, m, n) < SHOW:
                break
            false = count_chance(hit, m, n)
            if false <= FALSE_CONFIRM:
                return m, n
            best = min(best, (false, n, m))
        n += 1
    return best[2], best[1]


@dataclass(frozen=True)
class MttConfig:
    """Multi-target tracking parameters (see docs/multitarget.md for the rules they drive)."""

    q: float = 1.0
    noise_model: str = "continuous"
    process_noise: str = "auto"
    maneuver_s: float = 15.0  # mean maneuver duration (process_noise = "imm")
    straight_s: float = 60.0  # mean time between maneuvers (process_noise = "imm")
    pd: float = 0.9
    clutter_density: float = 1e-7
    gate_probability: float = 0.999
    max_lag: float = 3.0
    period: float = 1.0
    picture_delay: float = 0.0
    init_velocity_std: float = 30.0
    init_z_std: float = 1000.0
    max_speed: float = MAX_SPEED
    sensors: tuple[str, ...] | str = "any"
    confirm_hits: int = 3
    confirm_window: int = 4
    delete_misses: int = 3
    sharing: str = "equal"
    association_gate_probability: float = 0.9999
    unmap_after: int = 3
    central_timeout: float = 5.0
    leave_after_s: float = 5.0
    maneuver: str = "none"
    associator: str = "gnn"
    vdie: VdieParams = field(default_factory=lambda: VdieParams(window=MTT_VDIE_WINDOW))
    central_maneuver_window: int = CENTRAL_MANEUVER_WINDOW
    mht: MhtConfig = field(default_factory=MhtConfig)
    sensor: dict[str, SensorOverride] = field(default_factory=dict)

    @property
    def central_detector(self) -> VdieParams | None:
        """The central tracks' maneuver detector (``maneuver = "vdie"``): ``[mtt.vdie]`` over
        ``central_maneuver_window`` fused observations; None without maneuver handling."""
        if self.maneuver != "vdie":
            return None
        return dataclasses.replace(self.vdie, window=self.central_maneuver_window)

    @cached_property
    def mht_settings(self) -> MhtConfig:
        """``[mtt.mht]`` with ``window = "auto"`` resolved from the smallest P_D configured (the
        window must wait for the least-detecting sensor's target; :func:`auto_window`)."""
        if self.mht.window != "auto":
            return self.mht
        pd = min([self.pd] + [self.pd_of(s) for s in self.sensor])
        return dataclasses.replace(self.mht, window=auto_window(pd))

    @property
    def motion(self) -> str:
        """``process_noise`` resolved: ``"fixed"`` or ``"imm"`` (``"auto"``: the associator's own)."""
        return AUTO_PROCESS_NOISE.get(self.associator, "fixed") if self.process_noise == "auto" else self.process_noise

    def clutter_gate_hit(self, sensor: str, R: np.ndarray, interval: float = 1.0) -> float:
        """:func:`clutter_hit` of position sensor ``sensor`` (its clutter density per m^2, noise
        covariance ``R``), its next scan ``interval`` seconds later (the sensor's period where known,
        else 1 s), or one second later for a faster sensor: a faster sensor starts as many more
        tracks a second as its gates are smaller (a 10 Hz sensor's chance at its own 0.1 s, a tenth,
        took away the note where 2.4 false tracks a picture were confirmed): its chance stays judged
        over a second, as the deletion counts are (:func:`scan_lost`). A radar's density is per m rad^2
        of its own measurement space: not for this formula."""
        return clutter_hit(self.clutter_of(sensor), R, interval, self.init_velocity_std, self.thresholds.gate[2])

    def counts_false_confirm(self, hit: float) -> float:
        """The chance that the configured M-of-N count confirms a track started on clutter when each
        of the next ``confirm_window - 1`` scans hits it with probability ``hit`` (:func:`count_chance`;
        one sensor's tracker: :meth:`clutter_gate_hit`)."""
        return count_chance(hit, self.confirm_hits, self.confirm_window)

    def raised_count_of(self, sensor: str, R: np.ndarray, interval: float = 1.0) -> tuple[int, int]:
        """The M-of-N count a tracker of position sensor ``sensor``'s scans (noise covariance ``R``, its
        scans ``interval`` seconds apart) confirms by where the count rules the tracks (``gnn``, mht's
        ``"counts"``): :func:`raised_count` of :meth:`clutter_gate_hit` at the sensor's P_D."""
        return raised_count(self.clutter_gate_hit(sensor, R, interval), self.pd_of(sensor), self.confirm_hits,
                            self.confirm_window)

    @property
    def confirm_bound(self) -> float | None:
        """The local trackers' bound on confirming a track started on clutter when they confirm by
        a test (jipda's existence: ``FALSE_CONFIRM`` a scan; mht's score: ``[mtt.mht]
        false_track``); None when they count detections (``gnn``, mht's ``"counts"``)."""
        from fedtrack.local_filters.mtt.associators.jipda import FALSE_CONFIRM

        if self.associator == "jipda":
            return FALSE_CONFIRM
        return self.mht.false_track if self.associator == "mht" and self.mht.management == "score" else None

    def count_note(self, position_sensors: Mapping[str, np.ndarray], intervals: Mapping[str, float] | None = None
                   ) -> str | None:
        """A warning when the count rules the tracks (``gnn``, mht's ``"counts"``) and some position
        sensor's clutter (``position_sensors``: each one's noise covariance ``R``; ``intervals``: each
        one's period, 1 s where not given) makes its tracker confirm clutter tracks more often than
        jipda's bound allows even with the count its tracker raises there (:func:`raised_count`: as far
        as a real target keeps a chance of 1/2 of confirming, within :data:`COUNT_WINDOW_CAP` scans; a sensor
        without clutter, ``clutter_density`` 0, starts no track on clutter, whatever the count)."""
        from fedtrack.local_filters.mtt.associators.jipda import FALSE_CONFIRM

        if self.confirm_bound is not None:
            return None
        every = intervals or {}
        worst = (0.0, "", 0.0, self.confirm_hits, self.confirm_window)
        for s, R in position_sensors.items():
            if self.clutter_of(s) > 0:
                hit = self.clutter_gate_hit(s, R, every.get(s, 1.0))
                m, n = self.raised_count_of(s, R, every.get(s, 1.0))
                worst = max(worst, (count_chance(hit, m, n), s, math.sqrt(float(np.max(np.diag(R)))), m, n))
        chance, sensor, sd, m, n = worst
        if chance <= FALSE_CONFIRM:
            return None
        return (f"at sensor {sensor}'s clutter_density {self.clutter_of(sensor):g} per m^2 (noise {sd:.3g} m) the "
                f"{m}-of-{n} count (raised as far as a real target keeps a chance of 1/2 to confirm, within "
                f"{max(COUNT_WINDOW_CAP, self.confirm_window)} scans) confirms a track started on clutter with "
                f"probability {chance:.3f} (above {FALSE_CONFIRM:g}): expect false tracks; associator = \"jipda\" "
                "confirms by existence")

    @property
    def unsupported_s(self) -> float:
        """[s] The longest a track-to-track centre keeps a central track without a fused observation:
        ``central_timeout``, or ``max_lag`` where longer (a track of a sensor slower than ``central_timeout``
        is kept up to four of its scan intervals, never beyond the lag the data may have: so a picture
        predicts a track at most ``unsupported_s + max_lag + period`` past its data)."""
        return max(self.central_timeout, self.max_lag)

    @property
    def mode_rates(self) -> ModeRates | None:
        """The two modes' switching rates (``process_noise = "imm"``), None: CV with ``q``."""
        return ModeRates(1.0 / self.straight_s, 1.0 / self.maneuver_s) if self.motion == "imm" else None

    def modes_of(self, sensor: str | None, dim: int) -> ModeRates | None:
        """The modes of the tracker of ``sensor``'s scans alone (None: of every sensor's), state size ``dim``:
        :attr:`mode_rates`, except that with ``process_noise = "auto"`` a position sensor's (``dim`` 4) whose
        ``noise_floor`` cannot see a maneuver (:func:`~.models.maneuver_visible`) tracks with CV and ``q``."""
        floor = None if sensor is None or dim != 4 or self.process_noise != "auto" else self.noise_floor_of(sensor)
        if floor is None or maneuver_visible(self.q, self.noise_model, self.maneuver_s, float(np.min(floor))):
            return self.mode_rates
        return None

    def validate(self) -> None:
        positive = {"q": self.q, "maneuver_s": self.maneuver_s, "straight_s": self.straight_s,
                    "period": self.period, "init_velocity_std": self.init_velocity_std, "init_z_std": self.init_z_std,
                    "central_timeout": self.central_timeout, "leave_after_s": self.leave_after_s}
        for key, value in positive.items():
            if not value > 0:
                raise ConfigError(f"{key}: must be > 0")
        if not self.period >= MIN_PERIOD:
            raise ConfigError(f"period: must be >= {MIN_PERIOD:g} s (pictures at 1 kHz at most), got {self.period:g}")
        if not self.period <= MAX_PERIOD:
            raise ConfigError(f"period: must be <= {MAX_PERIOD:g} s (a picture predicts the tracks up to a period past "
                              f"their last scan), got {self.period:g}")
        if self.noise_model not in NOISE_MODELS:
            raise ConfigError(f"noise_model: must be one of {', '.join(NOISE_MODELS)}")
        if self.associator not in ASSOCIATORS:
            raise ConfigError(f"associator: must be one of {', '.join(ASSOCIATORS)}")
        if self.process_noise not in PROCESS_NOISE:
            raise ConfigError(f"process_noise: must be one of {', '.join(PROCESS_NOISE)}")
        if self.maneuver not in MANEUVER_MODES:
            raise ConfigError(f"maneuver: must be one of {', '.join(MANEUVER_MODES)}")
        if self.associator in ("jipda", "mht") and self.maneuver != "none":
            raise ConfigError(f'maneuver: "vdie" works with associator = "gnn" only ({self.associator}\'s tracks are CV)')
        for key in ("max_lag", "picture_delay", "clutter_density", "max_speed"):
            if not getattr(self, key) >= 0:
                raise ConfigError(f"{key}: must be >= 0")
        # inf (TOML's literal) passed every range check: q, init_velocity_std or init_z_std made every covariance
        # non-finite (a traceback), picture_delay with max_lag inf an OverflowError, clutter_density every detection
        # clutter (no track ever); before the tour61 session. maneuver_s, straight_s, max_lag, central_timeout and
        # leave_after_s mean "never" when infinite (maneuver_s = inf: one mode, docs/mht.md)
        require_finite_keys(self, ("q", "init_velocity_std", "init_z_std", "picture_delay", "clutter_density"))
        if not self.picture_delay <= self.max_lag:  # the centre keeps its states max_lag back (engines.py)
            raise ConfigError(f"picture_delay: must be <= max_lag ({self.max_lag:g} s: a picture waits for late "
                              f"data at most as long as it is kept), got {self.picture_delay:g}")
        if not math.isfinite(self.max_speed):
            raise ConfigError("max_speed: must be a finite speed [m/s] (0: no two-point starts)")
        if not 0 < self.pd <= 1:  # 1: a sensor that never misses a target in its view
            raise ConfigError(f"pd: must be in (0, 1] (a detection probability), got {self.pd:g}")
        for key in ("gate_probability", "association_gate_probability"):
            if not 0 < getattr(self, key) < 1:
                raise ConfigError(f"{key}: must be in (0, 1) (a probability; 1 is an infinite gate), "
                                  f"got {getattr(self, key):g}")
        if not self.vdie.min_samples <= self.central_maneuver_window <= MAX_CENTRAL_MANEUVER_WINDOW:
            raise ConfigError(f"central_maneuver_window: must be in mtt.vdie.min_samples.."
                              f"{MAX_CENTRAL_MANEUVER_WINDOW}")
        if not 1 <= self.confirm_hits <= self.confirm_window:
            raise ConfigError("confirm_hits: must be in 1..confirm_window")
        if self.delete_misses < 1 or self.unmap_after < 1:
            raise ConfigError("delete_misses, unmap_after: must be >= 1")
        if self.sharing != "equal":
            raise ConfigError("sharing: only 'equal' (beta_i = number of live sensors) is supported")
        if isinstance(self.sensors, str) and self.sensors != "any":
            raise ConfigError('sensors: a list of sensor ids or "any"')
        for sid in (() if isinstance(self.sensors, str) else self.sensors) + tuple(self.sensor):
            try:
                check_id(sid)
            except InvalidName as exc:
                raise ConfigError(f"sensors: {exc}") from exc
        listed = () if isinstance(self.sensors, str) else self.sensors
        repeated = sorted({sid for sid in listed if listed.count(sid) > 1})
        if repeated:
            raise ConfigError(f"sensors: sensor id {repeated[0]!r} listed twice (each sensor once)")
        unused = [sid for sid in self.sensor if not self.allows(sid)]
        if unused:
            raise ConfigError(f"sensor.{unused[0]}: a table for a sensor that sensors = {list(listed)} does not "
                              f"allow (its scans are refused; add {unused[0]!r} to sensors or drop the table)")
        for sid, over in self.sensor.items():
            if over.pd is not None and not 0 < over.pd <= 1:
                raise ConfigError(f"sensor.{sid}.pd: must be in (0, 1]")
            if over.clutter_density is not None and not 0 <= over.clutter_density < math.inf:
                raise ConfigError(f"sensor.{sid}.clutter_density: must be finite and >= 0")
            floor = over.noise_floor
            # at most the wire's largest quantity: diag(floor²) stays finite (1e200 made it inf, the floor none)
            if floor is not None and not (len(floor) in (2, 3) and all(0 < v <= MAX_MAGNITUDE for v in floor)):
                raise ConfigError(f"sensor.{sid}.noise_floor: must be 2 (position: m, m) or 3 (radar: m, rad, rad) "
                                  f"standard deviations > 0 and <= {MAX_MAGNITUDE:g}")

    def allows(self, sensor: str) -> bool:
        return self.sensors == "any" or sensor in self.sensors

    def pd_of(self, sensor: str) -> float:
        over = self.sensor.get(sensor)
        return self.pd if over is None or over.pd is None else over.pd

    def log_miss(self, sensor: str | None = None) -> float:
        """``ln(1 - P_D)`` of ``sensor`` (None: ``[mtt] pd``): the log-probability that one of its
        scans misses a live target (finite at P_D 1)."""
        return log_miss_of(self.pd if sensor is None else self.pd_of(sensor))

    def misses_to_delete(self, sensor: str | None = None, dt: float = 0.0) -> int:
        """Misses in a row that delete a confirmed track of a tracker of ``sensor``'s scans:
        ``delete_misses``, or more where ``sensor``'s P_D makes that many likely for a live target
        (:func:`miss_count`: 3 at P_D 0.9, 5 at 0.8, 8 at 0.6); at a scan ``dt`` [s] after the
        tracker's last, at most ``LOST`` a second as well (:func:`scan_lost`: 4 at P_D 0.9 from
        0.1 s to 1 s)."""
        return max(self.delete_misses, int(miss_count(self.log_miss(sensor), scan_lost(dt))))

    def noise_floor_of(self, sensor: str) -> np.ndarray | None:
        """``sensor``'s noise floor (standard deviations per coordinate), None when not configured."""
        over = self.sensor.get(sensor)
        return None if over is None or over.noise_floor is None else np.array(over.noise_floor)

    def clutter_of(self, sensor: str) -> float:
        over = self.sensor.get(sensor)
        return self.clutter_density if over is None or over.clutter_density is None else over.clutter_density

    @cached_property
    def thresholds(self) -> "Thresholds":
        return Thresholds.of(self.gate_probability, self.association_gate_probability)


@dataclass(frozen=True)
class Thresholds:
    """Chi-square gates by dimension (2, 3 for detections; 4, 6 for track differences)."""

    gate: dict[int, float]
    association: dict[int, float]

    @staticmethod
    def of(gate_probability: float, association_probability: float) -> Thresholds:
        from scipy.special import chdtri

        return Thresholds({m: float(chdtri(m, 1.0 - gate_probability)) for m in (2, 3)},
                          {m: float(chdtri(m, 1.0 - association_probability)) for m in (2, 3, 4, 6)})


@dataclass(frozen=True)
class MttSettings:
    """The tables the multi-target replay and services read."""

    mtt: MttConfig = field(default_factory=MttConfig)


@dataclass(frozen=True)
class MttServiceSettings:
    """The tables ``serve mtt-local`` and ``serve mtt-centre`` read: ``[mtt]``, ``[deployment]`` and
    ``[frame]`` (the centre's pictures carry each track's WGS-84 position when it is set)."""

    mtt: MttConfig = field(default_factory=MttConfig)
    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    frame: FrameConfig | None = None
