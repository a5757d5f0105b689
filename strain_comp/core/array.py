"""Sensors sampled together (an array topic), run as ticks (docs/models.md, "Arrays")."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp._numba import njit, specialise
from strain_comp.base import samples as sc
from strain_comp.base.conversion import divider_ohm
from strain_comp.base.direction import STATE_SIZE, direction_update
from strain_comp.base.lift import LiftedArray, kernel
from strain_comp.base.registry import array_families
from strain_comp.base.samples import USED_CODE, Status, screen_one
from strain_comp.core.health import SensorHealth, add_counts
from strain_comp.core.outputs import ArrayOutput
from strain_comp.core.sensor import Latest, SensorState, run_together
from strain_comp.core.stages import RANGE_COLUMNS, bound, model_read
from strain_comp.core.uncertainty import N_FEATURES, features_one, sigma
from strain_comp.core.uncertainty import STATE_SIZE as BAND_SIZE
from strain_comp.errors import ParameterError

if TYPE_CHECKING:
    from numba.core.dispatcher import Dispatcher

# columns of the fused tick's per-sensor parameter table, then the range row (``RANGE_COLUMNS``),
# then the uncertainty weights (``strain_comp.core.uncertainty.FEATURES``)
_GAIN, _R1, _VIN, _R_SHORT, _R_OPEN, _DEADZONE, _TAU, _SIGN, _BAND, _RANGE = range(10)
_WEIGHTS = _RANGE + len(RANGE_COLUMNS)
_N_PARAMS = _WEIGHTS + N_FEATURES
# columns of its per-sensor held state
_LAST_GOOD_T, _STRAIN, _DIRECTION, _LAST_STATUS, _STD = range(5)


@njit(error_model="numpy", inline="always")
def sensor_front(k: int, t: float, raw: np.ndarray, par: np.ndarray, held: np.ndarray,
                 counts: np.ndarray, det: np.ndarray, gap: float, status: np.ndarray,
                 reset: np.ndarray) -> tuple[float, bool]:
    """The stages before the model for sensor ``k`` of a tick: (resistance, used)."""
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
    if not USED_CODE[code]:
        return ohm, False
    if rst:
        det[k, :] = 0.0
        counts[k, counts.shape[1] - 1] += 1
    return ohm, True


@njit(error_model="numpy", inline="always")
def sensor_back(k: int, t: float, ohm: float, estimate: float, par: np.ndarray,
                held: np.ndarray, det: np.ndarray, band: np.ndarray, x: np.ndarray) -> None:
    """The stages after the model for a used sample of sensor ``k``."""
    held[k, _DIRECTION] = direction_update(det[k], t, ohm, par[k, _DEADZONE],
                                           par[k, _TAU]) * par[k, _SIGN]
    held[k, _STRAIN] = bound(ohm, estimate, par[k, _RANGE:])
    if par[k, _BAND] > 0.0:
        features_one(t, held[k, _DIRECTION], ohm, held[k, _STRAIN], band[k], par[k, _RANGE:],
                     x)
        held[k, _STD] = sigma(x, par[k, _WEIGHTS:])
    held[k, _LAST_GOOD_T] = t


def family_tick(t: np.ndarray, idx: np.ndarray, raw: np.ndarray, par: np.ndarray,
                held: np.ndarray, counts: np.ndarray, det: np.ndarray, gap: float,
                status: np.ndarray, reset: np.ndarray, band: np.ndarray, x: np.ndarray,
                state: tuple[np.ndarray, ...], params: tuple[Any, ...], out: np.ndarray,
                out_status: np.ndarray) -> None:
    """Template: ticks ``t`` of one family's sensors around its kernel, into ``out``."""
    arrays = state + params
    for i in range(t.size):
        for j in range(idx.size):
            k = idx[j]
            ohm, used = sensor_front(k, t[i], raw[i], par, held, counts, det, gap, status,
                                     reset)
            if used:
                if reset[k]:
                    for rows in state:
                        rows[j, :] = 0.0
                estimate = kernel(j, t[i], model_read(ohm, par[k, _RANGE:]), *arrays)
                sensor_back(k, t[i], ohm, estimate, par, held, det, band, x)
            out[i, 0, k] = held[k, _STRAIN]
            out[i, 1, k] = held[k, _DIRECTION]
            out[i, 2, k] = held[k, _STD]
            out_status[i, k] = status[k]


@functools.cache
def family_tick_of(family: type[LiftedArray]) -> Dispatcher[Any]:
    """The family's tick: ``family_tick`` bound to the family's kernel."""
    return specialise(family_tick, {"kernel": family.kernel}, error_model="numpy")


class ArrayGroup:
    """The sensors of one array, stepped together."""

    def __init__(self, sensors: Mapping[str, SensorState], names: list[str],
                 deadzone_scale: float) -> None:
        self.names = names
        self.rebuild(sensors, deadzone_scale)

    @property
    def fused(self) -> bool:
        """True when a tick is the fused family ticks (else the per-sensor loop)."""
        return bool(self.kernels)

    def rebuild(self, sensors: Mapping[str, SensorState], deadzone_scale: float) -> None:
        """(Re)build from the engine's sensors: fresh state, zero counters."""
        self.sensors = [sensors[n] for n in self.names]
        self.banded = any(s.weights is not None for s in self.sensors)
        self.kernels: list[tuple[np.ndarray, LiftedArray]] = []
        if not all(not s.cal.input.filtered and s.cal.input.zero_span is None
                   and s.cal.sample_interval is None and not s.cal.effects
                   for s in self.sensors):
            return
        models, families = [s.model for s in self.sensors], array_families()
        rows = [[i for i, m in enumerate(models) if family.accepts(m)] for family in families]
        if sum(len(r) for r in rows) != len(models):  # a model without an array form
            return
        try:  # the model arrays of the families present
            self.kernels = [(np.array(r, dtype=np.int64), family([models[i] for i in r]))
                            for family, r in zip(families, rows, strict=True) if r]
        except ParameterError:  # different shapes within a family
            return
        k = len(self.sensors)
        par = np.zeros((k, _N_PARAMS))
        for i, s in enumerate(self.sensors):
            if s.cal.input.kind == "divider":
                par[i, _R1], par[i, _VIN] = s.cal.input.divider()
            par[i, _R_SHORT], par[i, _R_OPEN] = s.limits.r_short, s.limits.r_open
            par[i, _TAU] = s.cal.direction.tau
            par[i, _SIGN] = s.cal.direction.sign
            par[i, _RANGE:_WEIGHTS] = s.limits.row
            if s.weights is not None:
                par[i, _BAND] = 1.0
                par[i, _WEIGHTS:] = s.weights
        par[:, _GAIN] = [s.gain for s in self.sensors]
        self.par = par
        before = np.zeros(5)  # the held row before any sample: no good t, strain, status, std
        before[[_LAST_GOOD_T, _STRAIN, _LAST_STATUS, _STD]] = -math.inf, math.nan, -1, math.nan
        self.held = np.tile(before, (k, 1))
        self.band = np.full((k, BAND_SIZE), math.nan)
        self.x = np.empty(N_FEATURES)
        self.counts = np.zeros((k, len(Status) + 1), dtype=np.int64)
        self.states = np.zeros((k, STATE_SIZE))
        self.status = np.empty(k, dtype=np.int8)
        self.reset = np.empty(k, dtype=np.bool_)
        self.set_deadzone_scale(deadzone_scale)

    def set_gain(self, index: int, gain: float) -> None:
        """The tare gain of the ``index``-th sensor (kernel path)."""
        self.par[index, _GAIN] = gain

    def set_deadzone_scale(self, scale: float) -> None:
        """Every dead zone x ``scale``; the detectors restart from rest (kernel path)."""
        if not self.kernels:
            return
        self.par[:, _DEADZONE] = [s.cal.direction.deadzone * scale for s in self.sensors]
        self.states[:] = 0.0

    def run(self, t: np.ndarray, raw: np.ndarray, temperature: np.ndarray | None,
            gap_reset: float, latest: Latest) -> ArrayOutput:
        """Ticks ``t`` (rows of ``raw`` and ``temperature``): every field one row per tick."""
        if not self.kernels:  # each sensor's batch path (``run_together``)
            temps = {} if temperature is None else dict(zip(self.names, temperature.T, strict=True))
            outs = list(run_together(dict(zip(self.names, self.sensors, strict=True)), t, raw,
                                     temps, gap_reset, latest).values())
            nan = np.full(t.size, math.nan)
            return ArrayOutput(np.column_stack([o.strain for o in outs]),
                               np.column_stack([o.direction for o in outs]).astype(np.int8),
                               np.column_stack([o.status for o in outs]).astype(np.int8),
                               np.column_stack([o.out_of_range for o in outs]),
                               np.column_stack([nan if o.std is None else o.std for o in outs])
                               if self.banded else None)
        n, k = t.size, len(self.names)
        out = np.empty((n, 3, k))
        status = np.empty((n, k), dtype=np.int8)
        for idx, kern in self.kernels:
            tick = family_tick_of(type(kern))
            tick(t, idx, raw, self.par, self.held, self.counts, self.states, gap_reset,
                 self.status, self.reset, self.band, self.x, kern.state, kern.params, out,
                 status)
        return ArrayOutput(out[:, 0], out[:, 1].astype(np.int8), status,
                           status == sc.OUT_OF_RANGE, out[:, 2] if self.banded else None)

    def health(self) -> dict[str, SensorHealth]:
        """Counters of the kernel path's sensors (only when ``fused``)."""
        out = {}
        for k, name in enumerate(self.names):
            h = SensorHealth()
            add_counts(h, self.counts[k])
            if self.held[k, _LAST_GOOD_T] > -math.inf:
                h.last_good_t = float(self.held[k, _LAST_GOOD_T])
            if self.held[k, _LAST_STATUS] >= 0:
                h.last_status = Status(int(self.held[k, _LAST_STATUS]))
            out[name] = h
        return out
