"""The transport-free engine: calibrated strain, direction and health of every sensor."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from strain_comp.base import samples as sc
from strain_comp.base.conversion import resistance_to_divider
from strain_comp.base.direction import DirectionDetector
from strain_comp.core.array import ArrayGroup
from strain_comp.core.calibration import Calibration
from strain_comp.core.health import SensorHealth
from strain_comp.core.outputs import ArrayOutput, BatchOutput, SensorOutput
from strain_comp.core.range_policy import DEFAULT_OUT_OF_RANGE, OUT_OF_RANGE_MODES
from strain_comp.core.sensor import SensorState, run_together, scaled
from strain_comp.errors import InputError, ParameterError


def tracking_off(mode: str) -> None:
    """Refuse ``--baseline-tracking on``: baseline tracking was removed (docs/results.md)."""
    if mode != "off":
        raise InputError(f"--baseline-tracking {mode}: baseline tracking was removed (it "
                         "never acted on the generalisation benchmark); only off remains")

class Engine:
    """Calibrated strain, direction and health for every sensor of a calibration."""

    def __init__(self, calibration: Calibration, *,
                 arrays: Mapping[str, Sequence[str]] | None = None,
                 gap_reset: float = sc.DEFAULT_GAP_RESET,
                 stale_after: float = 1.0, deadzone_scale: float = 1.0,
                 out_of_range: str = DEFAULT_OUT_OF_RANGE) -> None:
        if out_of_range not in OUT_OF_RANGE_MODES:
            raise ParameterError("out_of_range", f"must be one of "
                                 f"{', '.join(OUT_OF_RANGE_MODES)}, got {out_of_range!r}")
        self.out_of_range = out_of_range
        if not gap_reset > 0:
            raise ParameterError("gap_reset", f"must be > 0 s, got {gap_reset}")
        self.calibration = calibration
        self.gap_reset = float(gap_reset)
        self.stale_after = float(stale_after)
        self.deadzone_scale = float(deadzone_scale)
        self._sensors = {name: SensorState.build(cal, self.deadzone_scale, out_of_range)
                         for name, cal in calibration.sensors.items()}
        self._arrays: dict[str, ArrayGroup] = {}
        for array, names in (arrays or {}).items():
            missing = [n for n in names if n not in self._sensors]
            if missing or not names:
                raise InputError(f"array {array!r}: sensors {missing or '(none)'} are not in "
                                 f"the calibration (known: {', '.join(self._sensors)})")
            self._arrays[array] = ArrayGroup(self._sensors, list(names), self.deadzone_scale)

    @property
    def sensors(self) -> list[str]:
        """Sensor names, in calibration order."""
        return list(self._sensors)

    @property
    def arrays(self) -> dict[str, list[str]]:
        """Array names -> ordered sensor names."""
        return {name: list(group.names) for name, group in self._arrays.items()}

    def _sensor(self, name: str) -> SensorState:
        try:
            return self._sensors[name]
        except KeyError:
            raise InputError(f"unknown sensor {name!r} (known: {', '.join(self._sensors)})") \
                from None

    def reset(self) -> None:
        """Fresh model and detector state, zeroed counters, no held output (tare gains kept)."""
        self._sensors = {name: replace(SensorState.build(s.cal, self.deadzone_scale,
                                                     self.out_of_range, s.limits), gain=s.gain)
                         for name, s in self._sensors.items()}
        for group in self._arrays.values():
            group.rebuild(self._sensors, self.deadzone_scale)

    def limits_row(self, sensor: str) -> np.ndarray:
        """The range bound's parameters of ``sensor`` (``SensorRange.row``)."""
        return self._sensor(sensor).limits.row

    def input_gain(self, sensor: str) -> float:
        """The tare gain of ``sensor``: its models see this x the measured resistance."""
        return self._sensor(sensor).gain

    def tare(self, sensor: str, rest_resistance: float) -> float:
        """Make ``rest_resistance`` (measured now, at rest) this sensor's zero."""
        reference = self._sensor(sensor).cal.input_rest
        if reference is None:
            raise ParameterError(f"{sensor}.rest_resistance",
                                 "the calibration stores none, so it cannot be tared")
        gain = reference / rest_resistance
        self.set_input_gain(sensor, gain)
        return gain

    def set_input_gain(self, sensor: str, gain: float) -> None:
        """Set the tare gain of ``sensor`` from the next sample (no step for the states)."""
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
            if sensor in group.names and group.fused:
                group.set_gain(group.names.index(sensor), float(gain))

    def set_deadzone_scale(self, scale: float) -> None:
        """Change the dead-zone scale (a node tunable); the detectors restart from rest."""
        self.deadzone_scale = float(scale)
        for sensor in self._sensors.values():
            sensor.detector = DirectionDetector(scaled(sensor.cal.direction, scale))
        for group in self._arrays.values():
            group.set_deadzone_scale(scale)

    def base_strain(self, name: str) -> float:
        """A sensor's latest clamped strain before its effect terms."""
        other = self._sensors.get(name)
        if other is None:
            return math.nan
        return other.base if other.cal.effects else other.strain

    def step(self, sensor: str, t: float, r: float, temperature: float = math.nan) -> SensorOutput:
        """One sample of one sensor: ``run`` on a batch of one."""
        out = self.run(sensor, [t], [r], None if math.isnan(temperature) else [temperature])
        std = math.nan if out.std is None else float(out.std[0])
        status = sc.Status(int(out.status[0]))
        return SensorOutput(float(out.strain[0]), int(out.direction[0]), status,
                            bool(out.out_of_range[0]),
                            float(out.resistance[0]) if status in sc.USED else math.nan, std)

    def run(self, sensor: str, t: npt.ArrayLike, r: npt.ArrayLike,
            temperature: npt.ArrayLike | None = None) -> BatchOutput:
        """One sensor over a batch (the engine's one per-sample path)."""
        s = self._sensor(sensor)
        return s.run_finish(s.run_model(t, r, temperature, self.gap_reset), self.base_strain, {})

    def run_array(self, sensors: Sequence[str], t: npt.ArrayLike, r: npt.ArrayLike,
                  temperature: Mapping[str, npt.ArrayLike | None] | None = None
                  ) -> dict[str, BatchOutput]:
        """Sensors sampled together over a batch (``run_together``)."""
        r = np.asarray(r, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != len(sensors):
            raise InputError(f"run_array: r must be (n, {len(sensors)}), got shape {r.shape}")
        return run_together({name: self._sensor(name) for name in sensors}, t, r,
                            temperature or {}, self.gap_reset, self.base_strain)

    def step_array(self, array: str, t: float, r_vector: npt.ArrayLike) -> ArrayOutput:
        """One tick of an array (``run_ticks`` of one)."""
        out = self.run_ticks(array, [t], np.asarray(r_vector, dtype=np.float64)[None, ...])
        return ArrayOutput(out.strain[0], out.direction[0], out.status[0],
                           out.out_of_range[0], None if out.std is None else out.std[0])

    def run_ticks(self, array: str, t: npt.ArrayLike, r: npt.ArrayLike,
                  temperature: npt.ArrayLike | None = None) -> ArrayOutput:
        """Ticks of an array registered at construction (``r``: (n, sensors))."""
        try:
            group = self._arrays[array]
        except KeyError:
            raise InputError(f"unknown array {array!r} (known: {', '.join(self._arrays)})") \
                from None
        times = np.ascontiguousarray(t, dtype=np.float64)
        raw = np.ascontiguousarray(r, dtype=np.float64)
        if times.ndim != 1 or raw.shape != (times.size, len(group.names)):
            raise InputError(f"array {array!r}: expected {len(group.names)} values, "
                             f"got shape {raw.shape[1:]}")
        return group.run(times, raw, None if temperature is None
                         else np.asarray(temperature, dtype=np.float64), self.gap_reset,
                         self.base_strain)

    def health(self, now: float | None = None) -> dict[str, SensorHealth]:
        """Copies of every sensor's counters."""
        kernel_health: dict[str, SensorHealth] = {}
        for group in self._arrays.values():
            if group.fused:
                kernel_health.update(group.health())
        out = {}
        for name, s in self._sensors.items():
            h = kernel_health.get(name) or replace(s.health)
            if now is not None:
                h.stale = h.last_good_t is None or now - h.last_good_t > self.stale_for(name)
            out[name] = h
        return out

    def stale_for(self, sensor: str) -> float:
        """``stale_after``, or two sample intervals of a slow instrument."""
        interval = self._sensor(sensor).cal.sample_interval
        return self.stale_after if interval is None else max(self.stale_after, 2.0 * interval)

    def warm_up(self) -> None:
        """Compile every kernel now (not on the first message): run a copy of the engine."""
        spare = Engine(self.calibration, arrays=self.arrays, gap_reset=self.gap_reset,
                       deadzone_scale=self.deadzone_scale)
        mid = {}  # a raw input value in the middle of each valid range
        for name, cal in self.calibration.sensors.items():
            r_mid = 0.5 * (cal.valid_range.r_lo + cal.valid_range.r_hi)
            mid[name] = (float(resistance_to_divider(r_mid, *cal.input.divider()))
                         if cal.input.kind == "divider" else r_mid)
        for name, value in mid.items():
            spare.run(name, np.array([1.0, 2.0]), np.array([value, value]))
        for array, names in spare.arrays.items():
            spare.step_array(array, 3.0, np.array([mid[n] for n in names]))

