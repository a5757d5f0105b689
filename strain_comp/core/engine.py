"""The transport-free engine: per-sensor screening, compensator, direction and health.

Bag replay and both live transports (rclpy node, DDS) feed the same ``Engine``, so a bag
replayed through the node logic gives the numbers ``replay`` gives (docs/design.md).

Per sample, in this order:

1. Input conversion: ``input.kind: divider`` readings [V] become ohm through
   R = R1 (Vin - V_R1) / V_R1 ([Electrolycra] section II.A); V_R1 <= 0 is an open
   circuit and V_R1 >= Vin a short.
2. Screening (``strain_comp.core.samples.screen_one``, the one rule the fit uses too;
   ``Status``, ``STATUS_RULES``): not finite, R <= 0 ohm, open circuit (R > ``OPEN_FACTOR`` x the
   top of the calibration's resistance range), short (0 < R < ``SHORT_FACTOR`` x its bottom),
   time not past the last good sample. These are *bad*: counted per kind, never fed to the
   model or the detector; the output holds the last good estimate (NaN strain and direction
   0 before the first good sample).
3. Long gaps: a good sample more than ``gap_reset`` seconds after the last good one, or
   that far *before* it (a bag loop or a sim-time reset), resets model and detector first
   (status ``GAP_RESET``, counted in ``n_gaps``). Smaller backward steps are rejected.
4. Out of range: R outside the valid resistance range widened by ``RANGE_MARGIN`` of its
   span is flagged (status ``OUT_OF_RANGE``) and still fed to the model; the estimate of
   every sample is clamped to the valid strain range widened by the same margin, and then,
   by ``out_of_range`` (``OUT_OF_RANGE_MODES``, default ``extend``), extended beyond it
   with a bounded slope within a bounded reach (the model reading R held at the range's
   end: ``_Sensor.bounded_slopes``), or with the model's end slope, or not. With an input
   filter (``input.alternation``, ``despike``, ``baseline_step``) the flag is taken on the
   filtered value the model reads (a pair mean, a removed spike), not on the raw sample.
5. The direction output comes from a ``DirectionDetector`` with the calibration's settings
   (dead zone scaled by ``deadzone_scale``), multiplied by ``direction.sign`` so that +1
   is loading (strain rising) also for a sensor whose R falls with strain; the models that
   switch on direction (rational, spike_decay) run their own detector with the unscaled
   settings on the raw dR/dt sign, as they were fitted.
6. Effect terms (``strain_comp.core.effects``) correct the clamped estimate and see the
   published direction; their state is reset with the model's at a gap reset. In an array
   (``step_array``, ``run_array``) a cross-talk term reads its neighbours' clamped
   pre-effect estimate of the same tick (NaN, i.e. held, where that sample was bad).

Between 3 and the model, the calibration's input corrections (``input.filtered``) act on
the used samples: pair means when the excitation alternates, then the spike and
baseline-step corrector (``strain_comp.core.chain.ChainCorrector``), so neither reaches a
model's or detector's state. Its state is kept across batches and ``step`` calls; a gap
reset restarts its references. An array with such a sensor runs the per-sensor path, not
the fused kernel.

``run`` (batch) equals repeated ``step`` exactly: screening is one sequential numba pass
(the same rule function ``step`` and the array tick call), then the model's ``run`` over
each run of used samples between resets, then the effect terms over the same runs, and the
held outputs are a forward fill. ``run_array`` equals ``step_array`` tick by tick in the same way.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.core import samples as sc
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.chain import DESPIKE_K, SPIKE, STEP, ChainCorrector, pair_values
from strain_comp.core.conversion import resistance_to_divider
from strain_comp.core.direction import (
    STATE_SIZE,
    DirectionDetector,
    DirectionSettings,
    direction_update,
)
from strain_comp.core.effects import EffectTerms, run_segments
from strain_comp.core.samples import STATUS_RULES, USED, USED_CODE, Status, screen_all, screen_one
from strain_comp.errors import InputError, ParameterError
from strain_comp.models._apl_kernels import step_sensor
from strain_comp.models.base import Compensator

OPEN_FACTOR = 100.0
"""R above this many times the top of the valid resistance range is an open circuit."""
SHORT_FACTOR = 0.01
"""0 < R below this fraction of the bottom of the valid resistance range is a short."""
RANGE_MARGIN = 0.05
"""Fraction of the valid range's span added on each side before flagging / clamping."""
OUT_OF_RANGE_MODES = ("clamp", "extrapolate", "extend")
"""Strain of a sample beyond the valid resistance range: clamped to the valid strain range
(plus the margin); or that plus the model's end slope times the resistance beyond it; or
that plus a bounded slope, within a bounded reach (``_Sensor.bounded_slopes``)."""
END_SPAN = 0.05
"""Share of the valid resistance range at each end over which the end slope is taken."""
DEFAULT_OUT_OF_RANGE = "extend"
"""Chosen on the generalisation benchmark (docs/generalisation.md): the lowest median and
worst ratio over every sensor and model on the headline workflow."""
EXTEND_SLOPE = (0.5, 2.0)
"""``extend``: the end slope is kept within these multiples of the secant slope."""
EXTEND_MONOTONE = 0.25
"""``extend``: a branch that ends this share of the strain span or more below the top of
the calibrated strain at the top of the resistance range (the resistance peaked before
the strain did) is not extended."""
EXTEND_REACH = 1.0
"""``extend``: calibrated strain spans the estimate reaches at most beyond the range."""
SETTLE = 200
"""Steps (at 10 Hz) of the slow ramp over the valid range the out-of-range slopes are read
on, each way (``_Sensor.branches``)."""
GAP_RESET = sc.DEFAULT_GAP_RESET
"""Default ``gap_reset`` [s]: a longer jump between good samples resets the state."""


_DIAG_OK, _DIAG_WARN, _DIAG_ERROR, _DIAG_STALE = 0, 1, 2, 3
LEVEL_NAMES = {_DIAG_OK: "OK", _DIAG_WARN: "WARN", _DIAG_ERROR: "ERROR", _DIAG_STALE: "STALE"}


def used_mask(status: npt.ArrayLike) -> np.ndarray:
    """True where a sample's ``Status`` is in ``USED`` (it was fed to the model)."""
    return USED_CODE[np.asarray(status)]


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
    n_spikes: int = 0
    """Isolated spikes the input corrector kept from the model (``input.despike``)."""
    n_baseline_steps: int = 0
    """Baseline steps it re-based (``input.baseline_step``: a connector re-seated?)."""
    last_good_t: float | None = None
    last_status: Status | None = None
    stale: bool = False
    baseline_tracked_s: float = 0.0
    """Seconds at rest over which baseline tracking moved the zero
    (``strain_comp.core.tracking``)."""
    baseline_correction: float = 0.0
    """Its total change of the tare gain (share: +0.02 is 2 % more gain)."""

    def count(self, status: Status, n: int = 1) -> None:
        """Add ``n`` samples of ``status`` to the counters (``STATUS_RULES``)."""
        used, counter = STATUS_RULES[status]
        if used:
            self.n_good += n
        if counter is not None:
            setattr(self, counter, getattr(self, counter) + n)

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
        values: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self)
                                     if f.name.startswith("n_")}
        values["last_good_t"] = "none" if self.last_good_t is None else repr(self.last_good_t)
        values["last_status"] = "none" if last is None else last.name
        if self.baseline_tracked_s > 0:
            values["baseline_tracked_s"] = f"{self.baseline_tracked_s:.6g}"
            values["baseline_correction"] = f"{self.baseline_correction:.6g}"
        return level, message, {k: str(v) for k, v in values.items()}


if {c for _, c in STATUS_RULES.values() if c} - {f.name for f in fields(SensorHealth)}:
    raise AssertionError("every counter of STATUS_RULES must be a SensorHealth field")


@dataclass(frozen=True)
class SensorOutput:
    """One sample's result: strain [%] (held if bad), direction (+1/0/-1), status, flag."""

    strain: float
    direction: int
    status: Status
    out_of_range: bool
    resistance: float = math.nan
    """The resistance [ohm] the model read (as ``BatchOutput.resistance``); NaN for a bad
    sample."""


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
    resistance: np.ndarray
    """The resistance [ohm] the model read at each used sample (converted, times the tare
    gain, after the input corrections: what effect terms read); other samples hold their
    converted input. Read-only: it may share memory with the caller's input."""
    reset: np.ndarray | None = None
    """True where a gap reset the state before the sample (counted in ``n_gaps``); None
    when not known (no resets assumed)."""
    corrections: np.ndarray | None = None
    """Where the input corrector removed a spike (``chain.SPIKE``) or confirmed a
    baseline step (``chain.STEP``), else 0; None without a corrector."""


def concatenate(outs: Sequence[BatchOutput]) -> BatchOutput:
    """One ``BatchOutput`` of consecutive ones (``run`` over pieces of a stream)."""
    def join(key: str) -> np.ndarray | None:
        values = [getattr(o, key) for o in outs]
        return None if any(v is None for v in values) else np.concatenate(values)

    return BatchOutput(*(join(f.name) for f in fields(BatchOutput)))  # type: ignore[arg-type]


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
    temperature: np.ndarray | None
    status: np.ndarray
    reset: np.ndarray
    last_good_t: float
    idx: np.ndarray
    """Indices of the used samples."""
    bounds: list[int]
    """Segment bounds in ``idx`` (a reset starts a segment)."""
    strain_used: np.ndarray
    dir_used: np.ndarray
    corrections: np.ndarray | None
    """The corrector's event per used sample (``BatchOutput.corrections``), if any."""

    def base(self, sensor: _Sensor) -> np.ndarray:
        """Clamped pre-effect estimate at every sample, NaN where the sample was bad."""
        out = np.full(self.t.size, np.nan)
        out[self.idx] = np.clip(self.strain_used, sensor.s_lo, sensor.s_hi)
        return out


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
    corrector: ChainCorrector | None = None
    """Spike and baseline-step correction when the calibration's input asks for it."""
    slopes: tuple[float, float] | None = None
    """(dS/dR at r_lo, at r_hi) beyond the valid range when the engine extends the estimate
    out of range (``OUT_OF_RANGE_MODES``), else None (clamped)."""
    reach: tuple[float, float] = (-math.inf, math.inf)
    """Lowest and highest strain an extended estimate reaches (``extend``)."""
    saturate: bool = False
    """``extend``: the model reads the resistance clipped to the valid range, so that its
    output beyond the range is its output at the range's end (a polynomial that turns back
    past the end, or cells driven where no data were, do not move it)."""

    def model_input(self, ohm: np.ndarray) -> np.ndarray:
        """What the model reads of used samples ``ohm`` (``saturate``)."""
        return np.clip(ohm, self.r_lo, self.r_hi) if self.saturate else ohm

    def beyond(self, ohm: np.ndarray, strain: np.ndarray) -> np.ndarray:
        """``strain`` clamped to the strain range, plus, with ``slopes``, the slope times
        the resistance beyond the valid range (continuous at its ends), within ``reach``."""
        out = np.clip(strain, self.s_lo, self.s_hi)
        if self.slopes is None:
            return out
        lo, hi = self.slopes
        out = out + np.where(ohm > self.r_hi, hi * (ohm - self.r_hi), 0.0) \
            + np.where(ohm < self.r_lo, lo * (ohm - self.r_lo), 0.0)
        return np.clip(out, *self.reach)

    def branches(self) -> tuple[np.ndarray, np.ndarray]:
        """The model's output along a slow ramp over the valid range and back from a fresh
        state (``SETTLE`` steps each way at 10 Hz): (loading branch, unloading branch),
        both at the resistances ``np.linspace(r_lo, r_hi, SETTLE + 1)``. A sensor leaves
        the range at the top while loading and at the bottom while unloading."""
        up = np.linspace(self.r_lo, self.r_hi, SETTLE + 1)
        r = np.concatenate([up, up[-2::-1]])
        out = self.cal.build_model().run(0.1 * np.arange(r.size), r)
        return out[:SETTLE + 1], out[SETTLE:][::-1]

    def end_slopes(self) -> tuple[float, float]:
        """dS/dR of the model's unloading branch over the first ``END_SPAN`` of the valid
        range and of its loading branch over the last (``branches``): ``extrapolate``."""
        loading, unloading = self.branches()
        k = max(1, round(END_SPAN * SETTLE))
        width = k * (self.r_hi - self.r_lo) / SETTLE
        lo = float(unloading[k] - unloading[0]) / width
        hi = float(loading[-1] - loading[-1 - k]) / width
        return (lo if math.isfinite(lo) else 0.0), (hi if math.isfinite(hi) else 0.0)

    def bounded_slopes(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``extend``: (slopes, reach). Each end slope kept within ``EXTEND_SLOPE`` x the
        secant slope of the model over the valid range (``branches``: the top of its
        loading branch to the bottom of its unloading one); zero (the range's end is held)
        where the map does not rise the way the gauge does (a secant against
        ``direction.sign``) or turns back at that end (an end slope against the secant,
        as past the resistance peak of a carbon-black strip); nor where the branch that
        reads the top of the strain ends ``EXTEND_MONOTONE`` of the span short of it: the
        training resistance peaked before the strain did. The extended estimate reaches
        at most ``EXTEND_REACH`` calibrated strain spans above the range, and below it
        never past zero strain: a resistance under the calibrated rest is far more often a
        rest level that moved than a compression."""
        lo_end, hi_end = self.end_slopes()
        loading, unloading = self.branches()
        secant = float(loading[-1] - unloading[0]) / (self.r_hi - self.r_lo)
        low, high = EXTEND_SLOPE

        def bounded(end: float) -> float:
            if not (math.isfinite(secant) and secant * self.cal.direction.sign > 0.0
                    and end * secant > 0.0):
                return 0.0
            return float(secant * min(max(end / secant, low), high))

        vr = self.cal.valid_range
        span = vr.s_hi - vr.s_lo
        slopes = [bounded(lo_end), bounded(hi_end)]
        top = 1 if secant > 0.0 else 0  # the end whose branch reads the strain's top
        if (loading[-1] if top else unloading[0]) < vr.s_hi - EXTEND_MONOTONE * span:
            slopes[top] = 0.0
        reach = (min(self.s_lo, max(0.0, vr.s_lo - EXTEND_REACH * span)),
                 max(self.s_hi, vr.s_hi + EXTEND_REACH * span))
        return (slopes[0], slopes[1]), reach

    def pair(self, t: np.ndarray, ohm: np.ndarray, previous: float
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """What the models see of used samples ``ohm`` at times ``t``: the calibration's pair
        statistic (``input.pair``) when its input alternates, then the spike / baseline-step
        corrector when set (``strain_comp.core.chain``), else ``ohm``; ``previous``: the used
        sample before them (NaN after a reset, which also restarts the corrector's
        references); with the corrector's event per sample (spikes and confirmed steps,
        also counted in ``health``), None without a corrector."""
        if not self.cal.input.filtered or not ohm.size:
            return ohm, None
        self.previous = float(ohm[-1])
        if self.cal.input.alternation:
            ohm = pair_values(ohm, previous, self.cal.input.pair)
        if self.corrector is None:
            return ohm, None
        if math.isnan(previous):
            self.corrector.restart()
        ohm, events = self.corrector.run(t, ohm)
        events = np.where((events == SPIKE) | (events == STEP), events, 0).astype(np.int8)
        self.health.n_spikes += int(np.count_nonzero(events == SPIKE))
        self.health.n_baseline_steps += int(np.count_nonzero(events == STEP))
        return ohm, events

    @classmethod
    def build(cls, cal: SensorCalibration, deadzone_scale: float,
              out_of_range: str = "clamp") -> _Sensor:
        vr = cal.valid_range
        r_margin = RANGE_MARGIN * (vr.r_hi - vr.r_lo)
        s_margin = RANGE_MARGIN * (vr.s_hi - vr.s_lo)
        sensor = cls(cal=cal, model=cal.build_model(),
                     detector=DirectionDetector(_scaled(cal.direction, deadzone_scale)),
                     r_short=SHORT_FACTOR * vr.r_lo, r_open=OPEN_FACTOR * vr.r_hi,
                     r_lo=vr.r_lo - r_margin, r_hi=vr.r_hi + r_margin,
                     s_lo=vr.s_lo - s_margin, s_hi=vr.s_hi + s_margin,
                     effects=EffectTerms.from_dicts(cal.effects),
                     corrector=_corrector(cal))
        if out_of_range == "extrapolate":
            sensor.slopes = sensor.end_slopes()
        elif out_of_range == "extend":
            sensor.slopes, sensor.reach = sensor.bounded_slopes()
            sensor.saturate = True
        return sensor

    def to_ohm(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(resistance [ohm] x the tare gain, through the input zero and span, forced
        status) from the raw input values."""
        forced = np.zeros(raw.shape, dtype=np.int8)
        if self.cal.input.kind != "divider":
            return self.span(raw * self.gain if self.gain != 1.0 else raw), forced
        _, vin = self.cal.input.divider()
        forced[raw <= 0.0] = Status.OPEN_CIRCUIT
        forced[raw >= vin] = Status.SHORT_CIRCUIT
        return self.span(self.cal.input.to_ohm(raw) * self.gain), forced

    def span(self, ohm: Any) -> Any:
        """``ohm`` through the calibration's input zero and span (``InputSettings.
        zero_span``; unchanged without one)."""
        if self.cal.input.zero_span is None:
            return ohm
        k, c = self.cal.input.span_map()
        return k * ohm + c

    def mid_raw(self) -> float:
        """A raw input value in the middle of the valid range (for warming up kernels)."""
        r_mid = 0.5 * (self.cal.valid_range.r_lo + self.cal.valid_range.r_hi)
        if self.cal.input.kind != "divider":
            return r_mid
        return float(resistance_to_divider(r_mid, *self.cal.input.divider()))


def _corrector(cal: SensorCalibration) -> ChainCorrector | None:
    settings = cal.input
    if settings.despike is None and settings.baseline_step is None:
        return None
    return ChainCorrector(k=settings.despike if settings.despike is not None else DESPIKE_K,
                          alternating=settings.alternation,
                          step_k=settings.baseline_step or 0.0)


_STATUSES = tuple(Status)
"""Every ``Status``, indexed by its code."""
_COUNTERS = tuple((("n_good",) if used else ()) + ((counter,) if counter else ())
                  for used, counter in (STATUS_RULES[s] for s in _STATUSES))
"""The health counters a sample of each status code adds to (from ``STATUS_RULES``)."""


def _add_counts(h: SensorHealth, counts: np.ndarray) -> None:
    """Add per-``Status`` sample counts (indexed by status code; a further entry, the gap
    resets, is left out) to ``h``'s counters."""
    for names, n in zip(_COUNTERS, counts.tolist(), strict=False):
        if n:
            for name in names:
                setattr(h, name, getattr(h, name) + n)


@njit
def _clamp(value: float, lo: float, hi: float) -> float:
    """``np.clip`` of one value (NaN stays NaN)."""
    return value if value != value else min(max(value, lo), hi)


@njit
def _screen_batch(t: np.ndarray, ohm: np.ndarray, forced: np.ndarray, last_good_t: float,
                  r_short: float, r_open: float, r_lo: float, r_hi: float, gap: float
                  ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """``screen_all``, plus the indices of the used samples and the positions among them
    where a gap reset starts a segment."""
    status, reset, last = screen_all(t, ohm, forced, last_good_t, r_short, r_open, r_lo,
                                     r_hi, gap)
    idx = np.empty(t.size, np.int64)
    starts = np.empty(t.size, np.int64)
    m = 0
    n_starts = 0
    for i in range(t.size):
        if sc.is_used(status[i]):
            if reset[i]:
                starts[n_starts] = m
                n_starts += 1
            idx[m] = i
            m += 1
    return status, reset, last, idx[:m], starts[:n_starts]


def _range_status(ohm: np.ndarray, reset: np.ndarray, r_lo: float, r_hi: float) -> np.ndarray:
    """Status codes of used samples from the resistance the model reads: out of range
    outside [r_lo, r_hi], else a gap reset or good (``screen_one``'s last rule)."""
    inside = np.where(reset, sc.GAP_RESET, sc.GOOD)
    return np.where((ohm < r_lo) | (ohm > r_hi), sc.OUT_OF_RANGE, inside).astype(np.int8)


@njit
def _hold(status: np.ndarray, reset: np.ndarray, idx: np.ndarray, strain_used: np.ndarray,
          dir_used: np.ndarray, strain: float, direction: int, s_lo: float, s_hi: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Clamp the used samples' strain (in place) and hold it, and the direction, over the
    bad samples. Also returns the out-of-range flags and the samples per status code, then
    the number of resets."""
    n = status.size
    out_s = np.empty(n)
    out_d = np.empty(n, np.int8)
    oor = np.empty(n, np.bool_)
    counts = np.zeros(sc.OUT_OF_RANGE + 2, np.int64)
    j = 0
    for i in range(n):
        counts[status[i]] += 1
        oor[i] = status[i] == sc.OUT_OF_RANGE
        if reset[i]:
            counts[counts.size - 1] += 1
        if j < idx.size and idx[j] == i:
            strain_used[j] = _clamp(strain_used[j], s_lo, s_hi)
            strain = strain_used[j]
            direction = dir_used[j]
            j += 1
        out_s[i] = strain
        out_d[i] = direction
    return out_s, out_d, oor, counts


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
                 stale_after: float = 1.0, deadzone_scale: float = 1.0,
                 out_of_range: str = DEFAULT_OUT_OF_RANGE) -> None:
        if out_of_range not in OUT_OF_RANGE_MODES:
            raise ParameterError("out_of_range", f"must be one of "
                                 f"{', '.join(OUT_OF_RANGE_MODES)}, got {out_of_range!r}")
        self.out_of_range = out_of_range
        if not gap_reset > 0:
            raise ParameterError("gap_reset", f"must be > 0 s, got {gap_reset}")
        if not deadzone_scale > 0:
            raise ParameterError("deadzone_scale", f"must be > 0, got {deadzone_scale}")
        self.calibration = calibration
        self.gap_reset = float(gap_reset)
        self.stale_after = float(stale_after)
        self.deadzone_scale = float(deadzone_scale)
        self._sensors = {name: _Sensor.build(cal, self.deadzone_scale, out_of_range)
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
        self._sensors = {name: replace(_Sensor.build(s.cal, self.deadzone_scale,
                                                     self.out_of_range), gain=s.gain)
                         for name, s in self._sensors.items()}
        for group in self._arrays.values():
            group.rebuild()

    def input_gain(self, sensor: str) -> float:
        """The tare gain of ``sensor``: its models see this x the measured resistance."""
        return self._sensor(sensor).gain

    def tare(self, sensor: str, rest_resistance: float) -> float:
        """Make ``rest_resistance`` [ohm] (measured now, at rest) this sensor's zero.

        Multiplicative: the models see R x (calibration's rest resistance / rest_resistance);
        with an input zero and span (``InputSettings.zero_span``) the gain is (its rest /
        rest_resistance), so the rest now reads as the calibrated rest through the span.
        Returns the new gain; ``ParameterError`` if the calibration stores no rest resistance
        or the value is not finite and > 0 (the old gain then stays).
        """
        reference = self._sensor(sensor).cal.input_rest
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
        """Set the tare gain of ``sensor`` (effective from the next sample; state kept, the
        input corrector's and the pair statistic's references carried over to the new gain,
        so the change is not taken for a baseline step, and so is the memory of effect terms
        that read the resistance, so the change is no step for them either)."""
        if not (math.isfinite(gain) and gain > 0):
            raise ParameterError(f"{sensor}.input_gain", f"must be finite and > 0, got {gain}")
        s = self._sensor(sensor)
        factor = float(gain) / s.gain
        s.previous *= factor
        if s.corrector is not None:
            s.corrector.rescale(factor)
        s.effects.rescale(factor)
        s.gain = float(gain)
        for group in self._arrays.values():
            if sensor in group.names and group.kernel is not None:
                group.set_gain(group.names.index(sensor), float(gain))

    def track_baseline(self, sensor: str, gain: float, seconds: float) -> None:
        """``set_input_gain`` by baseline tracking after ``seconds`` at rest: counted in
        the sensor's health (``baseline_tracked_s``, ``baseline_correction``)."""
        s = self._sensor(sensor)
        factor = gain / s.gain
        self.set_input_gain(sensor, gain)
        s.health.baseline_tracked_s += seconds
        s.health.baseline_correction = (1.0 + s.health.baseline_correction) * factor - 1.0

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
        corrected = run_segments(
            lambda k: sensor.effects.run(t[k], r[k], base[k], direction[k], temperature[k],
                                         {n: v[k] for n, v in nbrs.items()}),
            sensor.effects.reset, t.size, starts)
        # a correction that overflows (extreme inputs or coefficients) is not applied: the
        # estimate never becomes NaN; +-inf is clamped to the valid range by the caller
        return np.where(np.isnan(corrected), base, corrected)

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
            raw = s.span(raw * s.gain)
        code, reset = screen_one(t, raw, forced, s.last_good_t, s.r_short, s.r_open,
                                  s.r_lo, s.r_hi, sc.gap_for(s.cal.sample_interval,
                                                             self.gap_reset))
        status = Status(code)
        h = s.health
        if status not in USED:
            h.count(status)
            h.last_status = status
            return SensorOutput(s.strain, s.direction, status, False)
        if reset:
            s.model.reset()
            s.detector.reset()
            s.effects.reset()
            h.n_gaps += 1
        if s.cal.input.filtered:
            raw = float(s.pair(np.array([t]), np.array([raw]),
                               math.nan if reset else s.previous)[0][0])
            status = Status(int(_range_status(np.array([raw]), np.array([reset]),
                                              s.r_lo, s.r_hi)[0]))
        direction = int(s.detector.step(t, raw)) * s.cal.direction.sign
        read = min(max(raw, s.r_lo), s.r_hi) if s.saturate else raw
        return _Pending(t, raw, status, float(s.model.step(t, read)), direction)

    def _step_finish(self, s: _Sensor, p: _Pending, temperature: float,
                     neighbours: Mapping[str, float] | None = None) -> SensorOutput:
        """Effect terms, clamping, held output and counters of one used sample."""
        t, raw, status, strain, direction = p.t, p.r, p.status, p.strain, p.direction
        if s.cal.effects:
            nbrs = {n: np.array([v]) for n, v in (neighbours or {}).items()}
            strain = float(self._apply_effects(s, np.array([t]), np.array([raw]),
                                               np.array([strain]), np.array([direction]),
                                               np.array([temperature]), nbrs)[0])
        strain = float(s.beyond(np.array([raw]), np.array([strain]))[0]) \
            if s.slopes is not None else min(max(strain, s.s_lo), s.s_hi)
        h = s.health
        s.last_good_t = t
        s.strain, s.direction = strain, direction
        h.count(status)
        h.last_good_t = t
        h.last_status = status
        return SensorOutput(strain, direction, status, status is Status.OUT_OF_RANGE, raw)

    def run(self, sensor: str, t: npt.ArrayLike, r: npt.ArrayLike,
            temperature: npt.ArrayLike | None = None, *,
            neighbours: Mapping[str, npt.ArrayLike] | None = None) -> BatchOutput:
        """Batch path over whole arrays; identical to ``step`` sample by sample.

        ``neighbours``: for cross-talk effect terms, the named array neighbours' clamped
        pre-effect strain at the times ``t`` (else their latest values are held).
        """
        s = self._sensor(sensor)
        pending = self._run_model(s, t, r, temperature)
        nbrs = ({n: np.asarray(v, dtype=np.float64) for n, v in neighbours.items()}
                if neighbours else {})
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
        temp = (None if temperature is None
                else np.ascontiguousarray(temperature, dtype=np.float64))
        ohm, forced = s.to_ohm(raw)
        status, reset, last_good_t, idx, resets = _screen_batch(
            t, ohm, forced, s.last_good_t, s.r_short, s.r_open, s.r_lo, s.r_hi,
            sc.gap_for(s.cal.sample_interval, self.gap_reset))
        if s.cal.input.filtered:
            ohm = ohm.copy()  # corrected samples replace the used ones below; raw intact
        bounds = [0, *resets.tolist(), idx.size] if resets.size else [0, idx.size]
        corrections = np.zeros(idx.size, np.int8) if s.corrector is not None else None
        if 0 < idx.size == t.size and len(bounds) == 2:  # every sample used, one segment
            ohm, events = s.pair(t, ohm, s.previous)
            if events is not None:
                corrections = events
            dir_used = s.detector.run(t, ohm)
            strain_used = s.model.run(t, s.model_input(ohm))
        else:
            strain_used = np.empty(idx.size)
            dir_used = np.empty(idx.size, dtype=np.int8)
            for k, (a, b) in enumerate(itertools.pairwise(bounds)):
                if b == a:
                    continue
                if k > 0:
                    s.model.reset()
                    s.detector.reset()
                seg = idx[a:b]
                seg_ohm, events = s.pair(t[seg], ohm[seg],
                                         s.previous if k == 0 else math.nan)
                if s.cal.input.filtered:
                    ohm[seg] = seg_ohm
                if corrections is not None and events is not None:
                    corrections[a:b] = events
                dir_used[a:b] = s.detector.run(t[seg], seg_ohm)
                strain_used[a:b] = s.model.run(t[seg], s.model_input(seg_ohm))
        if s.cal.input.filtered:  # the range flag of what the model reads
            status[idx] = _range_status(ohm[idx], reset[idx], s.r_lo, s.r_hi)
        if s.cal.direction.sign < 0:
            dir_used = -dir_used
        return _PendingBatch(t, ohm, temp, status, reset, last_good_t, idx, bounds,
                             strain_used, dir_used, corrections)

    def _run_finish(self, s: _Sensor, p: _PendingBatch,
                    neighbours: Mapping[str, np.ndarray]) -> BatchOutput:
        """``run``'s second stage: effect terms, clamping, held outputs and counters."""
        t, status, reset, last_good_t, idx = p.t, p.status, p.reset, p.last_good_t, p.idx
        strain_used, dir_used = p.strain_used, p.dir_used
        if s.cal.effects and idx.size:
            nbrs = {n: v[idx] for n, v in neighbours.items()}
            starts = p.bounds[1:-1]  # a reset at the first sample resets at once
            temp = (np.full(idx.size, np.nan) if p.temperature is None
                    else p.temperature[idx])
            strain_used = self._apply_effects(s, t[idx], p.ohm[idx], strain_used, dir_used,
                                              temp, nbrs, starts)
        # clamped; held outputs: each sample shows the latest used sample at or before it
        s_lo, s_hi = s.s_lo, s.s_hi
        if s.slopes is not None and idx.size:
            strain_used = s.beyond(p.ohm[idx], strain_used)
            s_lo, s_hi = -math.inf, math.inf
        strain, direction, out_of_range, counts = _hold(
            status, reset, idx, strain_used, dir_used, s.strain, s.direction, s_lo, s_hi)
        h = s.health
        _add_counts(h, counts)
        h.n_gaps += int(counts[-1])
        if status.size:
            h.last_status = _STATUSES[status[-1]]
        if idx.size:
            s.last_good_t = last_good_t
            h.last_good_t = last_good_t
            s.strain, s.direction = float(strain_used[-1]), int(dir_used[-1])
        corrections = None
        if p.corrections is not None:
            corrections = np.zeros(t.size, np.int8)
            corrections[idx] = p.corrections
        return BatchOutput(strain, direction, status, out_of_range, p.ohm, reset, corrections)

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
                h.stale = h.last_good_t is None or now - h.last_good_t > self.stale_for(name)
            out[name] = h
        return out

    def stale_for(self, sensor: str) -> float:
        """The silence [s] after which ``sensor`` is stale: ``stale_after``, or two of its
        sample intervals for a slow instrument (``SensorCalibration.sample_interval``),
        which is otherwise stale between every two samples."""
        interval = self._sensor(sensor).cal.sample_interval
        return self.stale_after if interval is None else max(self.stale_after, 2.0 * interval)

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


# columns of the fused tick's per-sensor parameter table
_GAIN, _R1, _VIN, _R_SHORT, _R_OPEN, _R_LO, _R_HI, _S_LO, _S_HI, _DEADZONE, _TAU, _SIGN = \
    range(12)
# out of range (``_Sensor.beyond``): slopes below / above, reach low / high, saturate
_SLOPE_LO, _SLOPE_HI, _REACH_LO, _REACH_HI, _SATURATE = range(12, 17)
_N_PARAMS = 17
# columns of its per-sensor held state
_LAST_GOOD_T, _STRAIN, _DIRECTION, _LAST_STATUS = range(4)


@njit(error_model="numpy")
def _array_tick(t: float, raw: np.ndarray, par: np.ndarray, held: np.ndarray,
                counts: np.ndarray, det: np.ndarray, gap: float, model_out: np.ndarray,
                status: np.ndarray, reset: np.ndarray, x: np.ndarray, clock: np.ndarray,
                kind: np.ndarray, sigma: np.ndarray, p: np.ndarray, rho: np.ndarray,
                inv_width: np.ndarray, w: np.ndarray, norm: np.ndarray, b: np.ndarray,
                f_at_b: np.ndarray, inv_slopes: np.ndarray) -> None:
    """One array tick, all sensors, in one call: input conversion and tare gain,
    screening, gap reset, model step (``step_sensor``), detector, clamp, held outputs and
    counters (the module's steps 1-5). ``held[k]`` gets the published strain / direction /
    status; ``model_out[k]`` the unclamped model estimate of a used sample (NaN if bad),
    for the effect terms; ``counts[k]`` = samples per status code, then gap resets."""
    for k in range(raw.size):
        ri = raw[k]
        forced = sc.GOOD
        vin = par[k, _VIN]
        if vin > 0.0:  # voltage divider
            if ri <= 0.0:
                forced = sc.OPEN_CIRCUIT
            elif ri >= vin:
                forced = sc.SHORT_CIRCUIT
            ri = par[k, _R1] * (vin - ri) / ri if forced == sc.GOOD else np.nan
        ohm = ri * par[k, _GAIN]
        code, rst = screen_one(t, ohm, forced, held[k, _LAST_GOOD_T], par[k, _R_SHORT],
                               par[k, _R_OPEN], par[k, _R_LO], par[k, _R_HI], gap)
        status[k] = code
        reset[k] = rst
        counts[k, code] += 1
        held[k, _LAST_STATUS] = code
        if not sc.is_used(code):
            model_out[k] = np.nan
            continue
        if rst:
            x[k, :] = 0.0
            clock[k, :] = 0.0
            det[k, :] = 0.0
            counts[k, counts.shape[1] - 1] += 1
        read = _clamp(ohm, par[k, _R_LO], par[k, _R_HI]) if par[k, _SATURATE] else ohm
        estimate = step_sensor(k, t, read, x, clock, kind, sigma, p, rho, inv_width, w, norm,
                               b, f_at_b, inv_slopes)
        model_out[k] = estimate
        held[k, _DIRECTION] = direction_update(det[k], t, ohm, par[k, _DEADZONE],
                                               par[k, _TAU]) * par[k, _SIGN]
        held[k, _STRAIN] = _beyond(ohm, _clamp(estimate, par[k, _S_LO], par[k, _S_HI]),
                                   par[k])
        held[k, _LAST_GOOD_T] = t


@njit
def _beyond(ohm: float, strain: float, par: np.ndarray) -> float:
    """``_Sensor.beyond`` of one sample from a row of the fused tick's parameter table."""
    if ohm > par[_R_HI]:
        strain += par[_SLOPE_HI] * (ohm - par[_R_HI])
    elif ohm < par[_R_LO]:
        strain += par[_SLOPE_LO] * (ohm - par[_R_LO])
    return _clamp(strain, par[_REACH_LO], par[_REACH_HI])


class _ArrayGroup:
    """The sensors of one array, stepped together.

    When every sensor's model declares ``array_kernel`` (the APL family, same N and M) and
    no sensor's input is corrected (``InputSettings.filtered``), one tick is one call of
    the fused ``_array_tick`` kernel; the group then keeps the array's state, counters and
    held outputs itself, and its sensors should not also be fed through
    ``Engine.step``. Sensors with effect terms are corrected after the kernel, one by one
    in Python (the slower path). Otherwise a loop of ``Engine.step``.
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
        if not all(type(s.model).array_kernel and not s.cal.input.filtered
                   and s.cal.input.zero_span is None
                   and s.cal.sample_interval is None for s in self.sensors):
            return
        from strain_comp.models.apl import APLArray

        try:
            self.kernel = APLArray.from_models([s.model for s in self.sensors])
        except ParameterError:  # different N or M: fall back to the loop
            return
        k = len(self.sensors)
        par = np.zeros((k, _N_PARAMS))
        for i, s in enumerate(self.sensors):
            if s.cal.input.kind == "divider":
                par[i, _R1], par[i, _VIN] = s.cal.input.divider()
            par[i, _R_SHORT:_S_HI + 1] = (s.r_short, s.r_open, s.r_lo, s.r_hi, s.s_lo, s.s_hi)
            par[i, _TAU] = s.cal.direction.tau
            par[i, _SIGN] = s.cal.direction.sign
            par[i, _SLOPE_LO:_REACH_LO] = s.slopes if s.slopes is not None else (0.0, 0.0)
            par[i, _REACH_LO:_SATURATE] = s.reach
            par[i, _SATURATE] = s.saturate
        par[:, _GAIN] = [s.gain for s in self.sensors]
        self.par = par
        self.held = np.zeros((k, 4))
        self.held[:, _LAST_GOOD_T] = -math.inf
        self.held[:, _STRAIN] = math.nan
        self.held[:, _LAST_STATUS] = -1
        self.counts = np.zeros((k, len(Status) + 1), dtype=np.int64)
        self.states = np.zeros((k, STATE_SIZE))
        self.model_out = np.empty(k)
        self.status = np.empty(k, dtype=np.int8)
        self.reset = np.empty(k, dtype=np.bool_)
        self.set_deadzone_scale(self.engine.deadzone_scale)
        self.effects = [i for i, s in enumerate(self.sensors) if s.cal.effects]

    def set_gain(self, index: int, gain: float) -> None:
        self.par[index, _GAIN] = gain

    def set_deadzone_scale(self, scale: float) -> None:
        self.par[:, _DEADZONE] = [s.cal.direction.deadzone * scale for s in self.sensors]
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
        kern = self.kernel
        _array_tick(t, raw, self.par, self.held, self.counts, self.states,
                    self.engine.gap_reset, self.model_out, self.status, self.reset, kern.x,
                    kern.clock, kern.kind, kern.sigma, kern.p, kern.rho, kern.inv_width,
                    kern.w, kern.norm, kern.b, kern.f_at_b, kern.inv_slopes)
        status = self.status.copy()
        if self.effects:
            self._effects(t, raw)
        return ArrayOutput(self.held[:, _STRAIN].copy(),
                           self.held[:, _DIRECTION].astype(np.int8), status,
                           status == sc.OUT_OF_RANGE)

    def _effects(self, t: float, raw: np.ndarray) -> None:
        """Effect terms of the tick's used sensors (neighbours read clamped estimates)."""
        base = np.clip(self.model_out, self.par[:, _S_LO], self.par[:, _S_HI])
        for i in self.effects:
            s = self.sensors[i]
            if self.reset[i]:
                s.effects.reset()
            if not USED_CODE[self.status[i]]:
                continue
            ohm, _ = s.to_ohm(raw[i:i + 1])
            nbrs = {n: base[self.names.index(n):self.names.index(n) + 1]
                    for n in s.effects.neighbours if n in self.names}
            strain = self.engine._apply_effects(
                s, np.array([t]), ohm, self.model_out[i:i + 1],
                self.held[i:i + 1, _DIRECTION].astype(np.int8), np.array([math.nan]), nbrs)
            self.held[i, _STRAIN] = float(s.beyond(ohm, strain)[0]) if s.slopes is not None \
                else min(max(float(strain[0]), s.s_lo), s.s_hi)

    def health(self) -> dict[str, SensorHealth]:
        """Counters of the kernel path's sensors (only when ``kernel`` is set)."""
        out = {}
        for k, name in enumerate(self.names):
            h = SensorHealth(n_gaps=int(self.counts[k, -1]))
            _add_counts(h, self.counts[k])
            if self.held[k, _LAST_GOOD_T] > -math.inf:
                h.last_good_t = float(self.held[k, _LAST_GOOD_T])
            if self.held[k, _LAST_STATUS] >= 0:
                h.last_status = Status(int(self.held[k, _LAST_STATUS]))
            out[name] = h
        return out


def health_at(before: SensorHealth, t: np.ndarray, out: BatchOutput, ticks: np.ndarray, *,
              stale_after: float) -> list[SensorHealth]:
    """A sensor's health at each of ``ticks`` [s] from one ``run``'s statuses: ``before``
    (its health when the run started) plus the counts of the samples at or before each tick
    (``t`` in order), what ``Engine.health(now=tick)`` would have said had the run been cut
    there."""
    n = t.size
    pos = np.searchsorted(np.maximum.accumulate(t), ticks, side="right")
    cum = np.zeros((n + 1, len(Status) + 1), np.int64)
    cum[1:, :len(Status)] = np.cumsum(
        out.status[:, None].astype(np.int64) == np.arange(len(Status)), axis=0)
    if out.reset is not None:
        cum[1:, -1] = np.cumsum(out.reset)
    fixes = np.zeros((n + 1, 2), np.int64)
    if out.corrections is not None:
        fixes[1:] = np.cumsum(out.corrections[:, None] == np.array([SPIKE, STEP]), axis=0)
    last_used = np.maximum.accumulate(np.where(USED_CODE[out.status], np.arange(n), -1))
    found = []
    for now, k in zip(ticks.tolist(), pos.tolist(), strict=True):
        h = replace(before)
        _add_counts(h, cum[k, :-1])
        h.n_gaps += int(cum[k, -1])
        h.n_spikes += int(fixes[k, 0])
        h.n_baseline_steps += int(fixes[k, 1])
        if k:
            h.last_status = Status(int(out.status[k - 1]))
            if last_used[k - 1] >= 0:
                h.last_good_t = float(t[last_used[k - 1]])
        h.stale = h.last_good_t is None or now - h.last_good_t > stale_after
        found.append(h)
    return found


def diagnostics(health: Mapping[str, SensorHealth], *, prefix: str = "strain_comp"
                ) -> list[tuple[str, int, str, dict[str, str]]]:
    """``(name, level, message, values)`` per sensor, as BagWriter and the nodes publish."""
    return [(f"{prefix}: {name}", *h.to_diagnostic()) for name, h in health.items()]

