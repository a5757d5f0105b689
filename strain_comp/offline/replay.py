"""Offline replay: a bag's resistance through the engine's batch path into a new bag.

Inputs: ``/NAME/resistance`` (Float64) for every calibrated sensor NAME, and array topics
``/ARRAY/resistance`` (Float64MultiArray) whose labels are all calibrated sensors;
``/NAME/temperature`` when present (the latest value at or before each sample, as a live
node would hold it). The message time is the log time, as the node's clock is online.
An array topic goes through ``Engine.run_array``, so its cross-talk effect terms read the
neighbours' estimates of the same tick, exactly as ``Engine.step_array`` (the node) does.

Outputs, one message at every input message's time (bad samples included, marked):
``/NAME/strain`` (Float64, held estimate on bad samples), ``/NAME/direction`` (Int8),
``/NAME/status`` (Int8, ``strain_comp.core.engine.Status``); for arrays the same three as
Float64MultiArray on ``/ARRAY/strain``, ``/ARRAY/direction``, ``/ARRAY/status``;
``/diagnostics`` at the end of every ``diagnostics_period`` of log time that holds input.
Every input topic that can be written back (Float64, Int8, Float64MultiArray, Temperature,
DiagnosticArray) is copied through; anything else is listed in the summary's problems.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import GAP_RESET, BatchOutput, Engine, SensorHealth, diagnostics
from strain_comp.core.tare import tare_engine
from strain_comp.errors import BagError
from strain_comp.io.bag import BagContents, BagWriter, located, read_bag
from strain_comp.io.recording import array_sensor_names, hold_latest

OUTPUTS = ("strain", "direction", "status")


@dataclass
class ReplaySummary:
    """What ``replay_bag`` did: sensors and arrays replayed, health, messages, problems."""

    out_path: Path
    sensors: dict[str, SensorHealth]
    arrays: dict[str, list[str]]
    n_input_messages: int
    n_output_messages: int
    problems: list[str] = field(default_factory=list)


@dataclass
class _Input:
    topic: str
    name: str
    sensors: list[str]
    t: np.ndarray
    values: np.ndarray  # (n, k)
    is_array: bool


def _inputs(contents: BagContents, calibration: Calibration) -> list[_Input]:
    found: list[_Input] = []
    covered: set[str] = set()
    for topic, series in contents.series.items():
        if not topic.endswith("/resistance"):
            continue
        name = topic[1:].rsplit("/", 1)[0]
        if series.values.ndim == 1 and name in calibration.sensors:
            found.append(_Input(topic, name, [name], series.t, series.values[:, None], False))
            covered.add(name)
        elif series.values.ndim == 2:
            labels, _ = array_sensor_names(topic, contents.labels.get(topic) or [],
                                           series.values.shape[1])
            if all(label in calibration.sensors for label in labels):
                found.append(_Input(topic, name, labels, series.t, series.values, True))
                covered.update(labels)
    if not found:
        raise BagError(f"no /NAME/resistance topic for any calibrated sensor "
                       f"({', '.join(calibration.sensors)})")
    return found


def _temperature(contents: BagContents, name: str, t: np.ndarray) -> np.ndarray | None:
    series = contents.series.get(f"/{name}/temperature")
    if series is None or series.t.size == 0:
        return None
    return hold_latest(t, series.t, series.values)


def replay_bag(in_path: str | os.PathLike[str], calibration: Calibration,
               out_path: str | os.PathLike[str], *, diagnostics_period: float = 1.0,
               gap_reset: float = GAP_RESET, stale_after: float = 1.0,
               tare: str = "calibration") -> ReplaySummary:
    """Replay ``in_path`` through ``calibration`` into a new MCAP bag at ``out_path``.

    ``tare``: ``calibration`` or ``auto`` (``strain_comp.core.tare.tare_engine`` on each
    input's first seconds before the replay; its readings go to the problems list).
    """
    contents = read_bag(in_path)
    inputs = _inputs(contents, calibration)
    engine = Engine(calibration, gap_reset=gap_reset, stale_after=stale_after)
    tared = tare_engine(engine, {s: (i.t, i.values[:, j]) for i in inputs
                                 for j, s in enumerate(i.sensors)}, tare)
    t_all = np.concatenate([i.t for i in inputs])
    # a diagnostics tick at the end of every period that holds messages (bounded by them)
    t0 = t_all.min() if t_all.size else 0.0
    ticks = t0 + diagnostics_period * (np.unique(np.floor((t_all - t0) / diagnostics_period))
                                       + 1.0)
    temperature = {s: _temperature(contents, s, i.t) for i in inputs for s in i.sensors}
    results: dict[str, list[BatchOutput]] = {}
    statuses = []
    # run in pieces between diagnostics ticks, so health at a tick sees what came before it
    cuts = {i.topic: np.searchsorted(np.maximum.accumulate(i.t), ticks, side="right")
            for i in inputs}
    for k in range(ticks.size + 1):
        for inp in inputs:
            a = 0 if k == 0 else cuts[inp.topic][k - 1]
            b = cuts[inp.topic][k] if k < ticks.size else inp.t.size
            temps = {s: None if temperature[s] is None else temperature[s][a:b]
                     for s in inp.sensors}
            if inp.is_array:  # cross-talk terms read the same tick's neighbours, as online
                outs = engine.run_array(inp.sensors, inp.t[a:b], inp.values[a:b], temps)
            else:
                outs = {inp.name: engine.run(inp.name, inp.t[a:b], inp.values[a:b, 0],
                                             temps[inp.name])}
            for sensor in inp.sensors:
                results.setdefault(sensor, []).append(outs[sensor])
        if k < ticks.size:
            statuses.append(diagnostics(engine.health(now=float(ticks[k]))))
    out_path = Path(out_path)
    problems = list(contents.problems) + [f"{s}: {line}" for s, line in tared.items()]
    replayed = {s for i in inputs for s in i.sensors}
    problems += [f"calibrated sensor {s!r} has no input topic in the bag: not replayed "
                 "(STALE in /diagnostics)" for s in calibration.sensors if s not in replayed]
    n_out = 0
    written: set[str] = {"/diagnostics"}
    with BagWriter(out_path) as writer:
        for inp in inputs:
            full = {s: _concat(results[s]) for s in inp.sensors}
            for what in OUTPUTS:
                if inp.is_array:
                    topic = f"/{inp.name}/{what}"
                    values = np.stack([getattr(full[s], what) for s in inp.sensors], axis=1)
                    writer.write_float64_array(topic, inp.t, values.astype(np.float64),
                                               inp.sensors)
                    written.add(topic)
                    n_out += inp.t.size
                    continue
                topic = f"/{inp.name}/{what}"
                values = getattr(full[inp.name], what)
                if what == "strain":
                    writer.write_float64(topic, inp.t, values)
                else:
                    writer.write_int8(topic, inp.t, values)
                written.add(topic)
                n_out += inp.t.size
        if ticks.size:
            writer.write_diagnostics(ticks, statuses)
            n_out += ticks.size
        n_in = _copy_through(contents, writer, written, problems)
    return ReplaySummary(out_path, engine.health(), {i.name: i.sensors for i in inputs
                                                    if i.is_array},
                         n_in, n_out + n_in, located(in_path, problems))


def _concat(parts: list[BatchOutput]) -> BatchOutput:
    return BatchOutput(*(np.concatenate([getattr(p, f) for p in parts])
                         for f in ("strain", "direction", "status", "out_of_range")))


def _copy_through(contents: BagContents, writer: BagWriter, written: set[str],
                  problems: list[str]) -> int:
    """Write the input topics into the output bag; the number of messages copied."""
    n = 0
    for topic, kind in contents.types.items():
        if topic in written and topic != "/diagnostics":
            problems.append(f"{topic}: an input topic with an output's name; not copied")
            continue
        series = contents.series.get(topic)
        if kind == "diagnostic_msgs/msg/DiagnosticArray":
            if contents.diagnostics:
                writer.write_diagnostics([d[0] for d in contents.diagnostics],
                                         [d[1] for d in contents.diagnostics], topic=topic)
                n += len(contents.diagnostics)
        elif series is None:
            problems.append(f"{topic}: type {kind} is not copied to the output")
        elif kind == "std_msgs/msg/Float64":
            writer.write_float64(topic, series.t, series.values)
        elif kind == "std_msgs/msg/Int8":
            writer.write_int8(topic, series.t, series.values)
        elif kind == "std_msgs/msg/Float64MultiArray":
            writer.write_float64_array(topic, series.t, series.values,
                                       contents.labels.get(topic) or
                                       [str(i) for i in range(series.values.shape[1])])
        elif kind == "sensor_msgs/msg/Temperature":
            writer.write_temperature(topic, series.t, series.values)
        else:
            problems.append(f"{topic}: type {kind} is not copied to the output")
            continue
        if series is not None:
            n += series.t.size
    return n
