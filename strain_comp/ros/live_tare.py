"""The zero of a live node's sensors: ``~/tare`` and ``tare: auto`` by the offline rules
(``core.tare``; docs/ros.md, "Services"). A good sample is one the model used, also outside
the calibrated range: a rest that moved out of it is what a tare corrects."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from strain_comp.base.samples import used_mask
from strain_comp.core.engine import Engine
from strain_comp.core.tare import (
    REST_WINDOW,
    rest_level,
    rest_resistance_at_start,
    rest_resistance_when_decided,
)
from strain_comp.errors import InputError, ParameterError
from strain_comp.ros.params import NodeParams

TARE_WINDOW_S = 0.5
"""``~/tare``: the rest resistance is the median of the good samples of this last span [s]."""
RING = 4096
"""Recent samples kept per input for the tare."""
MAX_START_SAMPLES = 2**17
"""Samples an input's pending automatic tare may log (``REST_WINDOW`` = 5 s at 26 kHz); a
clock that does not advance (a paused sim clock) would otherwise let it grow without end:
past it the automatic tare is declined, the calibration's zero stays."""


@dataclass
class _Samples:
    """An input's raw samples (columns: its sensors) with their good flags (good: fed to the
    model, ``USED``, also when out of the calibrated range); ``SIZE`` rows at first."""

    SIZE: ClassVar[int] = RING
    k: int
    t: np.ndarray = field(init=False)
    raw: np.ndarray = field(init=False)
    good: np.ndarray = field(init=False)
    n: int = 0

    def __post_init__(self) -> None:
        self.t = np.full(self.SIZE, -math.inf)
        self.raw = np.zeros((self.SIZE, self.k))
        self.good = np.zeros((self.SIZE, self.k), dtype=bool)

    def since(self, t0: float, column: int) -> tuple[np.ndarray, np.ndarray]:
        """(times, raw values) of ``column``'s good samples with time >= t0, in time order."""
        m = min(self.n, self.t.size)
        mask = (self.t[:m] >= t0) & self.good[:m, column]
        order = np.argsort(self.t[:m][mask], kind="stable")
        return self.t[:m][mask][order], self.raw[:m, column][mask][order]


class _Recent(_Samples):
    """Ring of an input's latest ``RING`` samples (for ``~/tare``)."""

    def add(self, t: np.ndarray, raw: np.ndarray, status: np.ndarray) -> None:
        """Samples at times ``t`` (rows of ``raw`` and ``status``)."""
        at = (self.n + np.arange(t.size)) % RING
        self.t[at], self.raw[at], self.good[at] = t, raw, used_mask(status)
        self.n += t.size


class _StartLog(_Samples):
    """Every sample of an input since the earliest first good sample of a sensor whose
    automatic tare is pending (``keep_from``): about ``REST_WINDOW`` seconds, nothing while
    no pending sensor has had a good sample."""

    SIZE = 256

    def add(self, t: float, raw: np.ndarray, status: np.ndarray, *, keep_from: float) -> bool:
        """Log a sample (when full: drop those before ``keep_from``, then double if still
        more than half full); False past ``MAX_START_SAMPLES``."""
        if self.n == self.t.size:
            keep = np.flatnonzero(self.t[:self.n] >= keep_from)
            self.n = keep.size
            self.t[:self.n], self.raw[:self.n], self.good[:self.n] = (
                self.t[keep], self.raw[keep], self.good[keep])
            if self.n == self.t.size and self.n >= MAX_START_SAMPLES:
                return False
            if 2 * self.n > self.t.size:
                self.t = np.concatenate([self.t, np.full(self.t.size, -math.inf)])
                self.raw = np.concatenate([self.raw, np.zeros(self.raw.shape)])
                self.good = np.concatenate([self.good, np.zeros(self.good.shape, dtype=bool)])
        self.t[self.n], self.raw[self.n], self.good[self.n] = t, raw, used_mask(status)
        self.n += 1
        return True



class LiveTare:
    """Per input, the recent samples (for ``~/tare``) and, while a sensor's automatic tare
    is pending, every sample since its first good one; the tares taken, logged in ``log``."""

    def __init__(self, engine: Engine, params: NodeParams) -> None:
        self.engine = engine
        self.calibration = params.calibration
        self.inputs = {i.name: i.sensors for i in params.inputs}
        self.recent = {i.name: _Recent(len(i.sensors)) for i in params.inputs}
        self.pending: dict[str, float] = ({s: math.nan for s in params.calibration.sensors}
                                          if params.tare == "auto" else {})
        """Sensors whose automatic tare is pending: the time of their first good sample
        (NaN: none yet)."""
        self.start = ({i.name: _StartLog(len(i.sensors)) for i in params.inputs}
                      if self.pending else {})
        self.log: list[str] = []

    def seen(self, name: str, t: np.ndarray, raw: np.ndarray, status: np.ndarray,
             direction: np.ndarray) -> None:
        """Log samples of input ``name`` (rows: times; columns: its sensors) and take the
        automatic tares they decide."""
        self.recent[name].add(t, raw, status)
        start = self.start.get(name)
        if start is None:
            return
        for i in range(t.size):
            self._starting(name, float(t[i]), start, raw[i], status[i], direction[i])

    def _starting(self, name: str, t: float, start: _StartLog, raw: np.ndarray,
                  status: np.ndarray, direction: np.ndarray) -> None:
        if name not in self.start:
            return
        firsts = [self.pending[s] for s in self.inputs[name] if s in self.pending]
        if start.add(t, raw, status, keep_from=min((f for f in firsts if not math.isnan(f)),
                                                   default=math.inf)):
            self._auto_tare(name, t, start, status, direction)
        else:
            for sensor in self.inputs[name]:
                if self.pending.pop(sensor, None) is not None:
                    self.log.append(
                        f"{sensor}: auto tare declined: {MAX_START_SAMPLES} samples within "
                        f"{REST_WINDOW:g} s of clock time (is the clock paused?); the "
                        "calibration's zero stays (call ~/tare at rest)")
        if not any(s in self.pending for s in self.inputs[name]):
            del self.start[name]

    def _ohm(self, sensor: str, raw: np.ndarray) -> np.ndarray:
        return self.calibration.sensors[sensor].input.to_ohm(raw)

    def _auto_tare(self, name: str, t: float, log: _StartLog, status: np.ndarray,
                   direction: np.ndarray) -> None:
        for column, sensor in enumerate(self.inputs[name]):
            start = self.pending.get(sensor)
            if start is None:
                continue
            good = bool(used_mask(status[column]))
            if math.isnan(start):
                if good:
                    self.pending[sensor] = t
                continue
            if t - start < REST_WINDOW and not (good and direction[column] != 0):
                continue
            times, raw = log.since(start, column)
            cal = self.calibration.sensors[sensor]
            # past REST_WINDOW decided; before, the engine's detector moved and the rule's (on
            # pairs) may not have yet
            decide: Callable[..., float | None] = (
                rest_resistance_at_start if t - start >= REST_WINDOW
                else rest_resistance_when_decided)
            try:
                rest = decide(times, self._ohm(sensor, raw), cal.direction, pair=cal.input.pair)
                if rest is None:
                    continue
            except InputError as err:
                del self.pending[sensor]
                self.log.append(f"{sensor}: auto tare declined: {err}; the calibration's "
                                     "zero stays (call ~/tare at rest)")
                continue
            gain = self.engine.tare(sensor, rest)
            del self.pending[sensor]
            self.log.append(f"{sensor}: auto tare: rest resistance {rest:.6g} ohm, "
                                 f"input gain {gain:.6g}")

    def rests_now(self, problems: list[str]) -> dict[str, tuple[float, float]]:
        """Each sensor's rest level [ohm] over its input's last ``TARE_WINDOW_S`` of good
        samples and its calibrated rest (input units); a sensor without either is named in
        ``problems``."""
        rests: dict[str, tuple[float, float]] = {}
        for name, sensors in self.inputs.items():
            recent = self.recent[name]
            latest = recent.t[(recent.n - 1) % RING] if recent.n else -math.inf
            for column, sensor in enumerate(sensors):
                values = self._ohm(sensor, recent.since(latest - TARE_WINDOW_S, column)[1])
                cal = self.calibration.sensors[sensor]
                if cal.input_rest is None:
                    problems.append(f"{sensor}: the calibration stores no rest_resistance")
                elif values.size == 0:
                    problems.append(f"{sensor}: no good sample in the last {TARE_WINDOW_S} s")
                else:
                    rests[sensor] = (rest_level(values, pair=cal.input.pair), cal.input_rest)
        return rests

    def tare(self) -> str:
        """Make each sensor's current rest resistance its zero (all or none); the summary."""
        problems: list[str] = []
        rests = self.rests_now(problems)
        if problems:
            raise ParameterError("tare", "refused: " + "; ".join(problems))
        for sensor, (rest, _) in rests.items():
            self.engine.tare(sensor, rest)
            self.pending.pop(sensor, None)
        self.start.clear()  # no automatic tare is pending any more
        return "tared " + ", ".join(f"{s} (rest {r:.6g} ohm, gain {self.engine.input_gain(s):.6g})"
                                    for s, (r, _) in rests.items())
