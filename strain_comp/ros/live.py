"""What the live node does with each message, free of any transport (docs/ros.md;
docs/architecture.md, "Inside the node")."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np

from strain_comp.base.samples import USED, Status, used_mask
from strain_comp.core.calibration import Calibration
from strain_comp.core.effects import TEMPERATURE_RANGE
from strain_comp.core.fusion import OutputFusion
from strain_comp.core.health import COUNTERS, SensorHealth, diagnostics
from strain_comp.core.outputs import ArrayOutput, concatenate
from strain_comp.core.range_policy import fitted_rest
from strain_comp.errors import ParameterError, StrainCompError
from strain_comp.ros.live_start import LiveStart
from strain_comp.ros.live_tare import LiveTare
from strain_comp.ros.params import NodeParams

BAD_REASON = {Status.NOT_FINITE: "non-finite input", Status.NON_POSITIVE: "non-positive input",
              Status.TIME_NOT_INCREASING: "time not increasing",
              Status.OPEN_CIRCUIT: "open circuit", Status.SHORT_CIRCUIT: "short circuit"}
ERROR, STALE, WARN, OK = 2, 3, 1, 0
MAX_REFUSAL_KEYS = 32
"""Distinct refusal reasons counted (``NAME: reason``), each a /diagnostics value; further
reasons count under ``NAME: other reasons`` (a peer varying a message cannot grow them)."""
MAX_REASON_CHARS = 160
"""A refusal reason longer than this is cut in its counter's key."""
NON_FINITE = "the calibration gave a non-finite strain; not published"
"""The refusal of a good sample whose strain is not finite (a good sample is never NaN)."""


def _count(counter: Counter[str], key: str, other: str) -> None:
    """Count ``key``, or ``other`` once ``MAX_REFUSAL_KEYS`` distinct keys are counted."""
    counter[key if key in counter or len(counter) < MAX_REFUSAL_KEYS else other] += 1


class LiveCompensator:
    """One engine plus the per-input bookkeeping of a live node."""

    def __init__(self, params: NodeParams) -> None:
        """Build the engine of ``params`` and compile its kernels."""
        self.params = params
        self.tunables = dict(params.tunables)
        self.engine = params.build_engine()
        self.engine.warm_up()
        if params.tare == "auto":
            missing = [n for n, c in params.calibration.sensors.items()
                       if c.rest_resistance is None]
            if missing:
                raise ParameterError("tare", f"auto needs 'rest_resistance' in the calibration "
                                     f"of {', '.join(missing)}")
        self._last_publish: dict[str, float] = {}
        self.temperature: dict[str, np.ndarray] = {}
        """Per input that had one, its sensors' latest temperatures [deg C] (NaN: none yet)."""
        self._inputs = {i.name: i.sensors for i in params.inputs}
        self.taring = LiveTare(self.engine, params)
        self._last_message: dict[str, float] = {}
        self.refused: Counter[str] = Counter()
        self._refused_seen = 0
        self.faults: Counter[str] = Counter()
        self._faults_seen = 0
        self._counted_before: dict[str, SensorHealth] = {}
        """Health counters of the calibrations this one replaced (``hand_over``)."""
        self.fusion: dict[str, OutputFusion] = (
            {s: OutputFusion.for_calibration(c) for s, c in params.calibration.sensors.items()}
            if params.fuse_references else {})
        """Per sensor, its fused output gain and offset (``fuse_references: on``)."""
        self._estimate: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        """Per input, its sensors' latest used estimates before fusion: time, strain, inside."""
        self._column = {s: (i.name, j) for i in params.inputs for j, s in enumerate(i.sensors)}
        """Per sensor: (its input, its column)."""
        self._maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        """Per input, its sensors' fused gains and offsets (``_fused``)."""
        self.starting = LiveStart()

    # --- messages -------------------------------------------------------------------------

    def _due(self, name: str, t: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """Of the ``candidates`` at times ``t``, those published (one per 1/rate s)."""
        rate = self.tunables["publish_rate_limit_hz"]
        due: np.ndarray = np.array(candidates, dtype=bool)
        if rate <= 0.0:
            if due.any():
                self._last_publish[name] = float(t[np.flatnonzero(due)[-1]])
            return due
        for i in np.flatnonzero(due):
            last = self._last_publish.get(name)
            if last is not None and 0.0 <= t[i] - last < 1.0 / rate:
                due[i] = False
            else:
                self._last_publish[name] = float(t[i])
        return due

    def on_input(self, name: str, t: np.ndarray, values: np.ndarray
                 ) -> tuple[ArrayOutput, np.ndarray, np.ndarray]:
        """Samples of input ``name`` (rows): (the outputs; published; refused: non-finite)."""
        if t.size > 1 and self.taring.pending_on(name):
            # an automatic tare watches the input: a sample changes the next one
            parts = [self.on_input(name, t[i:i + 1], values[i:i + 1]) for i in range(t.size)]
            return (concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                    np.concatenate([p[2] for p in parts]))
        held = self.temperature.get(name)
        temps = None if held is None else np.tile(held, (t.size, 1))
        if name in self.engine.arrays:
            out = self.engine.run_ticks(name, t, values, temps)
        else:
            one = self.engine.run(name, t, values[:, 0], None if temps is None else temps[:, 0])
            out = ArrayOutput(one.strain[:, None], one.direction[:, None], one.status[:, None],
                              one.out_of_range[:, None],
                              None if one.std is None else one.std[:, None])
        self.starting.seen_inputs(self._inputs[name], t, values)
        self.taring.seen(name, t, values, out.status, out.direction)
        self._last_message[name] = float(t[-1])
        refused = (used_mask(out.status) & ~np.isfinite(out.strain)).any(axis=1)
        if self.fusion:
            out = self._fused(name, t, out, refused)
        return out, self._due(name, t, np.isfinite(out.strain).all(axis=1) & ~refused), refused

    def _fused(self, name: str, t: np.ndarray, out: ArrayOutput, refused: np.ndarray
               ) -> ArrayOutput:
        """``out`` fused; the used samples' estimates kept for the references."""
        k = out.strain.shape[1]
        times, strains, inside = self._estimate.setdefault(
            name, (np.full(k, np.nan), np.full(k, np.nan), np.zeros(k, bool)))
        for i in np.flatnonzero(~refused):
            used = used_mask(out.status[i])
            times[used] = t[i]
            strains[used] = out.strain[i][used]
            inside[used] = out.status[i][used] != int(Status.OUT_OF_RANGE)
        if name not in self._maps:
            maps = [self.fusion[s].relative() for s in self._inputs[name]]
            self._maps[name] = (np.array([m[0] for m in maps]), np.array([m[1] for m in maps]))
        gain, offset = self._maps[name]
        return replace(out, strain=gain * out.strain + offset)

    # --- known strains --------------------------------------------------------------------

    def on_reference(self, sensor: str, t: float, value: Any) -> str | None:
        """A known strain of a fused ``sensor``: None when fused, else the reason (counted)."""
        fusion = self.fusion[sensor]
        name, column = self._column[sensor]
        vectors = self._estimate.get(name)
        if vectors is None or np.isnan(vectors[0][column]):
            return fusion.refuse("no estimate yet")
        latest, strain, inside = (v[column] for v in vectors)
        if not inside:
            return fusion.refuse("estimate out of the calibrated range")
        if not t - latest <= self.engine.stale_for(sensor):
            return fusion.refuse("no recent estimate")
        reason = fusion.update(t, float(strain), value)
        if reason is None:
            self._maps.pop(name, None)
        return reason

    def reference_now(self, now: float) -> str:
        """``~/reference`` at clock time ``now``."""
        if not self.fusion:
            raise ParameterError("fuse_references", "false: set it to true in the params file "
                                 "to fuse known strains")
        strain = self.tunables["known_strain"]
        lines, refused = [], []
        for sensor, fusion in self.fusion.items():
            reason = self.on_reference(sensor, now, strain)
            if reason is None:
                lines.append(f"{sensor}: gain {fusion.gain:.6g}, offset {fusion.offset:.6g}")
            else:
                refused.append(f"{sensor}: {reason}")
        if refused:
            raise ParameterError("known_strain", f"{strain:g} refused for " + "; ".join(refused)
                                 + ("; fused for " + "; ".join(lines) if lines else ""))
        return f"known strain {strain:g} fused: " + "; ".join(lines)

    def refuse(self, name: str, reason: str) -> None:
        """Count a refused message by input and reason."""
        _count(self.refused, f"{name}: {reason[:MAX_REASON_CHARS]}", f"{name}: other reasons")

    def fault(self, name: str, error: BaseException) -> None:
        """Count a program error by input and exception type."""
        _count(self.faults, f"{name}: {type(error).__name__}", f"{name}: other errors")

    def on_temperature(self, name: str, value: float) -> None:
        """A sensor's latest temperature [deg C]; one outside ``TEMPERATURE_RANGE`` refused."""
        value = float(value)
        if not TEMPERATURE_RANGE[0] <= value <= TEMPERATURE_RANGE[1]:
            self.refuse(f"{name}/temperature", "temperature outside "
                        f"[{TEMPERATURE_RANGE[0]:g}, {TEMPERATURE_RANGE[1]:g}] degC")
            return
        inp, column = self._column[name]
        held = self.temperature.setdefault(inp, np.full(len(self._inputs[inp]), math.nan))
        held[column] = value

    # --- tare -----------------------------------------------------------------------------

    def span(self) -> tuple[LiveCompensator, str]:
        """``~/span`` (docs/ros.md): the compensator on the spanned calibration, the summary."""
        from strain_comp.offline.session_start import apply_span, span_from_points, span_reading

        strain = self.tunables.get("span_strain", 0.0)
        if not strain > 0:
            raise ParameterError("span_strain", "set it to the known strain the sensors are "
                                 "held at before calling ~/span")
        sensors = dict(self.params.calibration.sensors)
        lines: list[str] = []
        problems: list[str] = []
        for sensor, (rest, zero) in self.taring.rests_now(problems).items():
            cal = sensors[sensor]
            points = [(zero / self.engine.input_gain(sensor), fitted_rest(cal.valid_range)[0]),
                      (rest, strain)]
            try:
                span = span_from_points(cal, points)
                sensors[sensor] = apply_span(cal, span, {"span_strain": strain})
            except StrainCompError as err:
                problems.append(f"{sensor}: {err}")
                continue
            lines.append(f"{sensor}: {span_reading(span)}")
        if problems:
            raise ParameterError("span", "refused: " + "; ".join(problems))
        fresh = self.hand_over(self.successor(
            replace(self.params, calibration=Calibration(sensors))))
        return fresh, "spanned " + "; ".join(lines)

    # --- parameters -----------------------------------------------------------------------

    def set_tunable(self, name: str, value: float) -> None:
        """Apply a tunable's value (checked by its descriptor, or by ``parse_values``)."""
        self.tunables[name] = value
        if name == "deadzone_scale":
            self.engine.set_deadzone_scale(value)
        elif name == "gap_reset_s":
            self.engine.gap_reset = value
        elif name == "stale_after_s":
            self.engine.stale_after = value

    def start(self, now: float) -> tuple[LiveCompensator, str]:
        """``~/start`` at clock time ``now`` (``live_start``; no reference: ``span``)."""
        if self.starting.request(now, list(self.params.calibration.sensors)):
            return self, self.starting.detail
        try:
            fresh, summary = self.span()
        except ParameterError as err:
            self.starting.outcome("refused", f"refused: no reference and {err}")
            raise
        fresh.starting.outcome("applied", f"applied span_strain (no reference): {summary}")
        return fresh, fresh.starting.detail

    def start_reference(self, sensor: str, t: float, value: float) -> LiveCompensator:
        """A reference for ``~/start``: the compensator on the started calibration, or this one."""
        started = self.starting.seen_reference(sensor, t, value, self.params.calibration)
        if started is None:
            return self
        return self.hand_over(self.successor(replace(self.params, calibration=started)))

    def successor(self, params: NodeParams) -> LiveCompensator:
        """A reload's slow half, built on a worker thread: reads only inputs and tunables."""
        params.tunables = dict(self.tunables)
        return LiveCompensator(params)

    def hand_over(self, fresh: LiveCompensator) -> LiveCompensator:
        """``fresh`` with this one's counters, tunables and message times (not its zero)."""
        for name, value in self.tunables.items():
            fresh.set_tunable(name, value)
        fresh.refused, fresh._refused_seen = self.refused, self._refused_seen
        fresh.faults, fresh._faults_seen = self.faults, self._faults_seen
        fresh._counted_before = self.health()  # the counters go on from here
        fresh._last_message = dict(self._last_message)
        fresh.starting = self.starting
        for sensor, fusion in self.fusion.items():  # the estimate restarts, its counts go on
            if sensor in fresh.fusion:
                fresh.fusion[sensor].n_used += fusion.n_used
                fresh.fusion[sensor].refused.update(fusion.refused)
        return fresh

    def health(self, now: float | None = None) -> dict[str, SensorHealth]:
        """The engine's health with the counters of replaced calibrations added."""
        health = self.engine.health(now)
        for sensor, before in self._counted_before.items():
            for name in COUNTERS:
                setattr(health[sensor], name,
                        getattr(health[sensor], name) + getattr(before, name))
        return health

    # --- diagnostics ----------------------------------------------------------------------

    def diagnostics(self, now: float) -> list[tuple[str, int, str, dict[str, str]]]:
        """Statuses at clock time ``now`` [s]: per sensor, program errors, start, transport."""
        out = []
        health = self.health(now)
        for name, level, message, values in diagnostics(health):
            sensor = name.split(": ", 1)[1]
            h = health[sensor]
            last = self._last_message.get(self._column[sensor][0])
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
        errors = sum(self.faults.values())
        raised, self._faults_seen = errors - self._faults_seen, errors
        out.append(("strain_comp: program errors", ERROR if raised else OK,
                    f"{raised} program errors recently, a bug: the log has the traceback"
                    if raised else "ok",
                    {"n_errors": str(errors), "n_errors_recent": str(raised),
                     **{f"error[{k}]": str(v) for k, v in sorted(self.faults.items())}}))
        start = self.starting
        out.append(("strain_comp: session start", WARN if start.state == "refused" else OK,
                    f"{start.state}: {start.detail}", {"state": start.state}))
        total = sum(self.refused.values())
        recent, self._refused_seen = total - self._refused_seen, total
        reasons = {f"refused[{k}]": str(v) for k, v in sorted(self.refused.items())}
        worst = self.refused.most_common(1)[0][0] if self.refused else ""
        out.append(("strain_comp: transport", WARN if recent else OK,
                    f"{recent} messages refused recently (most: {worst})" if recent else "ok",
                    {"n_refused": str(total), "n_refused_recent": str(recent), **reasons}))
        return out


class ClockGate:
    """Under sim time, an input whose clock reading equals its previous one waits for a tick."""

    def __init__(self) -> None:
        self.last: dict[str, int] = {}
        self.held: dict[str, Any] = {}

    def arrive(self, name: str, now_ns: int, item: Any) -> list[tuple[str, int, Any]]:
        """(name, stamp, item) triples to process now, in order."""
        out = []
        if name in self.held:
            out.append((name, now_ns, self.held.pop(name)))
        elif self.last.get(name) == now_ns:
            self.held[name] = item
            return out
        self.last[name] = now_ns
        out.append((name, now_ns, item))
        return out

    def tick(self, now_ns: int) -> list[tuple[str, int, Any]]:
        """The clock moved to ``now_ns``: the held inputs to process now, stamped with it."""
        out = [(name, now_ns, item) for name, item in self.held.items()]
        for name in self.held:
            self.last[name] = now_ns
        self.held.clear()
        return out
