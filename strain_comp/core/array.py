"""Sensors sampled together (an array topic), stepped as one tick (docs/design.md,
"Arrays").

When every sensor's model belongs to a family with a per-sensor kernel for the array form
and no sensor's input is corrected, one tick is one numba call per family: the APL family
(``strain_comp.models.apl_array.APLArray``, same N and M, kernel
``strain_comp.models.apl_kernels.step_sensor``) through ``apl_tick``, creep_pi
(``strain_comp.models.creep_pi.CreepPIArray``, same numbers of play operators and time
constants, kernel ``strain_comp.models.creep_kernels.step_sensor``) through
``creep_tick``. Each family's tick is a thin loop over its sensors: the shared stages
``sensor_front`` (input fix, screen, counts, detector reset on a gap; the stage kernels of
``strain_comp.core.stages``), the gap reset of the model's state rows, the model read,
the family's kernel, then ``sensor_back`` (detector, range, hold): the lifted form of the
per-sample path. An array mixing the two families runs both ticks, each over its own
sensors. The group then keeps the array's state, counters and held outputs itself, and
its sensors should not also be fed through ``Engine.step``. Sensors with effect terms are
corrected after the kernels, one by one (the slower path). Otherwise a tick is a loop of
the per-sample path over the sensors.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import cast

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
from strain_comp.models import apl_kernels, creep_kernels
from strain_comp.models.apl_array import APLArray
from strain_comp.models.creep_pi import CreepPI, CreepPIArray

# columns of the fused tick's per-sensor parameter table, then the range row (``RANGE_COLUMNS``)
_GAIN, _R1, _VIN, _R_SHORT, _R_OPEN, _DEADZONE, _TAU, _SIGN, _RANGE = range(9)
_N_PARAMS = _RANGE + len(RANGE_COLUMNS)
# columns of its per-sensor held state
_LAST_GOOD_T, _STRAIN, _DIRECTION, _LAST_STATUS = range(4)

FamilyArray = APLArray | CreepPIArray
"""The model array of one family's sensors in a fused tick."""


@njit(error_model="numpy", inline="always")
def sensor_front(k: int, t: float, raw: np.ndarray, par: np.ndarray, held: np.ndarray,
                 counts: np.ndarray, det: np.ndarray, gap: float, model_out: np.ndarray,
                 status: np.ndarray, reset: np.ndarray) -> tuple[float, bool]:
    """The stages before the model for sensor ``k`` of a tick: input fix, tare gain,
    screen, counts. Returns (resistance [ohm], used); a sample not used gets NaN in
    ``model_out[k]``. On a gap reset the detector restarts and the gap is counted; the
    caller zeroes the model's state rows (``reset[k]``)."""
    ri, forced = raw[k], sc.GOOD
    if par[k, _VIN] > 0.0:  # voltage divider
        ri, forced = divider_ohm(ri, par[k, _R1], par[k, _VIN])
    ohm = ri * par[k, _GAIN]
    code, rst = screen_one(t, ohm, forced, held[k, _LAST_GOOD_T], par[k, _R_SHORT],
                           par[k, _R_OPEN], par[k, _RANGE], par[k, _RANGE + 1], gap)
    status[k] = code
    reset[k] = rst
    counts[k, code] += 1
    held[k, _LAST_STATUS] = code
    if not sc.is_used(code):
        model_out[k] = np.nan
        return ohm, False
    if rst:
        det[k, :] = 0.0
        counts[k, counts.shape[1] - 1] += 1
    return ohm, True


@njit(error_model="numpy", inline="always")
def sensor_back(k: int, t: float, ohm: float, estimate: float, par: np.ndarray,
                held: np.ndarray, det: np.ndarray, model_out: np.ndarray) -> None:
    """The stages after the model for a used sample of sensor ``k``: the unclamped
    estimate into ``model_out[k]`` (for the effect terms), the detector, the range bound
    and the hold (``held[k]``)."""
    model_out[k] = estimate
    held[k, _DIRECTION] = direction_update(det[k], t, ohm, par[k, _DEADZONE],
                                           par[k, _TAU]) * par[k, _SIGN]
    held[k, _STRAIN] = bound(ohm, estimate, par[k, _RANGE:])
    held[k, _LAST_GOOD_T] = t


@njit(error_model="numpy")
def apl_tick(t: float, idx: np.ndarray, raw: np.ndarray, par: np.ndarray, held: np.ndarray,
             counts: np.ndarray, det: np.ndarray, gap: float, model_out: np.ndarray,
             status: np.ndarray, reset: np.ndarray, x: np.ndarray, clock: np.ndarray,
             kind: np.ndarray, sigma: np.ndarray, p: np.ndarray, rho: np.ndarray,
             inv_width: np.ndarray, w: np.ndarray, norm: np.ndarray, b: np.ndarray,
             f_at_b: np.ndarray, inv_slopes: np.ndarray) -> None:
    """One tick of the array's APL-family sensors (``idx``: their rows of the group's
    tables; row j of the model arrays is sensor ``idx[j]``). ``held[k]`` gets the published
    strain / direction / status; ``counts[k]`` = samples per status code, then gap
    resets."""
    for j in range(idx.size):
        k = idx[j]
        ohm, used = sensor_front(k, t, raw, par, held, counts, det, gap, model_out, status,
                                 reset)
        if not used:
            continue
        if reset[k]:
            x[j, :] = 0.0
            clock[j, :] = 0.0
        estimate = apl_kernels.step_sensor(j, t, model_read(ohm, par[k, _RANGE:]), x, clock,
                                           kind, sigma, p, rho, inv_width, w, norm, b,
                                           f_at_b, inv_slopes)
        sensor_back(k, t, ohm, estimate, par, held, det, model_out)


@njit(error_model="numpy")
def creep_tick(t: float, idx: np.ndarray, raw: np.ndarray, par: np.ndarray,
               held: np.ndarray, counts: np.ndarray, det: np.ndarray, gap: float,
               model_out: np.ndarray, status: np.ndarray, reset: np.ndarray, z: np.ndarray,
               play: np.ndarray, clock: np.ndarray, decay: np.ndarray, norm: np.ndarray,
               tau: np.ndarray, widths: np.ndarray, coef: np.ndarray, bias: np.ndarray
               ) -> None:
    """``apl_tick`` for the array's creep_pi sensors: a gap reset zeroes the sensor's
    state rows (a zeroed clock restarts it at rest at its next input)."""
    for j in range(idx.size):
        k = idx[j]
        ohm, used = sensor_front(k, t, raw, par, held, counts, det, gap, model_out, status,
                                 reset)
        if not used:
            continue
        if reset[k]:
            z[j, :] = 0.0
            play[j, :] = 0.0
            clock[j, :] = 0.0
            decay[j, :] = 0.0
        estimate = creep_kernels.step_sensor(j, t, model_read(ohm, par[k, _RANGE:]), z, play,
                                             clock, decay, norm, tau, widths, coef, bias)
        sensor_back(k, t, ohm, estimate, par, held, det, model_out)


def family_arrays(sensors: list[SensorState]) -> list[tuple[np.ndarray, FamilyArray]] | None:
    """(rows in ``sensors``, model array) per family present, or None when a sensor's
    model has no array kernel or a family's sensors differ in shape (the loop path)."""
    models = [s.model for s in sensors]
    apl = [i for i, m in enumerate(models) if type(m).array_kernel]
    creep = [i for i, m in enumerate(models) if isinstance(m, CreepPI)]
    if len(apl) + len(creep) != len(sensors):
        return None
    out: list[tuple[np.ndarray, FamilyArray]] = []
    try:
        if apl:
            out.append((np.array(apl, dtype=np.int64),
                        APLArray.from_models([models[i] for i in apl])))
        if creep:
            out.append((np.array(creep, dtype=np.int64),
                        CreepPIArray([cast(CreepPI, models[i]) for i in creep])))
    except ParameterError:  # different shapes within a family
        return None
    return out


class ArrayGroup:
    """The sensors of one array, stepped together (the module's doc)."""

    def __init__(self, sensors: Callable[[], dict[str, SensorState]], names: list[str],
                 gap_reset: float, deadzone_scale: float, latest: Latest) -> None:
        self._all = sensors
        self.names = names
        self.gap_reset = gap_reset
        self.deadzone_scale = deadzone_scale
        self.latest = latest
        self.kernels: list[tuple[np.ndarray, FamilyArray]] = []
        self.rebuild()

    @property
    def fused(self) -> bool:
        """True when a tick is the fused family ticks (else the per-sensor loop)."""
        return bool(self.kernels)

    def rebuild(self) -> None:
        """(Re)build from the engine's sensors: fresh state, zero counters."""
        every = self._all()
        self.sensors = [every[n] for n in self.names]
        self.kernels = []
        if not all(not s.cal.input.filtered and s.cal.input.zero_span is None
                   and s.cal.sample_interval is None for s in self.sensors):
            return
        self.kernels = family_arrays(self.sensors) or []
        if not self.kernels:
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
        if not self.kernels:
            return
        self.par[:, _DEADZONE] = [s.cal.direction.deadzone * scale for s in self.sensors]
        self.states[:] = 0.0

    def step(self, t: float, raw: np.ndarray) -> ArrayOutput:
        """One tick: ``raw`` in the array's sensor order."""
        if not self.kernels:
            return self._loop(t, raw)
        for idx, kern in self.kernels:
            if isinstance(kern, APLArray):
                apl_tick(t, idx, raw, self.par, self.held, self.counts, self.states,
                         self.gap_reset, self.model_out, self.status, self.reset, kern.x,
                         kern.clock, kern.kind, kern.sigma, kern.p, kern.rho, kern.inv_width,
                         kern.w, kern.norm, kern.b, kern.f_at_b, kern.inv_slopes)
            else:
                creep_tick(t, idx, raw, self.par, self.held, self.counts, self.states,
                           self.gap_reset, self.model_out, self.status, self.reset, kern.z,
                           kern.play, kern.clock, kern.decay, kern.norm, kern.tau,
                           kern.widths, kern.coef, kern.bias)
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
        """Counters of the kernel path's sensors (only when ``fused``)."""
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
