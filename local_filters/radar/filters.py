"""The three radar local filters behind one interface: configs, a batched runner, a step API.

Algorithms: ``ekf`` (plain CV EKF), ``ekf-ie`` (EKF with direct input estimation, paper 002),
``ekf-tsfuzzy`` (EKF with TS-fuzzy error compensation, paper 003). All use the 3-D CV state
``[x, vx, y, vy, z, vz]`` and start with two-point differencing on the first two measurements.

* :func:`filter_kind` gives batched ``init``/``step``/``estimate`` functions (pure, over the
  leading Monte Carlo axis); :func:`run_batch` runs one over measurement arrays.
* :func:`make_radar_filter` gives a :class:`RadarFilter` whose ``.step(meas)`` takes one
  replay-format measurement dict and returns an estimate dict (or ``None`` while it needs a
  second measurement to initialize). The lead can wrap it as a distributed local filter.
* :func:`take_checked`: the rule for a measurement the filter cannot process, which the radar
  local filter and ``replay`` both follow.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from fedtrack.config import ConfigError, parse_dataclass, require_finite_keys
from fedtrack.jsonl import RADAR_FIELDS, InputError, as_covariance, as_float, as_vector, check_fields, require
from fedtrack.local_filters.radar.ekf import (
    CV3,
    MotionModel3D,
    ekf_step,
    motion_model_3d,
    two_point_init,
)
from fedtrack.local_filters.radar.input_estimation import (
    WINDOW_S,
    InputEstimationParams,
    ie_init,
    ie_step,
)
from fedtrack.local_filters.radar.measurement import polar_error
from fedtrack.local_filters.radar.ts_fuzzy import TSModel, load_model
from fedtrack.local_filters.radar.ts_fuzzy_ekf import (
    TAU_S,
    compensated,
    ts_init,
    ts_step,
)
from fedtrack.progress import progress_bar
from fedtrack.services.rejections import NUMERICAL_ERRORS, Numerical, require_covariances, require_finite

ALGORITHMS = ("ekf", "ekf-ie", "ekf-tsfuzzy")
MODEL_ENV = "FEDTRACK_TS_FUZZY_MODEL"


@dataclass(frozen=True)
class EkfConfig:
    """``q``: white-acceleration variance of the CV model, (m/s^2)^2."""

    q: float = 1.0

    def validate(self) -> None:
        require_finite_keys(self, ("q",))  # inf passed the > 0 check
        if not self.q > 0.0:
            raise ConfigError("q: must be > 0")


@dataclass(frozen=True)
class EkfIEConfig(EkfConfig):
    """Plain EKF keys plus the input-estimation window and test probabilities.

    The window is ``window_s`` seconds at the data's scan interval, or ``window`` scans when that is given
    (an override; a ``[radar_filter]`` table giving both is an error: :func:`make_radar_filter`)."""

    window: int | None = None
    window_s: float = WINDOW_S
    p_false_alarm: float = 1e-3
    p_input: float = 1e-3

    def validate(self) -> None:
        super().validate()
        self.params.validate()

    @property
    def params(self) -> InputEstimationParams:
        return InputEstimationParams(self.window, self.p_false_alarm, self.p_input, self.window_s)


@dataclass(frozen=True)
class EkfTsFuzzyConfig(EkfConfig):
    """Plain EKF keys plus ``model``: the ``.npz`` from ``fedtrack train ts-fuzzy``.

    Empty means the path in the environment variable ``FEDTRACK_TS_FUZZY_MODEL``.
    """

    model: str = ""

    @property
    def model_source(self) -> tuple[Path, str]:
        """The model file and where it was named: ``radar_filter.model``, else ``$FEDTRACK_TS_FUZZY_MODEL``."""
        if self.model:
            return Path(self.model), "radar_filter.model"
        if os.environ.get(MODEL_ENV):
            return Path(os.environ[MODEL_ENV]), f"${MODEL_ENV}"
        raise ConfigError(f"radar_filter.model: no TS-fuzzy model given: set it to a file `fedtrack train ts-fuzzy "
                          f"--out MODEL.npz` wrote, or ${MODEL_ENV}")


@dataclass(frozen=True)
class RadarFilterKeys(EkfIEConfig):
    """Every key of any radar filter: ``[radar_filter]`` as every command checks it (:func:`check_radar_filter`);
    the filter chosen then reads its own keys only."""

    model: str = ""


def check_radar_filter(table: Any) -> None:
    """A ConfigError naming the key when ``[radar_filter]`` holds a key no radar filter reads or a value out of its
    range (before the tour60 session only ``replay --algorithm ekf...`` and ``serve local-filter --filter ekf...``
    read the table: ``[radar_filter] qq = 1`` passed every other command, against the one-file rule)."""
    if not isinstance(table, dict):
        raise ConfigError(f"radar_filter: expected a table, got {table!r}")
    parse_dataclass(RadarFilterKeys, table, "radar_filter")


CONFIG_CLASSES: dict[str, type[EkfConfig]] = {
    "ekf": EkfConfig, "ekf-ie": EkfIEConfig, "ekf-tsfuzzy": EkfTsFuzzyConfig}


class FilterKind(NamedTuple):
    """Batched functions of one algorithm.

    ``init(z0, z1, R, model, sensor_position)``, ``step(state, z, R, model, sensor_position)``,
    ``estimate(state, model) -> (x, P, maneuver)``; ``label(maneuver) -> model name``.
    """

    init: Callable[..., Any]
    step: Callable[..., Any]
    estimate: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]
    label: Callable[[bool], str]


def _no_maneuver(x: np.ndarray) -> np.ndarray:
    return np.zeros(x.shape[:-1], bool)


def load_compatible_model(path: Path, name: str = "model") -> TSModel:
    """Load a TS model trained on the features this code computes (same smoothing constant); errors name
    the file and ``name``, where it was given (``radar_filter.model``, ``$FEDTRACK_TS_FUZZY_MODEL``, ``--model``)."""
    ts, meta = load_model(path, name)
    if "tau_s" not in meta or not np.isclose(float(meta["tau_s"]), TAU_S):
        raise ConfigError(f"{name}: {path} was trained with another feature smoothing constant; retrain it")
    return ts


def _ekf_state(state: Any, *args: Any) -> Any:
    return ekf_step(state, *args).state


def _ekf_estimate(state: Any, model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return state.x, state.P, _no_maneuver(state.x)


def _ie_estimate(state: Any, model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return state.filt.x, state.filt.P, state.maneuver


def _ts_estimate(ts: TSModel, state: Any, model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return compensated(state, ts, model), state.filt.P, _no_maneuver(state.ema)


def _label(plain: str, maneuvering: str, maneuver: bool) -> str:
    return maneuvering if maneuver else plain


def filter_kind(algorithm: str, config: EkfConfig, ts_model: TSModel | None = None) -> FilterKind:
    """The batched functions of ``algorithm`` (``ts_model`` overrides the configured file). Named
    functions and partials, no lambdas: a service checkpoints its filter by pickling it."""
    if algorithm == "ekf":
        return FilterKind(two_point_init, _ekf_state, _ekf_estimate, partial(_label, CV3, CV3))
    if algorithm in CONFIG_CLASSES and not isinstance(config, CONFIG_CLASSES[algorithm]):
        raise ConfigError(f"config for {algorithm} must be a {CONFIG_CLASSES[algorithm].__name__}")
    if algorithm == "ekf-ie":
        assert isinstance(config, EkfIEConfig)  # narrowed by the check above
        p = config.params
        return FilterKind(partial(ie_init, params=p), partial(ie_step, params=p), _ie_estimate,
                          partial(_label, CV3, "cv+input"))
    if algorithm == "ekf-tsfuzzy":
        assert isinstance(config, EkfTsFuzzyConfig)  # narrowed by the check above
        ts = ts_model if ts_model is not None else load_compatible_model(*config.model_source)
        return FilterKind(ts_init, ts_step, partial(_ts_estimate, ts), partial(_label, "cv+ts-fuzzy", "cv+ts-fuzzy"))
    raise ConfigError(f"algorithm: unknown radar filter {algorithm!r} (expected one of {ALGORITHMS})")


class BatchResult(NamedTuple):
    """Estimates (runs, K, n) and maneuver flags (runs, K); index 0 (before init) is NaN/False."""

    x: np.ndarray
    maneuver: np.ndarray
    P: np.ndarray | None


def run_batch(kind: FilterKind, zs: np.ndarray, R: np.ndarray, sensor_position: np.ndarray,
              model: MotionModel3D, label: str = "", keep_cov: bool = False) -> BatchResult:
    """Run a filter over measurements ``zs`` (runs, K, 3) taken every ``model.T`` seconds."""
    N, K = zs.shape[:2]
    n = model.dim
    x = np.full((N, K, n), np.nan)
    man = np.zeros((N, K), bool)
    P = np.full((N, K, n, n), np.nan) if keep_cov else None
    state = kind.init(zs[:, 0], zs[:, 1], R, model, sensor_position)

    def record(k: int) -> None:
        xe, Pe, me = kind.estimate(state, model)
        x[:, k], man[:, k] = xe, me
        if P is not None:
            P[:, k] = Pe

    record(1)
    with progress_bar(K - 2, label or "filter") as bar:
        for k in range(2, K):
            state = kind.step(state, zs[:, k], R, model, sensor_position)
            record(k)
            bar.update()
    return BatchResult(x, man, P)


class Measurement(NamedTuple):
    """One validated radar measurement."""

    t: float
    sensor: str
    z: np.ndarray
    R: np.ndarray
    sensor_position: np.ndarray


def parse_measurement(obj: dict[str, Any], where: str) -> Measurement:
    """Validate a replay-format measurement dict; errors name ``where`` and the field."""
    check_fields(obj, RADAR_FIELDS, "radar", where)
    sensor = require(obj, "sensor", where)
    if not isinstance(sensor, str) or not sensor:
        raise InputError(f"{where}: sensor must be a non-empty string")
    z = as_vector(require(obj, "z", where), "z", where, 3)
    problem = polar_error(z)
    if problem:
        raise InputError(f"{where}: {problem[1]}")
    return Measurement(as_float(require(obj, "t", where), "t", where), sensor, z,
                       as_covariance(require(obj, "R", where), "R", where, 3),
                       as_vector(require(obj, "sensor_position", where), "sensor_position", where, 3))


def same_interval(dt: float, T: float, t: float) -> bool:
    """Whether ``dt`` is the interval ``T`` up to the round-off of timestamps of magnitude ``t``.

    Each stamp carries up to half an ulp, so a difference of two stamps is off by up to one ulp
    of ``t`` and two differences by two: at epoch time (1.7e9 s, ulp 2.4e-7 s) the paper's 0.02 s
    varies by 1e-5 of itself from scan to scan, and a relative tolerance alone restarted the
    input-estimation window at every scan (the turn was never detected)."""
    return abs(dt - T) <= 4.0 * float(np.spacing(abs(t))) + 1e-9 * abs(T)


class RadarFilter:
    """Single-target, single-radar filter fed one measurement dict at a time (thin I/O wrapper).

    ``step(meas)`` returns ``None`` for the first measurement (initialization needs two) and
    afterwards ``{"t", "x", "P", "model", "maneuver"}`` with ``x`` in the 3-D CV order
    ``[x, vx, y, vy, z, vz]``. The sampling interval is the time difference of consecutive
    measurements; when it (or the sensor position) changes, the input-estimation window restarts
    (its length in scans taken again at the new interval when it is given in seconds).
    The state is kept as a batch of one so the batched filter functions apply unchanged.
    """

    def __init__(self, algorithm: str, config: EkfConfig, ts_model: TSModel | None = None) -> None:
        self.kind = filter_kind(algorithm, config, ts_model)
        self.config = config
        self._state: Any = None
        self._last: Measurement | None = None
        self._model: MotionModel3D | None = None

    @property
    def last_t(self) -> float | None:
        """The time of the last measurement taken (None before the first)."""
        return None if self._last is None else self._last.t

    def step(self, meas: dict[str, Any], where: str = "measurement") -> dict[str, Any] | None:
        """:meth:`take` the measurement dict ``meas`` (validated: errors name ``where``)."""
        return self.take(parse_measurement(meas, where), where)

    def afresh(self) -> RadarFilter:
        """This filter as it started (its algorithm and configuration, no measurement taken)."""
        fresh = copy.copy(self)
        fresh._state = fresh._last = fresh._model = None
        return fresh

    def take(self, m: Measurement, where: str = "measurement") -> dict[str, Any] | None:
        """Filter the validated measurement ``m``: its sensor must be the last one's, its time after it.
        :class:`Numerical` (the filter left as it was) when the estimate comes out non-finite or its
        covariance is one the wire refuses (a range of 1e90 m with a noise the wire takes at that range)."""
        last = self._last
        if last is not None:
            if m.sensor != last.sensor:
                raise InputError(f"{where}: sensor {m.sensor!r} differs from {last.sensor!r} (one radar per filter)")
            if not m.t > last.t:
                raise InputError(f"{where}: t must increase (got {m.t} after {last.t})")
        if last is None:
            self._last = m
            return None
        dt = m.t - last.t
        model = self._model
        if model is None or not same_interval(dt, model.T, max(abs(m.t), abs(last.t))):
            model = motion_model_3d(CV3, dt, self.config.q)
        try:
            with np.errstate(all="ignore"):  # checked below
                if self._state is None:
                    state = self.kind.init(last.z[None], m.z[None], m.R, model, m.sensor_position)
                else:
                    state = self._state
                    restart = (model is not self._model) or not np.array_equal(m.sensor_position, last.sensor_position)
                    if restart and "count" in state._fields:  # the input-estimation window (not tuple.count)
                        state = state._replace(count=np.zeros_like(state.count))
                    state = self.kind.step(state, m.z[None], m.R, model, m.sensor_position)
                x, P, man = self.kind.estimate(state, model)  # batch of one
        except NUMERICAL_ERRORS as exc:
            raise Numerical(f"{where}: the radar estimate: {exc}") from None
        require_finite(f"{where}: the radar estimate", x, P)
        require_covariances(f"{where}: the radar estimate", P)
        self._last, self._state, self._model = m, state, model
        return {"t": m.t, "x": x[0].tolist(), "P": P[0].tolist(),
                "model": self.kind.label(bool(man[0])), "maneuver": bool(man[0])}


def take_checked(filt: RadarFilter, m: Measurement, failed: bool,
                 where: str = "measurement") -> tuple[RadarFilter, dict[str, Any] | None]:
    """The filter after measurement ``m`` and its estimate (None while it initializes), by the radar
    local filter's rule for a measurement it cannot process (:meth:`RadarFilter.take`'s
    :class:`Numerical`): the first in a row is refused (raised, ``filt`` as it was); the second
    (``failed``: the last one was refused) starts the filter again from it (a new filter returned):
    predicted over a pause of 3,000 s the filter failed on every later scan, for good."""
    try:
        return filt, filt.take(m, where)
    except Numerical:
        if not failed:
            raise
    fresh = filt.afresh()
    return fresh, fresh.take(m, where)


def make_radar_filter(name: str, config: dict[str, Any] | EkfConfig | None = None,
                      folder: Path | None = None) -> RadarFilter:
    """A :class:`RadarFilter` for algorithm ``name`` from a ``[radar_filter]`` table (strict keys) or object;
    a relative ``model`` path is taken in ``folder``, the configuration file's (None: the working directory),
    as ``[zenoh] tls_dir`` is."""
    if name not in CONFIG_CLASSES:
        raise ConfigError(f"algorithm: unknown radar filter {name!r} (expected one of {ALGORITHMS})")
    cls = CONFIG_CLASSES[name]
    cfg = config if isinstance(config, EkfConfig) else parse_dataclass(cls, config or {}, "radar_filter")
    if isinstance(config, dict) and "window" in config and "window_s" in config:  # keys of ekf-ie only
        raise ConfigError("radar_filter.window: given with window_s (the window in scans or in seconds, not both)")
    if type(cfg) is not cls:
        raise ConfigError(f"config for {name} must be a {cls.__name__}")
    if isinstance(cfg, EkfTsFuzzyConfig) and cfg.model and folder is not None:
        cfg = replace(cfg, model=str(folder / cfg.model))  # an absolute model stays as it is
    return RadarFilter(name, cfg)
