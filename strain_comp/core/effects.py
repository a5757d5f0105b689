"""Effect terms: online corrections a static or hysteretic inverse model lacks.

The residual loop (docs/design.md, "The residual loop"; ``strain_comp.diagnosis``) finds which
physical effect explains the residual e = S_hat - S of a calibrated model and adds it as
an explicit term. Each effect is a *regressor* g_j computed causally, sample by sample,
from what a running model knows: time t [s], resistance R [ohm], the model's own estimate
S_hat [%], the direction detector's output d (+1 loading, 0 hold, -1 unloading), an
optional temperature T and the estimates of array neighbours. The corrected strain is

    S_corrected = S_hat - sum_j c_j g_j

with coefficients c_j fitted by least squares on the residual. A constant term is an
ordinary effect of kind ``offset`` (g = 1): the residual loop fits it together with every
other effect, so the correction never shifts the output by an offset it did not test.

Regressors use S_hat (not R) as their signal wherever a signal is needed: S_hat is in
strain units (coefficients are then dimensionless or in seconds) and monotone in strain
even where R is not (carbon-black sensors). The one exception, ``resistance_memory``
(``ResistanceMemory``), reads 100 ln R on purpose: what R still shows where S_hat has lost
it. R is what the model reads (converted, times the tare gain, after the input corrections).

Calibration-file form (one entry of a sensor's ``effects:`` list)::

    {name: relaxation_loading_tau10, kind: relaxation,
     params: {tau: 10.0, branch: loading}, coef: 0.031}

Every parameter has a default, so ``params: {}`` is valid. Each regressor has ``reset()``,
``step(sample) -> float`` and a batch ``run(batch) -> array`` that continues from the
current state and leaves it where repeated ``step`` calls would. The engine resets the
state wherever it resets the model (start, ``reset()``, a gap reset), so a ``baseline``
(``Baseline``) is captured again at the start of every run; a tare during a run
(``Engine.set_input_gain``) carries the state of R-reading terms over (``rescale``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.errors import ParameterError
from strain_comp.models.base import require_float


@dataclass
class Sample:
    """One sample as the online path sees it (inputs of ``Regressor.step``)."""

    t: float
    r: float
    s_hat: float
    direction: int
    temperature: float = math.nan
    neighbours: Mapping[str, float] | None = None


@dataclass
class Batch:
    """Whole arrays of samples (inputs of ``Regressor.run``); all of one length n.

    ``temperature`` may be None (no temperature topic); ``neighbours`` maps a neighbour
    sensor's name to its S_hat at the same sample times (NaN where unknown).
    """

    t: np.ndarray
    r: np.ndarray
    s_hat: np.ndarray
    direction: np.ndarray
    temperature: np.ndarray | None = None
    neighbours: Mapping[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, t: npt.ArrayLike, r: npt.ArrayLike, s_hat: npt.ArrayLike,
           direction: npt.ArrayLike, temperature: npt.ArrayLike | None = None,
           neighbours: Mapping[str, npt.ArrayLike] | None = None) -> Batch:
        """Contiguous float64 copies, checked to be 1-D and of one length."""
        arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (t, r, s_hat, direction)]
        n = arrays[0].size
        temp = None if temperature is None else np.ascontiguousarray(temperature, np.float64)
        nbrs = {str(k): np.ascontiguousarray(v, np.float64) for k, v in (neighbours or {}).items()}
        for a in [*arrays, *([temp] if temp is not None else []), *nbrs.values()]:
            if a.ndim != 1 or a.size != n:
                raise ValueError("effects: every input array must be 1-D and of one length")
        t_, r_, s_hat_, direction_ = arrays
        return cls(t_, r_, s_hat_, direction_, temperature=temp, neighbours=nbrs)


def _choice(params: Mapping[str, Any], key: str, options: Sequence[str], default: str) -> str:
    value = params.get(key, default)
    if value not in options:
        raise ParameterError(f"params.{key}", f"must be one of {', '.join(options)}; got {value!r}")
    return str(value)


def _number(params: Mapping[str, Any], key: str, default: float, **bounds: Any) -> float:
    """``params[key]`` as a finite float within ``bounds`` (see require_float), or default."""
    if key not in params:
        return default
    try:
        return require_float(params, key, **bounds)
    except ParameterError as err:
        raise ParameterError(f"params.{err.field}", err.problem) from None


def _positive(params: Mapping[str, Any], key: str, default: float) -> float:
    return _number(params, key, default, lo=0.0, strict=True)


def _ffill(values: np.ndarray, last: float) -> np.ndarray:
    """Hold the last finite value (``last`` before the first one; NaN if none yet)."""
    ok = np.isfinite(values)
    idx = np.where(ok, np.arange(values.size), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], last)


def run_segments(run: Callable[[slice], np.ndarray], reset: Callable[[], None], n: int,
                 starts: Sequence[int]) -> np.ndarray:
    """``run`` over the n samples in segments cut at ``starts`` (where the engine reset after
    a gap), calling ``reset`` between segments, as the engine resets effect state there."""
    out = np.empty(n)
    for k, (a, b) in enumerate(pairwise([0, *starts, n])):
        if k > 0:
            reset()
        if b > a:
            out[a:b] = run(slice(a, b))
    return out


class Regressor(ABC):
    """One effect regressor g(t) with explicit state; see the module docstring."""

    kind: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]] = ()

    @abstractmethod
    def reset(self) -> None:
        """Restore the initial state."""

    def step(self, sample: Sample) -> float:
        """Advance by one sample and return g at that sample: ``run`` on a batch of one, so
        a regressor with a compiled kernel has that one implementation."""
        neighbours = {n: [v] for n, v in (sample.neighbours or {}).items()}
        return float(self.run(Batch.of([sample.t], [sample.r], [sample.s_hat],
                                       [sample.direction], [sample.temperature],
                                       neighbours))[0])

    @abstractmethod
    def run(self, batch: Batch) -> np.ndarray:
        """g over a batch, continuing from (and updating) the current state."""

    @abstractmethod
    def params(self) -> dict[str, Any]:
        """The parameters as plain Python (the calibration file's ``params``)."""

    @classmethod
    @abstractmethod
    def from_params(cls, params: Mapping[str, Any]) -> Regressor:
        """Build from ``params``; ParameterError naming ``params.<key>`` if bad."""

    @property
    def neighbour(self) -> str | None:
        """Name of the array neighbour this regressor reads, if any."""
        return None

    def rescale(self, factor: float) -> None:
        """The resistance it reads is ``factor`` x what it was (a tare): carry the state
        over, as if that scale had held from the first sample. Terms that do not read the
        resistance keep no state in its scale: nothing to do."""
        return None


class Offset(Regressor):
    """g = 1: a constant offset of the estimate (a zero shift between runs)."""

    kind = "offset"

    def reset(self) -> None:
        pass

    def step(self, sample: Sample) -> float:
        return 1.0

    def run(self, batch: Batch) -> np.ndarray:
        return np.ones(batch.t.size)

    def params(self) -> dict[str, Any]:
        return {}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Offset:
        return cls()


@njit
def _rate_kernel(t: np.ndarray, u: np.ndarray, d: np.ndarray, tau: float, direction_mode: bool,
                 state: np.ndarray) -> np.ndarray:
    """Low-passed derivative y' = (du/dt - y) / tau, exact for piecewise-constant du/dt."""
    y, u_prev, t_prev, started = state[0], state[1], state[2], state[3]
    out = np.empty(t.size)
    for k in range(t.size):
        if started > 0.0:
            dt = t[k] - t_prev
            if dt > 0.0:
                y += (1.0 - math.exp(-dt / tau)) * ((u[k] - u_prev) / dt - y)
        started = 1.0
        u_prev = u[k]
        t_prev = t[k]
        out[k] = d[k] * y if direction_mode else y
    state[0], state[1], state[2], state[3] = y, u_prev, t_prev, started
    return out


class Rate(Regressor):
    """Signed strain rate dS_hat/dt [%/s], low-passed with time constant ``tau`` [s].

    Viscoelastic sensors lag or lead the strain by an amount proportional to its rate
    (rate-dependent hysteresis, [Electrolycra] section I). ``mode: direction`` gives
    d * rate (the detector's direction times the rate): an error of one sign whenever the
    sensor moves, whatever the direction (e.g. self-heating or a rate-dependent gain).
    """

    kind = "rate"
    param_names = ("tau", "mode")

    def __init__(self, tau: float = 1.0, mode: str = "signed") -> None:
        self.tau = tau
        self.mode = mode
        self._state = np.zeros(4)

    def reset(self) -> None:
        self._state = np.zeros(4)

    def run(self, batch: Batch) -> np.ndarray:
        return _rate_kernel(batch.t, batch.s_hat, batch.direction, self.tau,
                            self.mode == "direction", self._state)

    def params(self) -> dict[str, Any]:
        return {"tau": self.tau, "mode": self.mode}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Rate:
        return cls(_positive(params, "tau", 1.0),
                   _choice(params, "mode", ("signed", "direction"), "signed"))


class Direction(Regressor):
    """The detector's direction d ([EGaIn] section V.E) as a regressor.

    ``mode: sign`` gives d; ``mode: strain`` gives d * S_hat (a hysteresis loop whose width
    grows with strain). With ``hold: true`` a hold (d = 0) keeps the last moving
    direction, as hysteresis persists while the strain is held.

    d is the detector's output at the *previous* sample (0 at the first): the output at
    sample k follows dR/dt, which carries that sample's own read-out noise, as does the
    residual at k; a term using it would "correct" noise (a correlation the residual loop
    would find on any noisy record, effect or not). One sample of lag costs nothing for
    hysteresis, which persists over many samples.
    """

    kind = "direction"
    param_names = ("mode", "hold")

    def __init__(self, mode: str = "sign", hold: bool = False) -> None:
        self.mode = mode
        self.hold = hold
        self.reset()

    def reset(self) -> None:
        self._last = 0.0  # the last moving direction (hold) up to the previous sample
        self._prev = 0.0  # the previous sample's direction

    def run(self, batch: Batch) -> np.ndarray:
        d = np.concatenate(([self._prev], batch.direction[:-1]))
        if batch.direction.size:
            self._prev = float(batch.direction[-1])
        if self.hold:
            last = _ffill(np.where(batch.direction != 0.0, batch.direction, np.nan),
                          self._last)
            d = np.concatenate(([self._last], last[:-1]))[:batch.t.size]
            if last.size:
                self._last = float(last[-1])
        return d * batch.s_hat if self.mode == "strain" else d

    def params(self) -> dict[str, Any]:
        return {"mode": self.mode, "hold": self.hold}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Direction:
        hold = params.get("hold", False)
        if not isinstance(hold, bool):
            raise ParameterError("params.hold", f"must be true or false, got {hold!r}")
        return cls(_choice(params, "mode", ("sign", "strain"), "sign"), hold)


_BRANCHES = ("both", "loading", "unloading")


@njit
def _relaxation_kernel(t: np.ndarray, u: np.ndarray, d: np.ndarray, tau: float, branch: int,
                       state: np.ndarray) -> np.ndarray:
    """h_k = h_{k-1} exp(-dt/tau) + du_k [d_k in branch]: decaying memory of S_hat steps."""
    h, u_prev, t_prev, started = state[0], state[1], state[2], state[3]
    out = np.empty(t.size)
    for k in range(t.size):
        if started > 0.0:
            h *= math.exp(-(t[k] - t_prev) / tau)
            if branch == 0 or (branch == 1 and d[k] > 0) or (branch == 2 and d[k] < 0):
                h += u[k] - u_prev
        started = 1.0
        u_prev = u[k]
        t_prev = t[k]
        out[k] = h
    state[0], state[1], state[2], state[3] = h, u_prev, t_prev, started
    return out


class Relaxation(Regressor):
    """Exponentially decaying memory of recent strain change: relaxation after steps.

    The first-order filter x' = (S_hat - x) / tau gives the regressor h = S_hat - x, which
    jumps with every change of S_hat and decays with time constant ``tau`` [s] once the
    strain is held. A sensor that overshoots after a step and relaxes back (the
    Electrolycra's creep, [Electrolycra] section III; the spike-and-decay of
    [Nanocomposite] eq. (1)) leaves a residual c * h. ``branch: loading``
    (or ``unloading``) accumulates only the changes made while the detector says loading
    (unloading), since relaxation is often strong on loading and weak on unloading.
    Discretised exactly for a piecewise-constant input: h_k = h_{k-1} e^{-dt/tau} + dS_k.
    """

    kind = "relaxation"
    param_names = ("tau", "branch")

    def __init__(self, tau: float = 10.0, branch: str = "both") -> None:
        self.tau = tau
        self.branch = branch
        self._code = _BRANCHES.index(branch)
        self._state = np.zeros(4)

    def reset(self) -> None:
        self._state = np.zeros(4)

    def run(self, batch: Batch) -> np.ndarray:
        return _relaxation_kernel(batch.t, batch.s_hat, batch.direction, self.tau, self._code,
                                  self._state)

    def params(self) -> dict[str, Any]:
        return {"tau": self.tau, "branch": self.branch}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Relaxation:
        return cls(_positive(params, "tau", 10.0), _choice(params, "branch", _BRANCHES, "both"))


_MEMORY_FORMS = ("relaxation", "peak", "trough")


@njit
def _resistance_memory_kernel(t: np.ndarray, r: np.ndarray, tau: float, form: int,
                              state: np.ndarray) -> np.ndarray:
    """y = 100 ln R, held between samples; m relaxes towards it with ``tau`` (``peak``:
    m = max(m, y); ``trough``: m = min(m, y)); g = y - m (``peak``: m - y)."""
    m, y_prev, t_prev, started = state[0], state[1], state[2], state[3]
    out = np.empty(t.size)
    for k in range(t.size):
        y = 100.0 * math.log(max(r[k], 1e-300))
        if started > 0.0:
            m = y_prev + (m - y_prev) * math.exp(-(t[k] - t_prev) / tau)
        else:
            m = y
        if form == 1:
            m = max(m, y)
        elif form == 2:
            m = min(m, y)
        started = 1.0
        y_prev = y
        t_prev = t[k]
        out[k] = m - y if form == 1 else y - m
    state[0], state[1], state[2], state[3] = m, y_prev, t_prev, started
    return out


class ResistanceMemory(Regressor):
    """Fading memory of the resistance itself: the part of R still relaxing, or how far R
    stands from a recent spike. It reads R (the resistance the model sees), not S_hat,
    because where R is not monotone in strain (the carbon-black shoulder) or a step's
    overshoot runs past the calibrated range, S_hat has lost what R still shows.

    With y = 100 ln R (so the term does not change with a multiplicative tare) and a
    first-order memory of time constant ``tau`` [s]:

    * ``relaxation``: g = y - m, m' = (y - m) / tau, the share of R [%] above its recent
      average: a relaxation that follows every step of R, whatever its sign;
    * ``peak``: g = p - y, p the peak of y relaxing towards y with ``tau`` and never below
      it: how far R [%] has fallen from a recent spike, the decaying spike of
      [Nanocomposite] eq. (3), read without knowing the step that caused it;
    * ``trough``: g = y - q, the mirror of ``peak`` for sensors whose steps undershoot.

    A bank of such filters followed by a static map approximates any fading-memory
    operator (Boyd and Chua, 1985); the loop adds the few that pay on held-out data.
    Discretised exactly for a piecewise-constant input, as ``Relaxation``: the
    ``relaxation`` form is ``Relaxation`` (branch ``both``) applied to y.
    """

    kind = "resistance_memory"
    param_names = ("tau", "form")

    def __init__(self, tau: float = 10.0, form: str = "relaxation") -> None:
        self.tau = tau
        self.form = form
        self._code = _MEMORY_FORMS.index(form)
        self._state = np.zeros(4)

    def reset(self) -> None:
        self._state = np.zeros(4)

    def rescale(self, factor: float) -> None:
        """y and its memory shift by 100 ln(factor): g is unchanged."""
        self._state[:2] += 100.0 * math.log(factor)

    def run(self, batch: Batch) -> np.ndarray:
        return _resistance_memory_kernel(batch.t, batch.r, self.tau, self._code, self._state)

    def params(self) -> dict[str, Any]:
        return {"tau": self.tau, "form": self.form}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> ResistanceMemory:
        return cls(_positive(params, "tau", 10.0),
                   _choice(params, "form", _MEMORY_FORMS, "relaxation"))


class Elapsed(Regressor):
    """Slow drift: a function of the time since the first sample, x = (t - t0) / scale.

    ``form``: ``linear`` x, ``sqrt`` sqrt(x) (diffusion-limited ageing, swelling) or
    ``log`` log(1 + x) (creep of a polymer matrix); ``linear_strain`` x * S_hat: a drift
    of the *gain*. A resistance that drifts in proportion to itself, R (1 + d t), which is
    how contact and filler-network ageing usually act, shifts the strain estimate by about
    (1/G + S) d t for a gauge factor G: an offset drift plus this gain drift. ``scale`` [s]
    only sets the units of the coefficient (and the knee of ``log``). t0 is the first
    sample after ``reset``.
    """

    kind = "elapsed"
    param_names = ("form", "scale")

    def __init__(self, form: str = "linear", scale: float = 100.0) -> None:
        self.form = form
        self.scale = scale
        self._t0 = math.nan

    def reset(self) -> None:
        self._t0 = math.nan

    def _g(self, x: npt.ArrayLike) -> np.ndarray:
        x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
        if self.form == "sqrt":
            return np.sqrt(x)
        if self.form == "log":
            return np.log1p(x)
        return x

    def step(self, sample: Sample) -> float:
        if math.isnan(self._t0):
            self._t0 = sample.t
        g = float(self._g((sample.t - self._t0) / self.scale))
        return g * sample.s_hat if self.form == "linear_strain" else g

    def run(self, batch: Batch) -> np.ndarray:
        if batch.t.size and math.isnan(self._t0):
            self._t0 = float(batch.t[0])
        g = self._g((batch.t - self._t0) / self.scale)
        return g * batch.s_hat if self.form == "linear_strain" else g

    def params(self) -> dict[str, Any]:
        return {"form": self.form, "scale": self.scale}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Elapsed:
        return cls(_choice(params, "form", ("linear", "sqrt", "log", "linear_strain"),
                           "linear"),
                   _positive(params, "scale", 100.0))


RECALIBRATION_TERMS = ("recalibration_gain", "recalibration_offset")
"""Names of the two terms of an output gain and offset (``strain_comp.offline.recalibrate``):
a map of the output, not a term that models what moves."""
TEMPERATURE_RANGE = (-273.15, 1000.0)
"""Temperatures [deg C] a temperature term reads; one outside (below absolute zero, a
finite 1e308, NaN, inf) is a bad reading, treated as missing."""


def valid_temperature(temp: np.ndarray) -> np.ndarray:
    """Mask of readings inside ``TEMPERATURE_RANGE``."""
    return (temp >= TEMPERATURE_RANGE[0]) & (temp <= TEMPERATURE_RANGE[1])


class Temperature(Regressor):
    """Temperature dependence: g = T - t_ref (``form: offset``, a TCR shifting R) or
    g = (T - t_ref) * S_hat (``form: strain``, a temperature-dependent gauge factor).

    A missing or bad temperature (outside ``TEMPERATURE_RANGE``) holds the last valid one;
    before the first, g = 0.
    """

    kind = "temperature"
    param_names = ("form", "t_ref")

    def __init__(self, form: str = "offset", t_ref: float = 20.0) -> None:
        self.form = form
        self.t_ref = t_ref
        self._last = math.nan

    def reset(self) -> None:
        self._last = math.nan

    def step(self, sample: Sample) -> float:
        if TEMPERATURE_RANGE[0] <= sample.temperature <= TEMPERATURE_RANGE[1]:
            self._last = float(sample.temperature)
        if math.isnan(self._last):
            return 0.0
        dt = self._last - self.t_ref
        return dt * sample.s_hat if self.form == "strain" else dt

    def run(self, batch: Batch) -> np.ndarray:
        temp = batch.temperature
        if temp is None:
            temp = np.full(batch.t.size, np.nan)
        temp = np.where(valid_temperature(temp), temp, np.nan)
        held = _ffill(temp, self._last)
        if held.size:
            self._last = float(held[-1])
        dt = np.where(np.isnan(held), 0.0, held - self.t_ref)
        return dt * batch.s_hat if self.form == "strain" else dt

    def params(self) -> dict[str, Any]:
        return {"form": self.form, "t_ref": self.t_ref}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Temperature:
        return cls(_choice(params, "form", ("offset", "strain"), "offset"),
                   _number(params, "t_ref", 20.0))


class StrainLevel(Regressor):
    """g = S_hat ** power: a gain (power 1) or curvature (2, 3) error of the static map."""

    kind = "strain_level"
    param_names = ("power",)

    def __init__(self, power: int = 1) -> None:
        self.power = power

    def reset(self) -> None:
        pass

    def step(self, sample: Sample) -> float:
        return float(sample.s_hat) ** self.power

    def run(self, batch: Batch) -> np.ndarray:
        return batch.s_hat ** self.power

    def params(self) -> dict[str, Any]:
        return {"power": self.power}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> StrainLevel:
        power = params.get("power", 1)
        if isinstance(power, bool) or power not in (1, 2, 3):
            raise ParameterError("params.power", f"must be 1, 2 or 3, got {power!r}")
        return cls(int(power))


_MULLINS_FORMS = ("gap", "gap_strain", "cycles_log", "cycles_exp", "peak_strain")


@njit
def _mullins_kernel(s: np.ndarray, d: np.ndarray, form: int, n0: float,
                    state: np.ndarray) -> np.ndarray:
    """Running peak of S_hat and count of completed load cycles -> softening regressor."""
    peak, cycles, last = state[0], state[1], state[2]
    out = np.empty(s.size)
    for k in range(s.size):
        if s[k] > peak:
            peak = s[k]
        if d[k] != 0:
            if last < 0 and d[k] > 0:
                cycles += 1.0
            last = d[k]
        if form == 0:
            out[k] = peak - s[k]
        elif form == 1:
            out[k] = s[k] * (peak - s[k])
        elif form == 2:
            out[k] = s[k] * math.log1p(cycles)
        elif form == 3:
            out[k] = s[k] * math.exp(-cycles / n0)
        else:
            out[k] = s[k] * peak
    state[0], state[1], state[2] = peak, cycles, last
    return out


class Mullins(Regressor):
    """Mullins-type softening: the response depends on the strain history's peak and on
    how many load cycles the sensor has done (elastomers soften over the first cycles and
    below a previously reached strain).

    State: peak = running max of S_hat; cycles = completed load cycles (an unloading ->
    loading turn of the detector, holds ignored). ``form``: ``gap`` peak - S_hat (zero on
    virgin loading), ``gap_strain`` S_hat (peak - S_hat), ``cycles_log`` S_hat log(1 +
    cycles) (progressive softening), ``cycles_exp`` S_hat exp(-cycles / n0) (a gain excess
    that dies out over the first ~n0 cycles), ``peak_strain`` S_hat * peak (a gain loss
    that grows with the largest strain reached so far: the first-order form of the Mullins
    damage models, which soften the material in proportion to the maximum previous strain;
    it changes only while loading to a new peak, so it is told from a constant gain error
    by data whose peak grows over time).
    """

    kind = "mullins"
    param_names = ("form", "n0")

    def __init__(self, form: str = "cycles_exp", n0: float = 1.0) -> None:
        self.form = form
        self.n0 = n0
        self._code = _MULLINS_FORMS.index(form)
        self.reset()

    def reset(self) -> None:
        self._state = np.array([-np.inf, 0.0, 0.0])

    def run(self, batch: Batch) -> np.ndarray:
        return _mullins_kernel(batch.s_hat, batch.direction, self._code, self.n0, self._state)

    def params(self) -> dict[str, Any]:
        return {"form": self.form, "n0": self.n0}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Mullins:
        return cls(_choice(params, "form", _MULLINS_FORMS, "cycles_exp"),
                   _positive(params, "n0", 1.0))


STRETCH_FORMS = ("rest", "rest_log", "gain", "gain_log")
"""The forms of ``Stretch`` (its docstring), in the order of the kernel's codes."""


@njit
def _stretch_kernel(s: np.ndarray, band: float, scale: float, form: int,
                    state: np.ndarray) -> np.ndarray:
    """Stretch travel (|movement| of S_hat through a play of +-band) -> history regressor."""
    play, travel, started = state[0], state[1], state[2]
    out = np.empty(s.size)
    for k in range(s.size):
        if not math.isfinite(s[k]):
            out[k] = math.nan
            continue
        if started == 0.0:
            play, started = s[k], 1.0
        moved = min(max(play, s[k] - band), s[k] + band)
        travel += abs(moved - play)
        play = moved
        h = 1.0 - math.exp(-travel / scale) if form in (0, 2) else math.log1p(travel / scale)
        out[k] = h * s[k] if form >= 2 else h
    state[0], state[1], state[2] = play, travel, started
    return out


class Stretch(Regressor):
    """Stretch history: what the sensor has been through since the run started, as the
    strain travel x = sum |dS_hat| [%] counted through a play of +-``band`` % (so that
    noise at rest adds nothing; a 0 -> 50 -> 0 % cycle adds 100).

    ``form``: ``rest`` g = 1 - exp(-x / scale) (a rest level that moves with the stretch
    done and settles: the resistance at rest falling, or rising, a little after every
    release, as a textile thread's contacts rearrange), ``rest_log`` g = log(1 + x / scale)
    (one that keeps moving, ever slower), ``gain`` g = S_hat (1 - exp(-x / scale)) (a
    sensitivity that grows, or falls, over the first cycles and settles), ``gain_log``
    g = S_hat log(1 + x / scale) (one that keeps growing). Unlike ``mullins`` (cycles
    counted by the detector, the peak reached) it reads the amount of stretching, so a run
    of small cycles and one of few large ones age it alike.
    """

    kind = "stretch"
    param_names = ("form", "scale", "band")

    def __init__(self, form: str = "rest", scale: float = 1000.0, band: float = 0.5) -> None:
        self.form = form
        self.scale = scale
        self.band = band
        self._code = STRETCH_FORMS.index(form)
        self.reset()

    def reset(self) -> None:
        self._state = np.zeros(3)

    def run(self, batch: Batch) -> np.ndarray:
        return _stretch_kernel(batch.s_hat, self.band, self.scale, self._code, self._state)

    def params(self) -> dict[str, Any]:
        return {"form": self.form, "scale": self.scale, "band": self.band}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Stretch:
        return cls(_choice(params, "form", STRETCH_FORMS, "rest"),
                   _positive(params, "scale", 1000.0), _number(params, "band", 0.5, lo=0.0))


class Crosstalk(Regressor):
    """Cross-talk in an array: g = the S_hat of the neighbour sensor ``neighbour``.

    A neighbour's stretch couples into this sensor's resistance (shared substrate, shared
    return lead). A missing or NaN neighbour value holds the last valid one; before the
    first, g = 0.
    """

    kind = "crosstalk"
    param_names = ("neighbour",)

    def __init__(self, neighbour: str) -> None:
        self._neighbour = neighbour
        self._last = math.nan

    @property
    def neighbour(self) -> str | None:
        return self._neighbour

    def reset(self) -> None:
        self._last = math.nan

    def step(self, sample: Sample) -> float:
        value = (sample.neighbours or {}).get(self._neighbour, math.nan)
        if math.isfinite(value):
            self._last = float(value)
        return 0.0 if math.isnan(self._last) else self._last

    def run(self, batch: Batch) -> np.ndarray:
        values = batch.neighbours.get(self._neighbour)
        if values is None:
            values = np.full(batch.t.size, np.nan)
        held = _ffill(values, self._last)
        if held.size:
            self._last = float(held[-1])
        return np.where(np.isnan(held), 0.0, held)

    def params(self) -> dict[str, Any]:
        return {"neighbour": self._neighbour}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Crosstalk:
        neighbour = params.get("neighbour")
        if not isinstance(neighbour, str) or not neighbour:
            raise ParameterError("params.neighbour", f"must be a sensor name, got {neighbour!r}")
        return cls(neighbour)


@njit
def _baseline_kernel(t: np.ndarray, s: np.ndarray, window: float,
                     state: np.ndarray) -> np.ndarray:
    """Running mean of S_hat over the first ``window`` seconds after (re)start, then held."""
    t0, total, count = state[0], state[1], state[2]
    out = np.empty(t.size)
    for k in range(t.size):
        if count == 0.0:
            t0 = t[k]
        if t[k] - t0 <= window:
            total += s[k]
            count += 1.0
        out[k] = total / count
    state[0], state[1], state[2] = t0, total, count
    return out


class Baseline(Regressor):
    """Run-to-run baseline shift: g = b - rest, with b the mean of S_hat over the first
    ``window`` seconds of samples after a start (or a gap reset of the engine) and ``rest``
    [%] the strain the sensor is at when a run starts (what the calibration should read).

    Soft sensors often start each run at another resistance level (contact resistance,
    ageing, a different clamping): the whole run is then shifted by about the same
    amount, which a calibration fitted on one run cannot know. Captured online at the
    start of each run, b measures that shift; during the window g is the running mean so
    far (causal). The residual loop gives this term the coefficient 1 (the shift seen at
    rest is removed whole) and tells it from a constant ``offset`` only across runs.
    """

    kind = "baseline"
    param_names = ("window", "rest")

    def __init__(self, window: float = 5.0, rest: float = 0.0) -> None:
        self.window = window
        self.rest = rest
        self._state = np.zeros(3)

    def reset(self) -> None:
        self._state = np.zeros(3)

    def run(self, batch: Batch) -> np.ndarray:
        return _baseline_kernel(batch.t, batch.s_hat, self.window, self._state) - self.rest

    def params(self) -> dict[str, Any]:
        return {"window": self.window, "rest": self.rest}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Baseline:
        return cls(_positive(params, "window", 5.0), _number(params, "rest", 0.0))


KINDS: dict[str, type[Regressor]] = {cls.kind: cls for cls in (
    Offset, Rate, Direction, Relaxation, ResistanceMemory, Elapsed, Temperature, StrainLevel,
    Mullins, Stretch, Crosstalk, Baseline)}


def regressor_from_dict(effect: Mapping[str, Any]) -> Regressor:
    """The regressor of one effect entry; ParameterError(field, problem) if bad."""
    if not isinstance(effect, Mapping):
        raise ParameterError("(effect)", f"must be a mapping, got {type(effect).__name__}")
    name = effect.get("name")
    if not isinstance(name, str) or not name:
        raise ParameterError("name", "missing or not a string")
    kind = effect.get("kind")
    if not isinstance(kind, str) or kind not in KINDS:
        raise ParameterError("kind", f"must be one of {', '.join(KINDS)}; got {kind!r}")
    params = effect.get("params", {})
    if params is None:
        params = {}
    if not isinstance(params, Mapping):
        raise ParameterError("params", f"must be a mapping, got {type(params).__name__}")
    cls = KINDS[kind]
    unknown = sorted(str(k) for k in params if k not in cls.param_names)
    if unknown:
        raise ParameterError(f"params.{unknown[0]}", f"unknown parameter of kind {kind!r}")
    return cls.from_params(params)


def validate_effect_dict(effect: Mapping[str, Any]) -> None:
    """Check one calibration-file effect entry; ParameterError(field, problem) if bad."""
    regressor_from_dict(effect)
    require_float(effect, "coef")


def effect_dict(name: str, regressor: Regressor, coef: float) -> dict[str, Any]:
    """The calibration-file entry of a regressor with its coefficient."""
    return {"name": name, "kind": regressor.kind, "params": regressor.params(),
            "coef": float(coef)}


class EffectTerms:
    """The effect terms of one sensor, as the engine uses them:
    S_corrected = S_hat - sum_j coef_j g_j.
    """

    def __init__(self, names: Sequence[str], regressors: Sequence[Regressor],
                 coefs: npt.ArrayLike) -> None:
        self.names = list(names)
        self.regressors = list(regressors)
        self.coefs = np.asarray(coefs, dtype=np.float64).reshape(-1)
        if not len(self.names) == len(self.regressors) == self.coefs.size:
            raise ValueError("EffectTerms: names, regressors and coefs differ in length")

    @classmethod
    def from_dicts(cls, effects: Sequence[Mapping[str, Any]]) -> EffectTerms:
        """From a calibration's ``effects`` list; ParameterError names ``<i>.<field>``."""
        regressors, coefs = [], []
        for i, effect in enumerate(effects):
            try:
                validate_effect_dict(effect)
            except ParameterError as err:
                raise ParameterError(f"{i}.{err.field}", err.problem) from None
            regressors.append(regressor_from_dict(effect))
            coefs.append(float(effect["coef"]))
        return cls([str(e["name"]) for e in effects], regressors, coefs)

    def to_dicts(self) -> list[dict[str, Any]]:
        rows = zip(self.names, self.regressors, self.coefs, strict=True)
        return [effect_dict(n, g, c) for n, g, c in rows]

    def __bool__(self) -> bool:
        return bool(self.regressors)

    @property
    def neighbours(self) -> list[str]:
        """Names of the array neighbours whose S_hat these terms read."""
        return [g.neighbour for g in self.regressors if g.neighbour is not None]

    def reset(self) -> None:
        for g in self.regressors:
            g.reset()

    def rescale(self, factor: float) -> None:
        """The resistance these terms read is ``factor`` x what it was (``Regressor.rescale``)."""
        for g in self.regressors:
            g.rescale(factor)

    def step(self, t: float, r: float, s_hat: float, direction: int,
             temperature: float = math.nan,
             neighbours: Mapping[str, float] | None = None) -> float:
        """Corrected strain of one sample (advances every regressor's state)."""
        sample = Sample(t, r, s_hat, direction, temperature, neighbours)
        out = float(s_hat)
        for g, c in zip(self.regressors, self.coefs, strict=True):
            out -= c * g.step(sample)
        return out

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike, s_hat: npt.ArrayLike,
            direction: npt.ArrayLike, temperature: npt.ArrayLike | None = None,
            neighbours: Mapping[str, npt.ArrayLike] | None = None) -> np.ndarray:
        """Batch equivalent of repeated ``step``: corrected strain over arrays."""
        batch = Batch.of(t, r, s_hat, direction, temperature, neighbours)
        out = batch.s_hat.copy()
        for g, c in zip(self.regressors, self.coefs, strict=True):
            out -= c * g.run(batch)
        return out
