"""Sensors sampled together (an array topic), stepped as one tick (docs/design.md,
"Arrays").

When every sensor's model supplies a per-sensor kernel for the array form (the APL
family, same N and M: ``strain_comp.models.apl_array.APLArray``, whose kernel
``strain_comp.models.apl_kernels.step_sensor`` steps one sensor's row) and no sensor's
input is corrected, one tick is one call of ``array_tick``: the stages of
``strain_comp.core.stages`` run over the sensors around that kernel (input fix, screen,
gap reset, model read, detector, range, hold), the lifted form of the per-sample path.
The group then keeps the array's state, counters and held outputs itself, and its
sensors should not also be fed through ``Engine.step``. Sensors with effect terms are
corrected after the kernel, one by one (the slower path). Otherwise a tick is a loop of
the per-sample path over the sensors.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from strain_comp._numba import njit
from strain_comp.core import samples as sc
from strain_comp.core.direction import STATE_SIZE, direction_update
from strain_comp.core.health import SensorHealth, add_counts
from strain_comp.core.outputs import ArrayOutput, SensorOutput
from strain_comp.core.samples import USED_CODE, Status, screen_one
from strain_comp.core.sensor import Latest, Pending, SensorState
from strain_comp.core.stages import RANGE_COLUMNS, S_HI, S_LO, bound, divider_ohm, model_read
from strain_comp.errors import ParameterError
from strain_comp.models.apl_array import APLArray
from strain_comp.models.apl_kernels import step_sensor

# columns of the fused tick's per-sensor parameter table, then the range row (``RANGE_COLUMNS``)
_GAIN, _R1, _VIN, _R_SHORT, _R_OPEN, _DEADZONE, _TAU, _SIGN, _RANGE = range(9)
_N_PARAMS = _RANGE + len(RANGE_COLUMNS)
# columns of its per-sensor held state
_LAST_GOOD_T, _STRAIN, _DIRECTION, _LAST_STATUS = range(4)


@njit(error_model="numpy")
def array_tick(t: float, raw: np.ndarray, par: np.ndarray, held: np.ndarray,
               counts: np.ndarray, det: np.ndarray, gap: float, model_out: np.ndarray,
               status: np.ndarray, reset: np.ndarray, x: np.ndarray, clock: np.ndarray,
               kind: np.ndarray, sigma: np.ndarray, p: np.ndarray, rho: np.ndarray,
               inv_width: np.ndarray, w: np.ndarray, norm: np.ndarray, b: np.ndarray,
               f_at_b: np.ndarray, inv_slopes: np.ndarray) -> None:
    """One array tick, all sensors, in one call: the per-sample stages around the model's
    per-sensor kernel (``step_sensor``). ``held[k]`` gets the published strain /
    direction / status; ``model_out[k]`` the unclamped model estimate of a used sample
    (NaN if bad), for the effect terms; ``counts[k]`` = samples per status code, then gap
    resets."""
    for k in range(raw.size):
        row = par[k, _RANGE:]
        ri, forced = raw[k], sc.GOOD
        if par[k, _VIN] > 0.0:  # voltage divider
            ri, forced = divider_ohm(ri, par[k, _R1], par[k, _VIN])
        ohm = ri * par[k, _GAIN]
        code, rst = screen_one(t, ohm, forced, held[k, _LAST_GOOD_T], par[k, _R_SHORT],
                               par[k, _R_OPEN], row[0], row[1], gap)
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
        estimate = step_sensor(k, t, model_read(ohm, row), x, clock, kind, sigma, p, rho,
                               inv_width, w, norm, b, f_at_b, inv_slopes)
        model_out[k] = estimate
        held[k, _DIRECTION] = direction_update(det[k], t, ohm, par[k, _DEADZONE],
                                               par[k, _TAU]) * par[k, _SIGN]
        held[k, _STRAIN] = bound(ohm, estimate, row)
        held[k, _LAST_GOOD_T] = t


class ArrayGroup:
    """The sensors of one array, stepped together (the module's doc)."""

    def __init__(self, sensors: Callable[[], dict[str, SensorState]], names: list[str],
                 gap_reset: float, deadzone_scale: float, latest: Latest) -> None:
        self._all = sensors
        self.names = names
        self.gap_reset = gap_reset
        self.deadzone_scale = deadzone_scale
        self.latest = latest
        self.kernel: APLArray | None = None
        self.rebuild()

    def rebuild(self) -> None:
        """(Re)build from the engine's sensors: fresh state, zero counters."""
        every = self._all()
        self.sensors = [every[n] for n in self.names]
        self.kernel = None
        if not all(type(s.model).array_kernel and not s.cal.input.filtered
                   and s.cal.input.zero_span is None
                   and s.cal.sample_interval is None for s in self.sensors):
            return
        try:
            self.kernel = APLArray.from_models([s.model for s in self.sensors])
        except ParameterError:  # different N or M: fall back to the loop
            return
        k = len(self.sensors)
        par = np.zeros((k, _N_PARAMS))
        for i, s in enumerate(self.sensors):
            if s.cal.input.kind == "divider":
                par[i, _R1], par[i, _VIN] = s.cal.input.divider()
            par[i, _R_SHORT], par[i, _R_OPEN] = s.limits.r_short, s.limits.r_open
            par[i, _TAU] = s.cal.direction.tau
            par[i, _SIGN] = s.cal.direction.sign
            par[i, _RANGE:] = s.limits.row
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
        self.set_deadzone_scale(self.deadzone_scale)
        self.effects = [i for i, s in enumerate(self.sensors) if s.cal.effects]

    def set_gain(self, index: int, gain: float) -> None:
        """The tare gain of the ``index``-th sensor (kernel path)."""
        self.par[index, _GAIN] = gain

    def set_deadzone_scale(self, scale: float) -> None:
        """Every dead zone x ``scale``; the detectors restart from rest (kernel path)."""
        self.deadzone_scale = scale
        if self.kernel is None:
            return
        self.par[:, _DEADZONE] = [s.cal.direction.deadzone * scale for s in self.sensors]
        self.states[:] = 0.0

    def step(self, t: float, raw: np.ndarray) -> ArrayOutput:
        """One tick: ``raw`` in the array's sensor order."""
        if self.kernel is None:
            return self._loop(t, raw)
        kern = self.kernel
        array_tick(t, raw, self.par, self.held, self.counts, self.states, self.gap_reset,
                   self.model_out, self.status, self.reset, kern.x, kern.clock, kern.kind,
                   kern.sigma, kern.p, kern.rho, kern.inv_width, kern.w, kern.norm, kern.b,
                   kern.f_at_b, kern.inv_slopes)
        status = self.status.copy()
        if self.effects:
            self._effects(t, raw)
        return ArrayOutput(self.held[:, _STRAIN].copy(),
                           self.held[:, _DIRECTION].astype(np.int8), status,
                           status == sc.OUT_OF_RANGE)

    def _loop(self, t: float, raw: np.ndarray) -> ArrayOutput:
        """One tick as the per-sample path of each sensor (cross-talk terms read the
        neighbours' clamped pre-effect estimate of this tick)."""
        pending = [s.step_model(t, float(value), self.gap_reset)
                   for s, value in zip(self.sensors, raw, strict=True)]
        bases = {name: p.base(s) if isinstance(p, Pending) else math.nan
                 for name, s, p in zip(self.names, self.sensors, pending, strict=True)}
        outputs = [p if isinstance(p, SensorOutput) else
                   s.step_finish(p, math.nan, self.latest, bases)
                   for s, p in zip(self.sensors, pending, strict=True)]
        return ArrayOutput(np.array([o.strain for o in outputs]),
                           np.array([o.direction for o in outputs], dtype=np.int8),
                           np.array([o.status for o in outputs], dtype=np.int8),
                           np.array([o.out_of_range for o in outputs]))

    def _effects(self, t: float, raw: np.ndarray) -> None:
        """Effect terms of the tick's used sensors (neighbours read clamped estimates)."""
        base = np.clip(self.model_out, self.par[:, _RANGE + S_LO], self.par[:, _RANGE + S_HI])
        for i in self.effects:
            s = self.sensors[i]
            if self.reset[i]:
                s.effects.reset()
            if not USED_CODE[self.status[i]]:
                continue
            ohm, _ = s.to_ohm(raw[i:i + 1])
            nbrs = {n: base[self.names.index(n):self.names.index(n) + 1]
                    for n in s.effects.neighbours if n in self.names}
            strain = s.apply_effects(
                np.array([t]), ohm, self.model_out[i:i + 1],
                self.held[i:i + 1, _DIRECTION].astype(np.int8), np.array([math.nan]),
                self.latest, nbrs)
            self.held[i, _STRAIN] = bound(float(ohm[0]), float(strain[0]), s.limits.row)

    def health(self) -> dict[str, SensorHealth]:
        """Counters of the kernel path's sensors (only when ``kernel`` is set)."""
        out = {}
        for k, name in enumerate(self.names):
            h = SensorHealth(n_gaps=int(self.counts[k, -1]))
            add_counts(h, self.counts[k])
            if self.held[k, _LAST_GOOD_T] > -math.inf:
                h.last_good_t = float(self.held[k, _LAST_GOOD_T])
            if self.held[k, _LAST_STATUS] >= 0:
                h.last_status = Status(int(self.held[k, _LAST_STATUS]))
            out[name] = h
        return out
