"""The zero of a live node's sensors: ``~/tare`` and ``tare: auto`` by the offline rules
(``core.tare``; docs/ros.md, "Services"). A good sample is one the model used, also outside
the calibrated range: a rest that moved out of it is what a tare corrects."""

from __future__ import annotations

import math

import numpy as np

from strain_comp.base.samples import used_mask
from strain_comp.core.engine import Engine
from strain_comp.core.tare import (
    REST_WINDOW,
    rest_level,
    rest_resistance_at_start,
)
from strain_comp.errors import InputError, ParameterError
from strain_comp.ros.params import NodeParams

TARE_WINDOW_S = 0.5
"""``~/tare``: the rest resistance is the median of the good samples of this last span [s]."""
RING = 4096
"""Recent samples kept at most per input for ``~/tare`` (the last 0.5 s up to 8 kHz)."""
MAX_START_SAMPLES = 2**17
"""Samples a pending automatic tare may log (5 s at 26 kHz), past them declined: a paused
sim clock would otherwise let the log grow without end."""


class _Log:
    """An input's latest raw samples (columns: its sensors) and whether the model used each."""

    def __init__(self, k: int) -> None:
        self.t = np.full(256, -math.inf)
        self.raw = np.zeros((256, k))
        self.good = np.zeros((256, k), dtype=bool)
        self.n = 0

    def add(self, t: np.ndarray, raw: np.ndarray, status: np.ndarray, keep_from: float,
            most: int) -> bool:
        """Log samples, keeping those since ``keep_from`` (False: more than ``most``)."""
        kept = True
        if self.n + t.size > self.t.size:
            keep = np.flatnonzero(self.t[:self.n] >= keep_from)
            kept = keep.size <= most
            keep = keep[max(keep.size - most, 0):]
            self.n = keep.size
            self.t[:self.n], self.raw[:self.n], self.good[:self.n] = (
                self.t[keep], self.raw[keep], self.good[keep])
            while 2 * (self.n + t.size) > self.t.size:
                self.t = np.concatenate([self.t, np.full(self.t.size, -math.inf)])
                self.raw = np.concatenate([self.raw, np.zeros(self.raw.shape)])
                self.good = np.concatenate([self.good, np.zeros(self.good.shape, dtype=bool)])
        at = slice(self.n, self.n + t.size)
        self.t[at], self.raw[at], self.good[at] = t, raw, used_mask(status)
        self.n += t.size
        return kept

    def since(self, t0: float, column: int) -> tuple[np.ndarray, np.ndarray]:
        """(times, raw values) of ``column``'s good samples with time >= t0, in time order."""
        mask = (self.t[:self.n] >= t0) & self.good[:self.n, column]
        order = np.argsort(self.t[:self.n][mask], kind="stable")
        return self.t[:self.n][mask][order], self.raw[:self.n, column][mask][order]


class LiveTare:
    """Per input, its latest samples for ``~/tare`` and ``tare: auto``; the tares in ``log``."""

    def __init__(self, engine: Engine, params: NodeParams) -> None:
        self.engine = engine
        self.calibration = params.calibration
        self.inputs = {i.name: i.sensors for i in params.inputs}
        self.recent = {i.name: _Log(len(i.sensors)) for i in params.inputs}
        self.pending: dict[str, float] = ({s: math.nan for s in params.calibration.sensors}
                                          if params.tare == "auto" else {})
        """Sensors whose automatic tare is pending: their first good sample's time (or NaN)."""
        self.log: list[str] = []

    def pending_on(self, name: str) -> bool:
        """Whether a sensor of input ``name`` waits for its automatic tare."""
        return bool(self.pending) and not self.pending.keys().isdisjoint(self.inputs[name])

    def seen(self, name: str, t: np.ndarray, raw: np.ndarray, status: np.ndarray,
             direction: np.ndarray) -> None:
        """Log samples (one while a tare is pending) and take the automatic tares they decide."""
        keep_from = float(t[-1]) - TARE_WINDOW_S
        if not self.pending_on(name):
            self.recent[name].add(t, raw, status, keep_from, RING)
            return
        firsts = [self.pending.get(s, math.nan) for s in self.inputs[name]]
        keep_from = min([keep_from] + [f for f in firsts if not math.isnan(f)])
        if self.recent[name].add(t, raw, status, keep_from, MAX_START_SAMPLES):
            self._auto_tare(name, float(t[-1]), self.recent[name], status[-1], direction[-1])
        else:
            for sensor in self.inputs[name]:
                if self.pending.pop(sensor, None) is not None:
                    self.log.append(
                        f"{sensor}: auto tare declined: {MAX_START_SAMPLES} samples within "
                        f"{REST_WINDOW:g} s of clock time (is the clock paused?); the "
                        "calibration's zero stays (call ~/tare at rest)")

    def _ohm(self, sensor: str, raw: np.ndarray) -> np.ndarray:
        return self.calibration.sensors[sensor].input.to_ohm(raw)

    def _auto_tare(self, name: str, t: float, log: _Log, status: np.ndarray,
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
            try:
                rest = rest_resistance_at_start(times, self._ohm(sensor, raw), cal.direction,
                                                pair=cal.input.pair,
                                                ended=t - start >= REST_WINDOW)
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
        """Each sensor's rest now [ohm] and calibrated rest; one without either in problems."""
        rests: dict[str, tuple[float, float]] = {}
        for name, sensors in self.inputs.items():
            recent = self.recent[name]
            latest = recent.t[recent.n - 1] if recent.n else -math.inf
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
        return "tared " + ", ".join(f"{s} (rest {r:.6g} ohm, gain {self.engine.input_gain(s):.6g})"
                                    for s, (r, _) in rests.items())
