"""The transport-free engine: per-sensor screening, compensator, direction and health.

Bag replay and both live transports (rclpy node, DDS) feed the same ``Engine``, so a bag
replayed through the node logic gives the numbers ``replay`` gives (DESIGN.md).

Per sample, in this order:

1. Input conversion: ``input.kind: divider`` readings [V] become ohm through
   R = R1 (Vin - V_R1) / V_R1 (apl_electrolycra... section II.A); V_R1 <= 0 is an open
   circuit and V_R1 >= Vin a short.
2. Screening (``Status``): not finite, R <= 0 ohm, open circuit (R > ``OPEN_FACTOR`` x the
   top of the calibration's resistance range), short (0 < R < ``SHORT_FACTOR`` x its bottom),
   time not past the last good sample. These are *bad*: counted per kind, never fed to the
   model or the detector; the output holds the last good estimate (NaN strain and direction
   0 before the first good sample).
3. Long gaps: a good sample more than ``gap_reset`` seconds after the last good one, or
   that far *before* it (a bag loop or a sim-time reset), resets model and detector first
   (status ``GAP_RESET``, counted in ``n_gaps``). Smaller backward steps are rejected.
4. Out of range: R outside the valid resistance range widened by ``RANGE_MARGIN`` of its
   span is flagged (status ``OUT_OF_RANGE``) but still fed to the model, whose state must
   follow the sensor; the estimate of every sample is clamped to the valid strain range
   widened by the same margin, so it is never silently extrapolated far.
5. The direction output comes from a ``DirectionDetector`` with the calibration's settings
   (dead zone scaled by ``deadzone_scale``), multiplied by ``direction.sign`` so that +1
   is loading (strain rising) also for a sensor whose R falls with strain; the models that
   switch on direction (rational, spike_decay) run their own detector with the unscaled
   settings on the raw dR/dt sign, as they were fitted.
6. Effect terms (``strain_comp.core.effects``) correct the clamped estimate and see the
   published direction; their state is reset with the model's at a gap reset. In an array
   (``step_array``, ``run_array``) a cross-talk term reads its neighbours' clamped
   pre-effect estimate of the same tick (NaN, i.e. held, where that sample was bad).

``run`` (batch) equals repeated ``step`` exactly: screening is one sequential numba pass
(the same rule function ``step`` calls), then the model's ``run`` over each run of used
samples between resets, then the effect terms over the same runs, and the held outputs are
a forward fill. ``run_array`` equals ``step_array`` tick by tick in the same way.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.chain import pair_means
from strain_comp.core.conversion import divider_to_resistance, resistance_to_divider
from strain_comp.core.direction import (
    STATE_SIZE,
    DirectionDetector,
    DirectionSettings,
    direction_update,
)
from strain_comp.core.effects import EffectTerms, run_segments
from strain_comp.core.samples import SampleStatus
from strain_comp.errors import InputError, ParameterError
from strain_comp.models.base import Compensator

OPEN_FACTOR = 100.0
"""R above this many times the top of the valid resistance range is an open circuit."""
SHORT_FACTOR = 0.01
"""0 < R below this fraction of the bottom of the valid resistance range is a short."""
RANGE_MARGIN = 0.05
"""Fraction of the valid range's span added on each side before flagging / clamping."""
GAP_RESET = 5.0
"""Default ``gap_reset`` [s]: a longer jump between good samples resets the state."""
APL_FAMILY = frozenset({"apl", "pl", "mpi"})


class Status(IntEnum):
    """Per-sample status (the ``/NAME/status`` value in replay output).

    0-3 are ``strain_comp.core.samples.SampleStatus``; 0, 6, 7 are *used* samples (fed to the
    model), 1-5 are bad samples (held estimate).
    """

    GOOD = SampleStatus.GOOD
    NOT_FINITE = SampleStatus.NOT_FINITE
    NON_POSITIVE = SampleStatus.NON_POSITIVE
    TIME_NOT_INCREASING = SampleStatus.TIME_NOT_INCREASING
    OPEN_CIRCUIT = 4
    SHORT_CIRCUIT = 5
    GAP_RESET = 6
    OUT_OF_RANGE = 7


USED = frozenset({Status.GOOD, Status.GAP_RESET, Status.OUT_OF_RANGE})
"""The statuses of samples fed to the model (all others are bad: estimate held)."""
_DIAG_OK, _DIAG_WARN, _DIAG_ERROR, _DIAG_STALE = 0, 1, 2, 3
LEVEL_NAMES = {_DIAG_OK: "OK", _DIAG_WARN: "WARN", _DIAG_ERROR: "ERROR", _DIAG_STALE: "STALE"}


def used_mask(status: npt.ArrayLike) -> np.ndarray:
    """True where a sample's ``Status`` is in ``USED`` (it was fed to the model)."""
    status = np.asarray(status)
    return (status == Status.GOOD) | (status >= Status.GAP_RESET)


@njit
def _screen_one(t: float, r: float, forced: int, last_good_t: float, r_short: float,
                r_open: float, r_lo: float, r_hi: float, gap: float) -> tuple[int, bool]:
    """Status of one sample and whether it resets the state (rules in the module doc)."""
    if not (math.isfinite(t) and math.isfinite(r)):
        return 1 if forced == 0 else forced, False
    if forced != 0:
        return forced, False
    if r <= 0.0:
        return 2, False
    if r > r_open:
        return 4, False
    if r < r_short:
        return 5, False
    reset = False
    if last_good_t > -math.inf:
        if t <= last_good_t - gap or t - last_good_t > gap:
            reset = True
        elif t <= last_good_t:
            return 3, False
    if r < r_lo or r > r_hi:
        return 7, reset
    return (6 if reset else 0), reset


@njit
def _screen_all(t: np.ndarray, r: np.ndarray, forced: np.ndarray, last_good_t: float,
                r_short: float, r_open: float, r_lo: float, r_hi: float,
                gap: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``_screen_one`` over a sequence; returns (status, reset, last good time)."""
    n = t.size
    status = np.empty(n, dtype=np.int8)
    reset = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        code, rst = _screen_one(t[i], r[i], forced[i], last_good_t, r_short, r_open,
                                r_lo, r_hi, gap)
        status[i] = code
        reset[i] = rst
        if code == 0 or code >= 6:
            last_good_t = t[i]
    return status, reset, last_good_t


@njit
def _screen_vec(t: float, r: np.ndarray, forced: np.ndarray, last_good_t: np.ndarray,
                r_short: np.ndarray, r_open: np.ndarray, r_lo: np.ndarray, r_hi: np.ndarray,
                gap: float) -> tuple[np.ndarray, np.ndarray]:
    """``_screen_one`` across the sensors of an array at one tick (updates last_good_t)."""
    n = r.size
    status = np.empty(n, dtype=np.int8)
    reset = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        code, rst = _screen_one(t, r[i], forced[i], last_good_t[i], r_short[i], r_open[i],
                                r_lo[i], r_hi[i], gap)
        status[i] = code
        reset[i] = rst
        if code == 0 or code >= 6:
            last_good_t[i] = t
    return status, reset


@dataclass
class SensorHealth:
    """Counters of one sensor since start (or ``reset``) and its current state."""

    n_good: int = 0
    n_nan: int = 0
    n_non_positive: int = 0
    n_time_backwards: int = 0
    n_open: int = 0
    n_short: int = 0
    n_out_of_range: int = 0
    n_gaps: int = 0
    last_good_t: float | None = None
    last_status: Status | None = None
    stale: bool = False

    @property
    def n_bad(self) -> int:
        """Samples rejected (held estimate) of any kind."""
        return (self.n_nan + self.n_non_positive + self.n_time_backwards + self.n_open
                + self.n_short)

    def to_diagnostic(self) -> tuple[int, str, dict[str, str]]:
        """(level, message, key-values) as diagnostic_msgs/DiagnosticStatus carries them.

        STALE: no good sample for longer than ``stale_after`` (as of ``health(now)``);
        ERROR: the latest sample was rejected (the estimate is being held); WARN: the
        latest sample was out of range or followed a gap reset; OK otherwise.
        """
        last = self.last_status
        if self.stale:
            level, message = _DIAG_STALE, "stale: no good sample recently"
        elif last is None:
            level, message = _DIAG_WARN, "no sample yet"
        elif last not in USED:
            level, message = _DIAG_ERROR, f"bad input ({last.name.lower()}): estimate held"
        elif last is Status.OUT_OF_RANGE:
            level, message = _DIAG_WARN, "resistance out of the calibrated range"
        elif last is Status.GAP_RESET:
            level, message = _DIAG_WARN, "state reset after a gap"
        else:
            level, message = _DIAG_OK, "ok"
        values = {
            "n_good": self.n_good, "n_nan": self.n_nan, "n_non_positive": self.n_non_positive,
            "n_time_backwards": self.n_time_backwards, "n_open": self.n_open,
            "n_short": self.n_short, "n_out_of_range": self.n_out_of_range,
            "n_gaps": self.n_gaps,
            "last_good_t": "none" if self.last_good_t is None else repr(self.last_good_t),
            "last_status": "none" if last is None else last.name,
        }
        return level, message, {k: str(v) for k, v in values.items()}


@dataclass(frozen=True)
class SensorOutput:
    """One sample's result: strain [%] (held if bad), direction (+1/0/-1), status, flag."""

    strain: float
    direction: int
    status: Status
    out_of_range: bool


@dataclass(frozen=True)
class ArrayOutput:
    """One array tick's result, in the array's sensor order."""

    strain: np.ndarray
    direction: np.ndarray
    status: np.ndarray
    out_of_range: np.ndarray


@dataclass(frozen=True)
class BatchOutput:
    """``run``'s result: one entry per input sample."""

    strain: np.ndarray
    direction: np.ndarray
    status: np.ndarray
    out_of_range: np.ndarray


@dataclass
class _Pending:
    """One used sample after screening, model and detector, before the effect terms."""

    t: float
    r: float
    status: Status
    strain: float
    direction: int

    def base(self, sensor: _Sensor) -> float:
        """The clamped pre-effect estimate (what neighbours' cross-talk terms read)."""
        return min(max(self.strain, sensor.s_lo), sensor.s_hi)


@dataclass
class _PendingBatch:
    """``run``'s first stage: screening, model and detector over a batch."""

    t: np.ndarray
    ohm: np.ndarray
    temperature: np.ndarray
    status: np.ndarray
    reset: np.ndarray
    last_good_t: float
    idx: np.ndarray
    """Indices of the used samples."""
    bounds: list[int]
    """Segment bounds in ``idx`` (a reset starts a segment)."""
    strain_used: np.ndarray
    dir_used: np.ndarray

    def base(self, sensor: _Sensor) -> np.ndarray:
        """Clamped pre-effect estimate at every sample, NaN where the sample was bad."""
        out = np.full(self.t.size, np.nan)
        out[self.idx] = np.clip(self.strain_used, sensor.s_lo, sensor.s_hi)
        return out


_COUNTER = {Status.NOT_FINITE: "n_nan", Status.NON_POSITIVE: "n_non_positive",
            Status.TIME_NOT_INCREASING: "n_time_backwards", Status.OPEN_CIRCUIT: "n_open",
            Status.SHORT_CIRCUIT: "n_short", Status.OUT_OF_RANGE: "n_out_of_range"}


@dataclass
class _Sensor:
    """Everything the engine keeps for one sensor."""

    cal: SensorCalibration
    model: Compensator
    detector: DirectionDetector
    r_short: float
    r_open: float
    r_lo: float
    r_hi: float
    s_lo: float
    s_hi: float
    health: SensorHealth = field(default_factory=SensorHealth)
    last_good_t: float = -math.inf
    strain: float = math.nan
    direction: int = 0
    effects: EffectTerms = field(default_factory=lambda: EffectTerms([], [], []))
    base: float = math.nan
    """Latest clamped strain before effect terms (what neighbours' cross-talk terms read)."""
    gain: float = 1.0
    """Input gain (tare): the models see ``gain`` x the measured resistance."""
    previous: float = math.nan
    """Latest used resistance [ohm] (for pair means when the input alternates)."""

    def pair(self, ohm: np.ndarray, previous: float) -> np.ndarray:
        """What the models see of used samples ``ohm``: pair means when the calibration's
        input alternates (``strain_comp.core.chain``), else ``ohm``; ``previous``: the used
        sample before them (NaN after a reset)."""
        if not self.cal.input.alternation or not ohm.size:
            return ohm
        self.previous = float(ohm[-1])
        return pair_means(ohm, previous)

    @classmethod
    def build(cls, cal: SensorCalibration, deadzone_scale: float) -> _Sensor:
        vr = cal.valid_range
        r_margin = RANGE_MARGIN * (vr.r_hi - vr.r_lo)
        s_margin = RANGE_MARGIN * (vr.s_hi - vr.s_lo)
        return cls(cal=cal, model=cal.build_model(),
                   detector=DirectionDetector(_scaled(cal.direction, deadzone_scale)),
                   r_short=SHORT_FACTOR * vr.r_lo, r_open=OPEN_FACTOR * vr.r_hi,
                   r_lo=vr.r_lo - r_margin, r_hi=vr.r_hi + r_margin,
                   s_lo=vr.s_lo - s_margin, s_hi=vr.s_hi + s_margin,
                   effects=EffectTerms.from_dicts(cal.effects))

    def to_ohm(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(resistance [ohm] x the tare gain, forced status) from the raw input values."""
        forced = np.zeros(raw.shape, dtype=np.int8)
        if self.cal.input.kind != "divider":
            return raw * self.gain if self.gain != 1.0 else raw, forced
        vin = float(self.cal.input.vin)
        forced[raw <= 0.0] = Status.OPEN_CIRCUIT
        forced[raw >= vin] = Status.SHORT_CIRCUIT
        return divider_to_resistance(raw, float(self.cal.input.r1), vin) * self.gain, forced

    def mid_raw(self) -> float:
        """A raw input value in the middle of the valid range (for warming up kernels)."""
        r_mid = 0.5 * (self.cal.valid_range.r_lo + self.cal.valid_range.r_hi)
        if self.cal.input.kind != "divider":
            return r_mid
        return float(resistance_to_divider(r_mid, float(self.cal.input.r1),
                                           float(self.cal.input.vin)))

    def count(self, status: np.ndarray) -> None:
        """Add a batch's statuses to the counters."""
        h = self.health
        _add_counts(h, np.bincount(status.astype(np.intp), minlength=len(Status)))
        if status.size:
            h.last_status = Status(int(status[-1]))


def _add_counts(h: SensorHealth, counts: np.ndarray) -> None:
    """Add per-``Status`` sample counts (indexed by status code) to ``h``'s counters."""
    h.n_good += int(sum(counts[code] for code in USED))
    for code, name in _COUNTER.items():
        setattr(h, name, getattr(h, name) + int(counts[code]))


def _scaled(settings: DirectionSettings, scale: float) -> DirectionSettings:
    return replace(settings, deadzone=settings.deadzone * scale)


class Engine:
    """Calibrated strain, direction and health for every sensor of a calibration.

    ``arrays`` maps an array name to its ordered sensor names (all in ``calibration``).
    ``gap_reset`` [s]: a larger jump between good samples resets model and detector;
    ``stale_after`` [s]: ``health(now)`` reports a sensor stale after that long without a
    good sample; ``deadzone_scale`` multiplies every direction dead zone.
    """

    def __init__(self, calibration: Calibration, *,
                 arrays: Mapping[str, Sequence[str]] | None = None, gap_reset: float = GAP_RESET,
                 stale_after: float = 1.0, deadzone_scale: float = 1.0) -> None:
        if not gap_reset > 0:
            raise ParameterError("gap_reset", f"must be > 0 s, got {gap_reset}")
        if not deadzone_scale > 0:
            raise ParameterError("deadzone_scale", f"must be > 0, got {deadzone_scale}")
        self.calibration = calibration
        self.gap_reset = float(gap_reset)
        self.stale_after = float(stale_after)
        self.deadzone_scale = float(deadzone_scale)
        self._sensors = {name: _Sensor.build(cal, self.deadzone_scale)
                         for name, cal in calibration.sensors.items()}
        self._arrays: dict[str, _ArrayGroup] = {}
        for array, names in (arrays or {}).items():
            missing = [n for n in names if n not in self._sensors]
            if missing or not names:
                raise InputError(f"array {array!r}: sensors {missing or '(none)'} are not in "
                                 f"the calibration (known: {', '.join(self._sensors)})")
            self._arrays[array] = _ArrayGroup(self, list(names))

    @property
    def sensors(self) -> list[str]:
        """Sensor names, in calibration order."""
        return list(self._sensors)

    @property
    def arrays(self) -> dict[str, list[str]]:
        """Array names -> ordered sensor names."""
        return {name: list(group.names) for name, group in self._arrays.items()}

    def _sensor(self, name: str) -> _Sensor:
        try:
            return self._sensors[name]
        except KeyError:
            raise InputError(f"unknown sensor {name!r} (known: {', '.join(self._sensors)})") \
                from None

    def reset(self) -> None:
        """Fresh model and detector state, zeroed counters, no held output (tare gains kept)."""
        self._sensors = {name: replace(_Sensor.build(s.cal, self.deadzone_scale), gain=s.gain)
                         for name, s in self._sensors.items()}
        for group in self._arrays.values():
            group.rebuild()

    def input_gain(self, sensor: str) -> float:
        """The tare gain of ``sensor``: its models see this x the measured resistance."""
        return self._sensor(sensor).gain

    def tare(self, sensor: str, rest_resistance: float) -> float:
        """Make ``rest_resistance`` [ohm] (measured now, at rest) this sensor's zero.

        Multiplicative: the models see R x (calibration's rest resistance / rest_resistance).
        Returns the new gain; ``ParameterError`` if the calibration stores no rest resistance
        or the value is not finite and > 0 (the old gain then stays).
        """
        reference = self._sensor(sensor).cal.rest_resistance
        if reference is None:
            raise ParameterError(f"{sensor}.rest_resistance",
                                 "the calibration stores none, so it cannot be tared")
        if not (math.isfinite(rest_resistance) and rest_resistance > 0):
            raise ParameterError(f"{sensor}.tare", f"rest resistance must be finite and > 0 "
                                 f"ohm, got {rest_resistance}")
        gain = reference / rest_resistance
        self.set_input_gain(sensor, gain)
        return gain

    def set_input_gain(self, sensor: str, gain: float) -> None:
        """Set the tare gain of ``sensor`` (effective from the next sample; state kept)."""
        if not (math.isfinite(gain) and gain > 0):
            raise ParameterError(f"{sensor}.input_gain", f"must be finite and > 0, got {gain}")
        self._sensor(sensor).gain = float(gain)
        for group in self._arrays.values():
            if sensor in group.names and group.kernel is not None:
                group.gain[group.names.index(sensor)] = float(gain)

    def set_deadzone_scale(self, scale: float) -> None:
        """Change the dead-zone scale (a node tunable); the detectors restart from rest."""
        if not scale > 0:
            raise ParameterError("deadzone_scale", f"must be > 0, got {scale}")
        self.deadzone_scale = float(scale)
        for sensor in self._sensors.values():
            sensor.detector = DirectionDetector(_scaled(sensor.cal.direction, scale))
        for group in self._arrays.values():
            if group.kernel is not None:
                group.set_deadzone_scale(scale)

    def _apply_effects(self, sensor: _Sensor, t: np.ndarray, r: np.ndarray, strain: np.ndarray,
                       direction: np.ndarray, temperature: np.ndarray,
                       neighbours: Mapping[str, np.ndarray] | None = None,
                       starts: Sequence[int] = ()) -> np.ndarray:
        """The one place where a calibration's effect terms correct the strain.

        The terms (``strain_comp.core.effects``) read the model's estimate clamped to the valid
        strain range, as ``strain_comp.diagnosis.loop`` fitted them. ``neighbours``: array
        neighbours' clamped pre-effect strain at these samples; where not given, each
        neighbour's latest value is held. ``starts``: sample positions where a gap reset
        starts a new segment: the terms' state is reset there, as the model's is.
        """
        base = np.clip(strain, sensor.s_lo, sensor.s_hi)
        given = neighbours or {}
        nbrs = {n: given[n] if n in given else np.full(t.size, self._base_strain(n))
                for n in sensor.effects.neighbours}
        sensor.base = float(base[-1])
        return run_segments(
            lambda k: sensor.effects.run(t[k], r[k], base[k], direction[k], temperature[k],
                                         {n: v[k] for n, v in nbrs.items()}),
            sensor.effects.reset, t.size, starts)

    def _base_strain(self, name: str) -> float:
        """A sensor's latest clamped strain before its effect terms (NaN if unknown)."""
        other = self._sensors.get(name)
        if other is None:
            return math.nan
        return other.base if other.effects else other.strain

    def step(self, sensor: str, t: float, r: float, temperature: float = math.nan) -> SensorOutput:
        """One sample of one sensor: time [s], raw input (ohm or divider volts)."""
        s = self._sensor(sensor)
        pending = self._step_model(s, float(t), float(r))
        if isinstance(pending, SensorOutput):
            return pending
        return self._step_finish(s, pending, float(temperature))

    def _step_model(self, s: _Sensor, t: float, raw: float) -> SensorOutput | _Pending:
        """Screening, gap reset, detector and model of one sample (a bad one: its output)."""
        forced = 0
        if s.cal.input.kind == "divider":
            r_arr, f_arr = s.to_ohm(np.array([raw]))
            raw, forced = float(r_arr[0]), int(f_arr[0])
        else:
            raw *= s.gain
        code, reset = _screen_one(t, raw, forced, s.last_good_t, s.r_short, s.r_open,
                                  s.r_lo, s.r_hi, self.gap_reset)
        status = Status(code)
        h = s.health
        if status not in USED:
            setattr(h, _COUNTER[status], getattr(h, _COUNTER[status]) + 1)
            h.last_status = status
            return SensorOutput(s.strain, s.direction, status, False)
        if reset:
            s.model.reset()
            s.detector.reset()
            s.effects.reset()
            h.n_gaps += 1
        raw = float(s.pair(np.array([raw]), math.nan if reset else s.previous)[0])
        direction = int(s.detector.step(t, raw)) * s.cal.direction.sign
        return _Pending(t, raw, status, float(s.model.step(t, raw)), direction)

    def _step_finish(self, s: _Sensor, p: _Pending, temperature: float,
                     neighbours: Mapping[str, float] | None = None) -> SensorOutput:
        """Effect terms, clamping, held output and counters of one used sample."""
        t, raw, status, strain, direction = p.t, p.r, p.status, p.strain, p.direction
        if s.cal.effects:
            nbrs = {n: np.array([v]) for n, v in (neighbours or {}).items()}
            strain = float(self._apply_effects(s, np.array([t]), np.array([raw]),
                                               np.array([strain]), np.array([direction]),
                                               np.array([temperature]), nbrs)[0])
        strain = min(max(strain, s.s_lo), s.s_hi)
        h = s.health
        s.last_good_t = t
        s.strain, s.direction = strain, direction
        h.n_good += 1
        h.last_good_t = t
        h.last_status = status
        if status is Status.OUT_OF_RANGE:
            h.n_out_of_range += 1
        return SensorOutput(strain, direction, status, status is Status.OUT_OF_RANGE)

    def run(self, sensor: str, t: npt.ArrayLike, r: npt.ArrayLike,
            temperature: npt.ArrayLike | None = None, *,
            neighbours: Mapping[str, npt.ArrayLike] | None = None) -> BatchOutput:
        """Batch path over whole arrays; identical to ``step`` sample by sample.

        ``neighbours``: for cross-talk effect terms, the named array neighbours' clamped
        pre-effect strain at the times ``t`` (else their latest values are held).
        """
        s = self._sensor(sensor)
        pending = self._run_model(s, t, r, temperature)
        nbrs = {n: np.asarray(v, dtype=np.float64) for n, v in (neighbours or {}).items()}
        return self._run_finish(s, pending, nbrs)

    def run_array(self, sensors: Sequence[str], t: npt.ArrayLike, r: npt.ArrayLike,
                  temperature: Mapping[str, npt.ArrayLike | None] | None = None
                  ) -> dict[str, BatchOutput]:
        """Batch path for sensors sampled together (an array topic): ``r`` is (n, k) in the
        order of ``sensors``. Equal, tick by tick, to ``step_array``: every cross-talk term
        reads its neighbours' clamped pre-effect estimate of the same tick."""
        r = np.asarray(r, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != len(sensors):
            raise InputError(f"run_array: r must be (n, {len(sensors)}), got shape {r.shape}")
        temps = temperature or {}
        pending = {name: self._run_model(self._sensor(name), t, r[:, j], temps.get(name))
                   for j, name in enumerate(sensors)}
        bases = {name: p.base(self._sensors[name]) for name, p in pending.items()}
        return {name: self._run_finish(self._sensors[name], p, bases)
                for name, p in pending.items()}

    def _run_model(self, s: _Sensor, t: npt.ArrayLike, r: npt.ArrayLike,
                   temperature: npt.ArrayLike | None) -> _PendingBatch:
        """``run``'s first stage: screening, gap resets, detector and model."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        raw = np.ascontiguousarray(r, dtype=np.float64)
        if t.ndim != 1 or t.shape != raw.shape:
            raise InputError("run: t and r must be 1-D arrays of one length")
        temp = (np.full(t.shape, np.nan) if temperature is None
                else np.ascontiguousarray(temperature, dtype=np.float64))
        ohm, forced = s.to_ohm(raw)
        status, reset, last_good_t = _screen_all(t, ohm, forced, s.last_good_t, s.r_short,
                                                 s.r_open, s.r_lo, s.r_hi, self.gap_reset)
        used = used_mask(status)
        idx = np.flatnonzero(used)
        if s.cal.input.alternation:
            ohm = ohm.copy()  # pair means replace the used samples below; raw stays intact
        strain_used = np.empty(idx.size)
        dir_used = np.empty(idx.size, dtype=np.int8)
        bounds = [0, *np.flatnonzero(reset[idx]).tolist(), idx.size]
        for k, (a, b) in enumerate(itertools.pairwise(bounds)):
            if b == a:
                continue
            if k > 0:
                s.model.reset()
                s.detector.reset()
            seg = idx[a:b]
            ohm[seg] = s.pair(ohm[seg], s.previous if k == 0 else math.nan)
            dir_used[a:b] = s.detector.run(t[seg], ohm[seg])
            strain_used[a:b] = s.model.run(t[seg], ohm[seg])
        if s.cal.direction.sign < 0:
            dir_used = -dir_used
        return _PendingBatch(t, ohm, temp, status, reset, last_good_t, idx, bounds,
                             strain_used, dir_used)

    def _run_finish(self, s: _Sensor, p: _PendingBatch,
                    neighbours: Mapping[str, np.ndarray]) -> BatchOutput:
        """``run``'s second stage: effect terms, clamping, held outputs and counters."""
        t, status, reset, last_good_t, idx = p.t, p.status, p.reset, p.last_good_t, p.idx
        strain_used, dir_used = p.strain_used, p.dir_used
        used = used_mask(status)
        if s.cal.effects and idx.size:
            nbrs = {n: v[idx] for n, v in neighbours.items()}
            starts = p.bounds[1:-1]  # a reset at the first sample resets at once
            strain_used = self._apply_effects(s, t[idx], p.ohm[idx], strain_used, dir_used,
                                              p.temperature[idx], nbrs, starts)
        np.clip(strain_used, s.s_lo, s.s_hi, out=strain_used)
        # held outputs: each sample shows the latest used sample at or before it
        rank = np.cumsum(used) - 1
        if idx.size:
            take = np.maximum(rank, 0)
            strain = np.where(rank < 0, s.strain, strain_used[take])
            direction = np.where(rank < 0, s.direction, dir_used[take]).astype(np.int8)
        else:
            strain = np.full(t.size, s.strain)
            direction = np.full(t.size, s.direction, dtype=np.int8)
        s.count(status)
        s.health.n_gaps += int(np.count_nonzero(reset))
        if idx.size:
            s.last_good_t = last_good_t
            s.health.last_good_t = last_good_t
            s.strain, s.direction = float(strain_used[-1]), int(dir_used[-1])
        return BatchOutput(strain.astype(np.float64), direction, status,
                           status == Status.OUT_OF_RANGE)

    def step_array(self, array: str, t: float, r_vector: npt.ArrayLike) -> ArrayOutput:
        """One tick of an array: ``r_vector`` in the array's sensor order."""
        try:
            group = self._arrays[array]
        except KeyError:
            raise InputError(f"unknown array {array!r} (known: {', '.join(self._arrays)})") \
                from None
        raw = np.asarray(r_vector, dtype=np.float64)
        if raw.shape != (len(group.names),):
            raise InputError(f"array {array!r}: expected {len(group.names)} values, "
                             f"got shape {raw.shape}")
        return group.step(float(t), raw)

    def health(self, now: float | None = None) -> dict[str, SensorHealth]:
        """Copies of every sensor's counters; with ``now`` [s], stale is evaluated."""
        kernel_health: dict[str, SensorHealth] = {}
        for group in self._arrays.values():
            if group.kernel is not None:
                kernel_health.update(group.health())
        out = {}
        for name, s in self._sensors.items():
            h = kernel_health.get(name) or replace(s.health)
            if now is not None:
                h.stale = h.last_good_t is None or now - h.last_good_t > self.stale_after
            out[name] = h
        return out

    def warm_up(self) -> None:
        """Compile every kernel now (not on the first message): run a copy of the engine."""
        spare = Engine(self.calibration, arrays=self.arrays, gap_reset=self.gap_reset,
                       deadzone_scale=self.deadzone_scale)
        mid = {name: s.mid_raw() for name, s in spare._sensors.items()}
        for name, value in mid.items():
            spare.step(name, 0.0, value)
            spare.run(name, np.array([1.0, 2.0]), np.array([value, value]))
        for array, names in spare.arrays.items():
            spare.step_array(array, 3.0, np.array([mid[n] for n in names]))


@njit
def _direction_array(states: np.ndarray, t: float, r: np.ndarray, used: np.ndarray,
                     deadzone: np.ndarray, tau: np.ndarray, held: np.ndarray) -> None:
    """Step every used sensor's detector (row of ``states``); ``held`` gets the outputs."""
    for k in range(r.size):
        if used[k]:
            held[k] = direction_update(states[k], t, r[k], deadzone[k], tau[k])


class _ArrayGroup:
    """The sensors of one array, stepped together.

    When every sensor is of the APL family (same N and M), one tick is one call of helper
    A's ``APLArray`` kernel plus one screening and one detector kernel for all sensors; the
    group then keeps the array's state, counters and held outputs itself, and its sensors
    should not also be fed through ``Engine.step``. Otherwise a loop of ``Engine.step``.
    """

    def __init__(self, engine: Engine, names: list[str]) -> None:
        self.engine = engine
        self.names = names
        self.kernel: Any = None
        self.rebuild()

    def rebuild(self) -> None:
        """(Re)build from the engine's sensors: fresh state, zero counters."""
        self.sensors = [self.engine._sensors[n] for n in self.names]
        self.kernel = None
        if not all(s.cal.model in APL_FAMILY and not s.cal.input.alternation
                   for s in self.sensors):
            return
        from strain_comp.models.apl import APLArray

        try:
            self.kernel = APLArray.from_models([s.model for s in self.sensors])
        except ParameterError:  # different N or M: fall back to the loop
            return
        k = len(self.sensors)
        self.r_short, self.r_open, self.r_lo, self.r_hi, self.s_lo, self.s_hi = (
            np.array([getattr(s, attr) for s in self.sensors])
            for attr in ("r_short", "r_open", "r_lo", "r_hi", "s_lo", "s_hi"))
        self.last_good_t = np.full(k, -math.inf)
        self.strain = np.full(k, math.nan)
        self.direction = np.zeros(k, dtype=np.int8)
        self.counts = np.zeros((k, len(Status)), dtype=np.int64)
        self.gaps = np.zeros(k, dtype=np.int64)
        self.last_status = np.full(k, -1, dtype=np.int8)
        self.states = np.zeros((k, STATE_SIZE))
        self.tau = np.array([s.cal.direction.tau for s in self.sensors])
        self.sign = np.array([s.cal.direction.sign for s in self.sensors], dtype=np.int8)
        self.set_deadzone_scale(self.engine.deadzone_scale)
        self.divider = [i for i, s in enumerate(self.sensors) if s.cal.input.kind == "divider"]
        self.gain = np.array([s.gain for s in self.sensors])
        self.effects = [i for i, s in enumerate(self.sensors) if s.cal.effects]

    def set_deadzone_scale(self, scale: float) -> None:
        self.deadzone = np.array([s.cal.direction.deadzone * scale for s in self.sensors])
        self.states[:] = 0.0

    def step(self, t: float, raw: np.ndarray) -> ArrayOutput:
        if self.kernel is None:
            engine = self.engine
            pending = [engine._step_model(s, t, float(value))
                       for s, value in zip(self.sensors, raw, strict=True)]
            bases = {name: p.base(s) if isinstance(p, _Pending) else math.nan
                     for name, s, p in zip(self.names, self.sensors, pending, strict=True)}
            outputs = [p if isinstance(p, SensorOutput) else
                       engine._step_finish(s, p, math.nan, bases)
                       for s, p in zip(self.sensors, pending, strict=True)]
            return ArrayOutput(np.array([o.strain for o in outputs]),
                               np.array([o.direction for o in outputs], dtype=np.int8),
                               np.array([o.status for o in outputs], dtype=np.int8),
                               np.array([o.out_of_range for o in outputs]))
        ohm = raw * self.gain
        forced = np.zeros(raw.size, dtype=np.int8)
        for i in self.divider:
            conv, code = self.sensors[i].to_ohm(raw[i:i + 1])
            ohm[i], forced[i] = conv[0], code[0]
        status, reset = _screen_vec(t, ohm, forced, self.last_good_t, self.r_short,
                                    self.r_open, self.r_lo, self.r_hi, self.engine.gap_reset)
        used = used_mask(status)
        if reset.any():
            self.kernel.x[reset] = 0.0  # the state APLArray.reset() clears, for these rows
            self.kernel.clock[reset] = 0.0
            self.states[reset] = 0.0
            self.gaps += reset
            for i in np.flatnonzero(reset):
                self.sensors[i].effects.reset()
        strain = self.kernel.step(t, np.where(used, ohm, math.nan))
        _direction_array(self.states, t, ohm, used, self.deadzone, self.tau, self.direction)
        direction = self.direction * self.sign
        base = np.clip(np.where(used, strain, np.nan), self.s_lo, self.s_hi)
        for i in self.effects:
            if used[i]:
                nbrs = {n: base[self.names.index(n):self.names.index(n) + 1]
                        for n in self.sensors[i].effects.neighbours if n in self.names}
                strain[i] = self.engine._apply_effects(
                    self.sensors[i], np.array([t]), ohm[i:i + 1], strain[i:i + 1],
                    direction[i:i + 1], np.array([math.nan]), nbrs)[0]
        np.clip(strain, self.s_lo, self.s_hi, out=strain)
        self.strain = np.where(used, strain, self.strain)
        self.counts[np.arange(raw.size), status] += 1
        self.last_status = status
        return ArrayOutput(self.strain.copy(), direction, status,
                           status == Status.OUT_OF_RANGE)

    def health(self) -> dict[str, SensorHealth]:
        """Counters of the kernel path's sensors (only when ``kernel`` is set)."""
        out = {}
        for k, name in enumerate(self.names):
            h = SensorHealth(n_gaps=int(self.gaps[k]))
            _add_counts(h, self.counts[k])
            if self.last_good_t[k] > -math.inf:
                h.last_good_t = float(self.last_good_t[k])
            if self.last_status[k] >= 0:
                h.last_status = Status(int(self.last_status[k]))
            out[name] = h
        return out


def diagnostics(health: Mapping[str, SensorHealth], *, prefix: str = "strain_comp"
                ) -> list[tuple[str, int, str, dict[str, str]]]:
    """``(name, level, message, values)`` per sensor, as BagWriter and the nodes publish."""
    return [(f"{prefix}: {name}", *h.to_diagnostic()) for name, h in health.items()]

