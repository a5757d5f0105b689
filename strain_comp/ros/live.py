"""What the live node does with each message, free of any transport.

The rclpy node holds one ``LiveCompensator``: it builds the engine from validated node
parameters, compiles its kernels at start-up (not on the first message), reads a
Float64MultiArray's layout, applies the publish-rate limit and tunable changes, keeps the
recent good samples the tare needs, and turns health into diagnostic statuses. The node
only moves messages, so a bag played through it gives what ``replay`` gives.

Time: every input is stamped with the node's clock when its callback runs (std_msgs/Float64
and Float64MultiArray carry no stamp): ROS time, i.e. /clock under ``use_sim_time``. Under
sim time a player publishes a /clock tick before each input, but the two travel on different
topics and may arrive in either order; ``ClockGate`` therefore holds an input whose clock
reading equals the previous input's stamp until the next tick (one held input per topic),
so the input takes its own tick's time either way.

Tare (multiplicative, ``Engine.tare``): the zero is a rest resistance R0 measured now, the
models then see R x (calibration rest resistance / R0). A good sample here is one the engine
fed to its model (``USED``), also when it lies outside the calibrated range: a rest that
moved out of the range is what a tare corrects.

- ``tare()`` (the node's ``~/tare`` service): R0 = ``core.tare.rest_level`` (median of pair
  means) of each sensor's good samples of the last ``TARE_WINDOW_S`` seconds; all sensors or
  none (a refusal names each reason).
- ``tare: auto`` (parameter): R0 = ``core.tare.rest_resistance_at_start``, the rule
  ``--tare auto`` applies offline, on the good samples since a sensor's first good sample,
  evaluated once the rule's own detector (on pair values) leaves hold or
  ``core.tare.TARE_WINDOW`` seconds have passed (``core.tare.rest_resistance_when_decided``;
  every sample since then, however fast the input), so it takes the zero ``--tare auto``
  takes offline. A run that
  did not start at rest is not tared (logged with the reason), as offline: a later hold
  may be under load, no zero to take; the calibration's zero stays until ``~/tare`` is
  called at a known rest.

Known strains (``fuse_references: true``; ``strain_comp.core.fusion``): a reference on
``NAME/strain_reference`` (``on_reference``), on ``ARRAY/strain_reference`` (one value per
sensor, NaN for none; ``on_reference_array``) or from ``~/reference`` (every sensor is at
``known_strain`` now; ``reference_now``) is paired with the sensor's latest estimate and
fused into its output gain and offset; every later output is g x estimate + b. A
reference is refused and counted (by reason, in the sensor's /diagnostics) when the sensor
has no recent estimate within its calibrated range, or the fusion refuses it (non-finite,
beyond the gate); one naming a sensor not calibrated is refused as a message.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.core.effects import TEMPERATURE_RANGE
from strain_comp.core.engine import (
    USED,
    ArrayOutput,
    Engine,
    SensorHealth,
    SensorOutput,
    Status,
    diagnostics,
    used_mask,
)
from strain_comp.core.fusion import OutputFusion
from strain_comp.core.tare import (
    TARE_WINDOW,
    rest_level,
    rest_resistance_at_start,
    rest_resistance_when_decided,
)
from strain_comp.core.tracking import fitted_rest, tracker_for
from strain_comp.errors import InputError, ParameterError, StrainCompError
from strain_comp.io.multiarray import array_values
from strain_comp.ros.params import TUNABLE, NodeParams, validate_tunable

TARE_WINDOW_S = 0.5
"""``~/tare``: the rest resistance is the median of the good samples of this last span [s]."""
RING = 4096
"""Recent samples kept per input for the tare."""
MAX_START_SAMPLES = 2**17
"""Samples an input's pending automatic tare may log (``TARE_WINDOW`` = 5 s at 26 kHz); a
clock that does not advance (a paused sim clock) would otherwise let it grow without end:
past it the automatic tare is declined, the calibration's zero stays."""
BAD_REASON = {Status.NOT_FINITE: "non-finite input", Status.NON_POSITIVE: "non-positive input",
              Status.TIME_NOT_INCREASING: "time not increasing",
              Status.OPEN_CIRCUIT: "open circuit", Status.SHORT_CIRCUIT: "short circuit"}
ERROR, STALE, WARN, OK = 2, 3, 1, 0
MAX_REFUSAL_KEYS = 32
"""Distinct refusal reasons counted (``NAME: reason``), each a /diagnostics value; further
reasons count under ``NAME: other reasons`` (a peer varying a message cannot grow them)."""
MAX_REASON_CHARS = 160
"""A refusal reason longer than this is cut in its counter's key."""
_COUNTS = tuple(f.name for f in fields(SensorHealth) if f.name.startswith("n_"))


class ClockGate:
    """Under sim time: an input whose clock reading [ns] equals the previous input's stamp on
    the same topic waits for the next clock tick; a second such input releases the first at
    the unchanged time (it then counts as time-not-increasing, as it would without the gate).
    """

    def __init__(self) -> None:
        self.last: dict[str, int] = {}
        self.held: dict[str, Any] = {}

    def arrive(self, name: str, now_ns: int, item: Any) -> list[tuple[int, Any]]:
        """(stamp, item) pairs to process now, in order."""
        out = []
        if name in self.held:
            out.append((now_ns, self.held.pop(name)))
        elif self.last.get(name) == now_ns:
            self.held[name] = item
            return out
        self.last[name] = now_ns
        out.append((now_ns, item))
        return out

    def tick(self, now_ns: int) -> list[tuple[int, Any]]:
        """The clock moved to ``now_ns``: the held inputs to process now, stamped with it."""
        out = [(now_ns, item) for item in self.held.values()]
        for name in self.held:
            self.last[name] = now_ns
        self.held.clear()
        return out


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

    def _store(self, i: int, t: float, raw: np.ndarray, status: np.ndarray) -> None:
        self.t[i], self.raw[i] = t, raw
        self.good[i] = used_mask(status)
        self.n += 1

    def since(self, t0: float, column: int) -> tuple[np.ndarray, np.ndarray]:
        """(times, raw values) of ``column``'s good samples with time >= t0, in time order."""
        m = min(self.n, self.t.size)
        mask = (self.t[:m] >= t0) & self.good[:m, column]
        order = np.argsort(self.t[:m][mask], kind="stable")
        return self.t[:m][mask][order], self.raw[:m, column][mask][order]


class _Recent(_Samples):
    """Ring of an input's latest ``RING`` samples (for ``~/tare``)."""

    def add(self, t: float, raw: np.ndarray, status: np.ndarray) -> None:
        self._store(self.n % RING, t, raw, status)


class _StartLog(_Samples):
    """Every sample of an input since the earliest first good sample of a sensor whose
    automatic tare is pending (``keep_from``): about ``TARE_WINDOW`` seconds, nothing while
    no pending sensor has had a good sample."""

    SIZE = 256

    def add(self, t: float, raw: np.ndarray, status: np.ndarray, *, keep_from: float) -> bool:
        """Log a sample; when full, first drop the samples before ``keep_from`` [s], then
        double if still more than half full (amortised O(1) per sample). False (nothing
        logged) when that would pass ``MAX_START_SAMPLES``."""
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
        self._store(self.n, t, raw, status)
        return True


class LiveCompensator:
    """One engine plus the per-input bookkeeping of a live node."""

    def __init__(self, params: NodeParams, *, warm_up: bool = True) -> None:
        self.params = params
        self.tunables = dict(params.tunables)
        self.engine: Engine = params.build_engine()
        if warm_up:
            self.engine.warm_up()
        if params.tare == "auto":
            missing = [n for n, c in params.calibration.sensors.items()
                       if c.rest_resistance is None]
            if missing:
                raise ParameterError("tare", f"auto needs 'rest_resistance' in the calibration "
                                     f"of {', '.join(missing)}")
        self._last_publish: dict[str, float] = {}
        self.temperature: dict[str, float] = {}
        self._inputs = {i.name: i.sensors for i in params.inputs}
        self._recent = {i.name: _Recent(len(i.sensors)) for i in params.inputs}
        self._last_message: dict[str, float] = {}
        self._auto: dict[str, float] = ({s: math.nan for s in params.calibration.sensors}
                                        if params.tare == "auto" else {})
        self._start = ({i.name: _StartLog(len(i.sensors)) for i in params.inputs}
                       if self._auto else {})
        self.tracker = tracker_for(self.engine, params.baseline_tracking)
        self.refused: Counter[str] = Counter()
        self._refused_seen = 0
        self._counted_before: dict[str, SensorHealth] = {}
        """Health counters of the calibrations this one replaced (``reload``)."""
        self.tare_log: list[str] = []
        self.fusion: dict[str, OutputFusion] = (
            {s: OutputFusion.for_span(fitted_rest(c.valid_range)[1])
             for s, c in params.calibration.sensors.items()}
            if params.fuse_references else {})
        """Per sensor, its fused output gain and offset (``fuse_references: on``)."""
        self._estimate: dict[str, tuple[float, float, bool]] = {}
        """Per single sensor, its latest estimate before fusion: (time, strain, within the
        calibrated range), of a sample the model used."""
        self._array_estimate: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        """Per array, the same as three vectors (times, NaN before a first used sample;
        strains; within the range), updated in place each tick."""
        self._column = {s: (i.name, j) for i in params.inputs if i.is_array
                        for j, s in enumerate(i.sensors)}
        """Array sensors: (array, column)."""
        self._maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        """Per array, its sensors' fused gains and offsets (``_fused_array``)."""

    # --- messages -------------------------------------------------------------------------

    def _due(self, name: str, t: float) -> bool:
        """Publish-rate limit on message time: at most one output per 1/rate seconds."""
        rate = self.tunables["publish_rate_limit_hz"]
        last = self._last_publish.get(name)
        if rate > 0.0 and last is not None and 0.0 <= t - last < 1.0 / rate:
            return False
        self._last_publish[name] = t
        return True

    def on_sensor(self, name: str, t: float, value: float) -> SensorOutput | None:
        """Feed one resistance message; the output to publish, or None (rate limited, or no
        estimate yet: a bad sample before any good one holds no finite strain)."""
        if self.tracker is not None:
            self.tracker.advance(name, t)
        out = self.engine.step(name, t, value, self.temperature.get(name, math.nan))
        if self.tracker is not None:
            self.tracker.observe(name, t, out)
        self._seen(name, t, np.array([value]), np.array([out.status]),
                   np.array([out.direction]))
        if out.status in USED and not math.isfinite(out.strain):  # a good sample: never NaN
            raise InputError("the calibration gave a non-finite strain; not published")
        if self.fusion:
            if out.status in USED:
                self._estimate[name] = (t, out.strain, out.status != Status.OUT_OF_RANGE)
            out = replace(out, strain=self.fusion[name].apply(out.strain))
        return out if math.isfinite(out.strain) and self._due(name, t) else None

    def on_array(self, name: str, t: float, data: Any, *, offset: int = 0,
                 sizes: list[int] | None = None, label: str = "") -> ArrayOutput | None:
        """Feed one array message (its ``data``, ``layout.data_offset``, ``dim[*].size``,
        ``dim[0].label``); None as ``on_sensor`` (until every sensor has an estimate)."""
        sensors = self._inputs[name]
        values = array_values(data, offset, sizes or [], len(sensors), label, sensors)
        out = self.engine.step_array(name, t, values)
        self._seen(name, t, values, out.status, out.direction)
        if (used_mask(out.status) & ~np.isfinite(out.strain)).any():  # good samples: never NaN
            raise InputError("the calibration gave a non-finite strain; not published")
        if self.fusion:
            out = self._fused_array(name, t, out)
        return out if np.isfinite(out.strain).all() and self._due(name, t) else None

    def _fused_array(self, name: str, t: float, out: ArrayOutput) -> ArrayOutput:
        """``out`` with each sensor's fused gain and offset applied; its used samples'
        estimates kept for the references."""
        used = used_mask(out.status)
        k = used.size
        times, strains, inside = self._array_estimate.setdefault(
            name, (np.full(k, np.nan), np.full(k, np.nan), np.zeros(k, bool)))
        times[used] = t
        strains[used] = out.strain[used]
        inside[used] = out.status[used] != int(Status.OUT_OF_RANGE)
        if name not in self._maps:
            self._maps[name] = (np.array([self.fusion[s].gain for s in self._inputs[name]]),
                                np.array([self.fusion[s].offset for s in self._inputs[name]]))
        gain, offset = self._maps[name]
        return replace(out, strain=gain * out.strain + offset)

    # --- known strains --------------------------------------------------------------------

    def on_reference(self, sensor: str, t: float, value: Any) -> str | None:
        """A known strain of ``sensor`` at time ``t`` [s] (its ``strain_reference`` topic):
        fused (None) or refused and counted (the reason). InputError for a sensor that is
        not calibrated here or while ``fuse_references`` is false."""
        fusion = self.fusion.get(sensor)
        if fusion is None:
            raise InputError(f"no sensor {sensor!r} in the calibration" if self.fusion else
                             "fuse_references is false")
        latest = self._latest(sensor)
        if latest is None:
            return fusion.refuse("no estimate yet")
        if not latest[2]:
            return fusion.refuse("estimate out of the calibrated range")
        if not t - latest[0] <= self.engine.stale_for(sensor):
            return fusion.refuse("no recent estimate")
        reason = fusion.update(t, latest[1], value)
        if reason is None:
            for array, sensors in self._inputs.items():
                if sensor in sensors:
                    self._maps.pop(array, None)
        return reason

    def _latest(self, sensor: str) -> tuple[float, float, bool] | None:
        """A sensor's latest estimate before fusion (time, strain, within the range)."""
        if sensor not in self._column:
            return self._estimate.get(sensor)
        array, column = self._column[sensor]
        vectors = self._array_estimate.get(array)
        if vectors is None or np.isnan(vectors[0][column]):
            return None
        return (float(vectors[0][column]), float(vectors[1][column]), bool(vectors[2][column]))

    def on_reference_array(self, name: str, t: float, data: Any, *, offset: int = 0,
                           sizes: list[int] | None = None, label: str = ""
                           ) -> dict[str, str | None]:
        """An array's known strains (layout as ``on_array``; NaN: no reference for that
        sensor): per sensor given, None when fused or the reason it was refused."""
        sensors = self._inputs[name]
        values = array_values(data, offset, sizes or [], len(sensors), label, sensors)
        return {sensor: self.on_reference(sensor, t, float(value))
                for sensor, value in zip(sensors, values, strict=True) if not np.isnan(value)}

    def reference_now(self, now: float | None = None) -> str:
        """``~/reference``: every sensor is at ``known_strain`` at the clock time ``now``
        [s] (None: each sensor's latest sample's time). The summary; ParameterError when
        ``fuse_references`` is false or a sensor's reference was refused (the others are
        fused; each refusal counted)."""
        if not self.fusion:
            raise ParameterError("fuse_references", "false: set it to true in the params file "
                                 "to fuse known strains")
        strain = self.tunables["known_strain"]
        lines, refused = [], []
        for sensor, fusion in self.fusion.items():
            latest = self._latest(sensor)
            reason = (fusion.refuse("no estimate yet") if latest is None else
                      self.on_reference(sensor, latest[0] if now is None else now, strain))
            if reason is None:
                lines.append(f"{sensor}: gain {fusion.gain:.6g}, offset {fusion.offset:.6g}")
            else:
                refused.append(f"{sensor}: {reason}")
        if refused:
            raise ParameterError("known_strain", f"{strain:g} refused for " + "; ".join(refused)
                                 + ("; fused for " + "; ".join(lines) if lines else ""))
        return f"known strain {strain:g} fused: " + "; ".join(lines)

    def refuse(self, name: str, reason: str) -> None:
        """Count a message that could not be handled, by input and reason (at most
        ``MAX_REFUSAL_KEYS`` distinct keys)."""
        key = f"{name}: {reason[:MAX_REASON_CHARS]}"
        if key not in self.refused and len(self.refused) >= MAX_REFUSAL_KEYS:
            key = f"{name}: other reasons"
        self.refused[key] += 1

    def on_temperature(self, name: str, value: float) -> None:
        """Remember a sensor's latest temperature [deg C] for its effect terms; a reading
        outside ``TEMPERATURE_RANGE`` is refused and counted, the previous one stays."""
        value = float(value)
        if not TEMPERATURE_RANGE[0] <= value <= TEMPERATURE_RANGE[1]:
            self.refuse(f"{name}/temperature", "temperature outside "
                        f"[{TEMPERATURE_RANGE[0]:g}, {TEMPERATURE_RANGE[1]:g}] degC")
            return
        self.temperature[name] = value

    def _seen(self, name: str, t: float, raw: np.ndarray, status: np.ndarray,
              direction: np.ndarray) -> None:
        recent = self._recent[name]
        recent.add(t, raw, status)
        self._last_message[name] = t
        start = self._start.get(name)
        if start is not None:
            firsts = [self._auto[s] for s in self._inputs[name] if s in self._auto]
            if start.add(t, raw, status, keep_from=min((f for f in firsts if not math.isnan(f)),
                                                       default=math.inf)):
                self._auto_tare(name, t, start, status, direction)
            else:
                for sensor in self._inputs[name]:
                    if self._auto.pop(sensor, None) is not None:
                        self.tare_log.append(
                            f"{sensor}: auto tare declined: {MAX_START_SAMPLES} samples within "
                            f"{TARE_WINDOW:g} s of clock time (is the clock paused?); the "
                            "calibration's zero stays (call ~/tare at rest)")
            if not any(s in self._auto for s in self._inputs[name]):
                del self._start[name]

    # --- tare -----------------------------------------------------------------------------

    def _ohm(self, sensor: str, raw: np.ndarray) -> np.ndarray:
        return self.params.calibration.sensors[sensor].input.to_ohm(raw)

    def _auto_tare(self, name: str, t: float, log: _StartLog, status: np.ndarray,
                   direction: np.ndarray) -> None:
        for column, sensor in enumerate(self._inputs[name]):
            start = self._auto.get(sensor)
            if start is None:
                continue
            good = bool(used_mask(status[column]))
            if math.isnan(start):
                if good:
                    self._auto[sensor] = t
                continue
            if t - start < TARE_WINDOW and not (good and direction[column] != 0):
                continue
            times, raw = log.since(start, column)
            cal = self.params.calibration.sensors[sensor]
            ohm = self._ohm(sensor, raw)
            try:
                if t - start >= TARE_WINDOW:  # decided
                    rest = rest_resistance_at_start(times, ohm, cal.direction,
                                                    pair=cal.input.pair)
                else:  # the engine's detector moved; the rule's (on pairs) may not have yet
                    found = rest_resistance_when_decided(times, ohm, cal.direction,
                                                         pair=cal.input.pair)
                    if found is None:
                        continue
                    rest = found
            except InputError as err:
                del self._auto[sensor]
                self.tare_log.append(f"{sensor}: auto tare declined: {err}; the calibration's "
                                     "zero stays (call ~/tare at rest)")
                continue
            gain = self.engine.tare(sensor, rest)
            del self._auto[sensor]
            self.tare_log.append(f"{sensor}: auto tare: rest resistance {rest:.6g} ohm, "
                                 f"input gain {gain:.6g}")

    def tare(self) -> str:
        """Make each sensor's current rest resistance its zero (all or none); the summary.

        ParameterError naming every sensor that cannot be tared (no rest resistance in its
        calibration, no good sample in the last ``TARE_WINDOW_S``); the gains then stay.
        """
        rests: dict[str, float] = {}
        problems = []
        for name, sensors in self._inputs.items():
            recent = self._recent[name]
            latest = recent.t[(recent.n - 1) % RING] if recent.n else -math.inf
            for column, sensor in enumerate(sensors):
                values = self._ohm(sensor, recent.since(latest - TARE_WINDOW_S, column)[1])
                cal = self.params.calibration.sensors[sensor]
                if cal.rest_resistance is None:
                    problems.append(f"{sensor}: the calibration stores no rest_resistance")
                elif values.size == 0:
                    problems.append(f"{sensor}: no good sample in the last {TARE_WINDOW_S} s")
                else:
                    rests[sensor] = rest_level(values, pair=cal.input.pair)
        if problems:
            raise ParameterError("tare", "refused: " + "; ".join(problems))
        for sensor, rest in rests.items():
            self.engine.tare(sensor, rest)
            self._auto.pop(sensor, None)
        self._start.clear()  # no automatic tare is pending any more
        return "tared " + ", ".join(f"{s} (rest {r:.6g} ohm, gain {self.engine.input_gain(s):.6g})"
                                    for s, r in rests.items())

    def span(self) -> tuple[LiveCompensator, str]:
        """``~/span``: every sensor is held at the known strain ``span_strain`` now; its
        input zero and span (``recalibrate --input``, ``InputSettings.zero_span``) through
        its rest (the zero of its latest tare, else the calibration's) and the median of
        its good samples of the last ``TARE_WINDOW_S``. Returns the compensator on the new
        calibration (state restarts, as after a reload; the rest now reads as the
        calibrated rest) and the summary; ParameterError, nothing changed, otherwise."""
        from strain_comp.offline.recalibrate import span_from_points, span_reading

        strain = self.tunables.get("span_strain", 0.0)
        if not strain > 0:
            raise ParameterError("span_strain", "set it to the known strain the sensors are "
                                 "held at before calling ~/span")
        sensors = dict(self.params.calibration.sensors)
        lines, problems = [], []
        for name, names in self._inputs.items():
            recent = self._recent[name]
            latest = recent.t[(recent.n - 1) % RING] if recent.n else -math.inf
            for column, sensor in enumerate(names):
                cal = sensors[sensor]
                values = self._ohm(sensor, recent.since(latest - TARE_WINDOW_S, column)[1])
                zero = cal.input_rest
                if zero is None or values.size == 0:
                    problems.append(f"{sensor}: " + ("the calibration stores no "
                                    "rest_resistance" if zero is None else
                                    f"no good sample in the last {TARE_WINDOW_S} s"))
                    continue
                points = [(zero / self.engine.input_gain(sensor), fitted_rest(cal.valid_range)[0]),
                          (rest_level(values, pair=cal.input.pair), strain)]
                try:
                    span = span_from_points(cal, points)
                except StrainCompError as err:
                    problems.append(f"{sensor}: {err}")
                    continue
                sensors[sensor] = replace(cal, input=replace(cal.input, zero_span=span))
                lines.append(f"{sensor}: {span_reading(span)}")
        if problems:
            raise ParameterError("span", "refused: " + "; ".join(problems))
        fresh = self.reload(replace(self.params, calibration=Calibration(sensors)))
        return fresh, "spanned " + "; ".join(lines)

    # --- parameters -----------------------------------------------------------------------

    def check_tunable(self, name: str, value: Any) -> float:
        """The validated value; ParameterError if out of range, unknown or read-only."""
        value = validate_tunable(name, value)
        if TUNABLE[name].read_only:
            raise ParameterError(name, "read-only: set it in the params file and restart")
        return value

    def set_tunable(self, name: str, value: Any) -> None:
        """Validate (``check_tunable``) and apply a tunable."""
        self._apply(name, self.check_tunable(name, value))

    def _apply(self, name: str, value: float) -> None:
        self.tunables[name] = value
        if name == "deadzone_scale":
            self.engine.set_deadzone_scale(value)
        elif name == "gap_reset_s":
            self.engine.gap_reset = value
        elif name == "stale_after_s":
            self.engine.stale_after = value

    def reload(self, params: NodeParams) -> LiveCompensator:
        """A new LiveCompensator on ``params``'s calibration carrying on from this one
        (``successor`` then ``hand_over``). StrainCompError if the new one cannot run."""
        return self.hand_over(self.successor(params))

    def successor(self, params: NodeParams) -> LiveCompensator:
        """The slow half of a reload: a LiveCompensator built on ``params``'s calibration
        (engine built and warmed up) with this one's tunables, not yet carrying anything
        over. Reads only this one's inputs and tunables, so the node runs it on a worker
        thread while this one keeps handling messages. StrainCompError if it cannot run."""
        params.tunables = dict(self.tunables)
        fresh = LiveCompensator(params)
        if [i.sensors for i in params.inputs] != [i.sensors for i in self.params.inputs]:
            raise StrainCompError("the reloaded calibration changes the sensors")
        return fresh

    def hand_over(self, fresh: LiveCompensator) -> LiveCompensator:
        """``fresh`` (from ``successor``) carrying on from this one, as of now: its health
        and refusal counters go on from this one's, its tunables are this one's current
        ones, its inputs' last message times are this one's. Model state restarts and the
        input gains return to 1 (a new calibration brings its own zero; ``tare: auto``
        tares again). Quick: the node calls it between two messages."""
        for name, value in self.tunables.items():
            fresh._apply(name, value)
        fresh.refused, fresh._refused_seen = self.refused, self._refused_seen
        fresh._counted_before = self.health()  # the counters go on from here
        fresh._last_message = dict(self._last_message)
        for sensor, fusion in self.fusion.items():  # the estimate restarts, its counts go on
            if sensor in fresh.fusion:
                fresh.fusion[sensor].n_used += fusion.n_used
                fresh.fusion[sensor].refused.update(fusion.refused)
        return fresh

    def health(self, now: float | None = None) -> dict[str, SensorHealth]:
        """The engine's health with the counters of replaced calibrations added."""
        health = self.engine.health(now)
        for sensor, before in self._counted_before.items():
            for name in _COUNTS:
                setattr(health[sensor], name,
                        getattr(health[sensor], name) + getattr(before, name))
        return health

    # --- diagnostics ----------------------------------------------------------------------

    def diagnostics(self, now: float) -> list[tuple[str, int, str, dict[str, str]]]:
        """Statuses at clock time ``now`` [s]: one per sensor, then the transport's.

        A sensor is ERROR with the reason while its latest sample is bad (e.g. "non-finite
        input"), STALE when no message arrived for ``stale_after_s`` (two sample intervals
        of a slow instrument, ``Engine.stale_for``), else as the engine says.
        The transport is WARN while messages were refused since the previous call.
        """
        out = []
        health = self.health(now)
        last_message = {s: self._last_message.get(i.name) for i in self.params.inputs
                        for s in i.sensors}
        for name, level, message, values in diagnostics(health):
            sensor = name.split(": ", 1)[1]
            h = health[sensor]
            last = last_message.get(sensor)
            stale_after = self.engine.stale_for(sensor)
            silent = last is None or now - last > stale_after
            if h.last_status is not None and h.last_status not in USED and not silent:
                level, message = ERROR, f"{BAD_REASON[h.last_status]}: estimate held"
            elif silent and last is not None:
                level, message = STALE, f"no input for more than {stale_after:g} s"
            cal = self.params.calibration.sensors[sensor]
            gain = self.engine.input_gain(sensor)
            values["input_gain"] = repr(gain)
            values["rest_resistance"] = ("none" if cal.rest_resistance is None
                                         else repr(cal.rest_resistance / gain))
            values["model"] = cal.model
            if sensor in self.fusion:
                values.update(self.fusion[sensor].diagnostic_values())
            out.append((name, level, message, values))
        total = sum(self.refused.values())
        recent, self._refused_seen = total - self._refused_seen, total
        reasons = {f"refused[{k}]": str(v) for k, v in sorted(self.refused.items())}
        worst = self.refused.most_common(1)[0][0] if self.refused else ""
        out.append(("strain_comp: transport", WARN if recent else OK,
                    f"{recent} messages refused recently (most: {worst})" if recent else "ok",
                    {"n_refused": str(total), "n_refused_recent": str(recent), **reasons}))
        return out
