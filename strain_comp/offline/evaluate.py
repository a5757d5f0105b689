"""Evaluation: ``Scorer`` runs a calibration through the engine's batch path and keeps running
error sums over the used samples with a finite reference (held ones counted, not scored);
``evaluate_bag`` streams a bag into it, ``evaluate_recordings`` recordings as one piece of a
bag (docs/architecture.md)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.base.samples import Status, used_mask
from strain_comp.core.calibration import Calibration, SensorCalibration, check_reference
from strain_comp.core.engine import Engine
from strain_comp.core.fusion import SparseFusion
from strain_comp.core.metrics import ErrorAccumulator
from strain_comp.core.tare import tare_engine
from strain_comp.errors import InputError
from strain_comp.io.bag import BagContents, iter_bag, located
from strain_comp.io.bag.reader import WINDOW
from strain_comp.io.recording import (
    REFERENCE,
    RESISTANCE,
    PieceAlign,
    Recording,
    as_contents,
    reference_columns,
    temperature_series,
    topic_sensors,
)
from strain_comp.offline.evaluation import EvaluationResult, SensorEvaluation

if TYPE_CHECKING:
    from strain_comp.core.outputs import BatchOutput
    from strain_comp.offline.series import SeriesCSV

PLOT_POINTS = 50_000
"""Most samples per sensor ``evaluate_bag`` keeps for plots (evenly spaced)."""


class _Kept:
    """Every ``stride``-th sample of one sensor, for plots, the stride doubled past ``cap``."""

    def __init__(self, cap: int | None) -> None:
        self.cap = cap
        self.stride = 1
        self.n = 0
        self.index = np.empty(0, np.int64)
        self.columns: dict[str, np.ndarray] = {}

    def add(self, **columns: np.ndarray) -> None:
        size = columns["t"].size
        index = np.arange(self.n, self.n + size)
        self.n += size
        take = index % self.stride == 0
        self.index = np.concatenate((self.index, index[take]))
        for key, column in columns.items():
            new = column[take]
            self.columns[key] = new if key not in self.columns else \
                np.concatenate((self.columns[key], new))
        while self.cap is not None and self.index.size > self.cap:
            self.stride *= 2
            take = self.index % self.stride == 0
            self.index = self.index[take]
            self.columns = {k: v[take] for k, v in self.columns.items()}

    def get(self, key: str) -> np.ndarray:
        return self.columns.get(key, np.empty(0))


class _Score:
    """One sensor's running statistics and cumulative status counts."""

    def __init__(self, plot_points: int | None) -> None:
        self.errors = ErrorAccumulator()
        self.n_samples = 0
        self.n_bad = 0
        self.n_out_of_range = 0
        self.bad: dict[int, int] = {}
        self.kept = _Kept(plot_points) if plot_points != 0 else None

    def add(self, t: np.ndarray, r: np.ndarray, s: np.ndarray, out: BatchOutput) -> None:
        estimate = np.asarray(out.strain, dtype=np.float64)
        status = np.asarray(out.status)
        good = used_mask(status)
        scored = good & np.isfinite(s) & np.isfinite(estimate)
        std = None if out.std is None else np.asarray(out.std, dtype=np.float64)
        self.errors.add(estimate[scored], s[scored], None if std is None else std[scored])
        self.n_samples += int(t.size)
        self.n_bad += int(np.sum(~good))
        self.n_out_of_range += int(np.sum(np.asarray(out.out_of_range)))
        values, counts = np.unique(status[~good], return_counts=True)
        for v, c in zip(values.tolist(), counts.tolist(), strict=True):
            self.bad[int(v)] = self.bad.get(int(v), 0) + int(c)
        if self.kept is not None:
            self.kept.add(t=t, r=r, reference=s, estimate=estimate,
                          direction=np.asarray(out.direction), scored=scored,
                          out_of_range=np.asarray(out.out_of_range, bool),
                          **({} if std is None else {"std": std}))

    def evaluation(self, name: str, cal: SensorCalibration, input_gain: float,
                   fused: SparseFusion | None) -> SensorEvaluation:
        kept = self.kept or _Kept(0)
        return SensorEvaluation(
            name=name, model=cal.model, stats=self.errors.stats(), t=kept.get("t"),
            r=kept.get("r"), reference=kept.get("reference"), estimate=kept.get("estimate"),
            direction=kept.get("direction"), scored=kept.get("scored").astype(bool),
            n_samples=self.n_samples, n_bad=self.n_bad, n_out_of_range=self.n_out_of_range,
            bad_by_status={Status(v).name.lower(): c for v, c in sorted(self.bad.items())},
            unit=cal.strain_unit, errors=self.errors,
            out_of_range=kept.get("out_of_range").astype(bool), input_gain=input_gain,
            input_unit="V" if cal.input.kind == "divider" else cal.input.unit,
            references=None if fused is None else {"every": fused.every,
                                                   **fused.fusion.state()},
            std=kept.get("std") if self.errors.n_banded else np.empty(0),
            coverage_95=self.errors.coverage_95())


def _crosstalk_off_tick(name: str, cal: SensorCalibration, same_tick: set[str]) -> list[str]:
    """The note for cross-talk terms whose neighbour is not on ``name``'s array topic."""
    # offline such a term reads the neighbour's estimate of the previous batch, not the tick's
    off = [f"{e.get('name')} ({e['params'].get('neighbour')})" for e in cal.effects
           if e.get("kind") == "crosstalk" and isinstance(e.get("params"), Mapping)
           and str(e["params"].get("neighbour")) not in same_tick]
    if not off:
        return []
    return [f"{name}: cross-talk term {', '.join(off)} reads a sensor not recorded on its "
            "array topic: offline it sees that sensor's estimate batch by batch, not tick by "
            "tick, and this error is not the calibration's (record the array on one topic)"]


def _temperature_missing(name: str, cal: SensorCalibration) -> list[str]:
    """The note that a temperature term is not applied without temperature (it reads 0)."""
    terms = [str(e.get("name")) for e in cal.effects if e.get("kind") == "temperature"]
    if not terms:
        return []
    return [f"{name}: no temperature in the data: the calibration's temperature term "
            f"{', '.join(terms)} is not applied"]


def nothing_scored(calibration: Calibration, names: list[str]) -> str:
    """The error when no calibrated sensor can be scored, naming both sides."""
    return ("no calibrated sensor has a strain_reference in the data (calibration: "
            f"{', '.join(calibration.sensors)}; data: {', '.join(names) or 'none'})")


@dataclass
class _Input:
    """One resistance topic: its calibrated columns and the samples waiting for alignment."""

    prefix: str
    names: list[str]
    """Calibrated sensors, in column order of ``columns``."""
    columns: list[int]
    single: bool
    group: list[str]
    """Sensors run together by ``Engine.run_array`` (calibration order), else empty."""
    temperature: dict[str, PieceAlign]
    """Per sensor its ``/NAME/temperature``, only when an effect term here could read it."""
    reference: dict[str, PieceAlign]
    ref_columns: dict[str, int | None] | None = None
    """``reference_columns`` once the reference topic is seen, else None."""
    t: np.ndarray = field(default_factory=lambda: np.empty(0))
    r: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))


class Scorer:
    """The one evaluation: a bag fed piece by piece (recordings: ``as_contents``), each input
    tared from its first piece, its samples run and scored once their reference is known."""

    def __init__(self, calibration: Calibration, engine: Engine, tare: str,
                 plot_points: int | None, series: SeriesCSV | None = None, bag: str = "",
                 references_every: float | None = None) -> None:
        self.calibration = calibration
        self.engine = engine
        self.tare = tare
        self.plot_points = plot_points
        self.series = series
        self.bag = bag
        self.references_every = references_every
        self.fused: dict[str, SparseFusion] = {}
        self.scores: dict[str, _Score] = {}
        self.notes: list[str] = []
        self.inputs: dict[str, _Input | None] = {}
        self.names: list[str] = []
        """Every sensor found in the data, in ``load_recordings`` order."""
        self.bag_problems: list[str] = []
        self.problems: list[str] = []
        self.references: set[str] = set()
        self.with_temperature: set[str] = set()
        """Sensors whose input has a temperature sample in a piece read so far."""

    def _problem(self, line: str) -> None:
        if line not in self.problems:
            self.problems.append(line)

    def piece(self, contents: BagContents) -> None:
        """Take a piece's new inputs, queue its samples and score those now aligned."""
        self.bag_problems += contents.problems
        for topic in sorted(contents.series):
            if topic.endswith(REFERENCE):
                self.references.add(topic)
            if topic.endswith(RESISTANCE) and topic not in self.inputs:
                self.inputs[topic] = self._input(topic, contents)
        for topic, inp in self.inputs.items():
            if inp is not None:
                self._add(inp, topic, contents)
                self._run(inp)

    def finish(self) -> EvaluationResult:
        """The rest of every input run and scored; each calibrated sensor's evaluation, or
        the note why it has none."""
        for inp in self.inputs.values():
            if inp is not None:
                for align in [*inp.temperature.values(), *inp.reference.values()]:
                    align.finish()
                self._run(inp)
        for topic in sorted(self.references):
            if topic[:-len(REFERENCE)] + RESISTANCE not in self.inputs:
                self._problem(f"{topic}: reference without a resistance topic; ignored")
        inputs = [inp for inp in self.inputs.values() if inp is not None]
        referenced = {name for inp in inputs for name in inp.ref_columns or {}}
        same_tick = {name: set(inp.names) for inp in inputs if not inp.single
                     for name in inp.names}
        missing = [n for n in self.calibration.sensors if n in self.names and n not in referenced]
        if self.references_every is not None and missing:
            raise InputError(f"--references-every {self.references_every:g}: "
                             f"{', '.join(missing)} has no strain_reference in the data (the "
                             "references fused are the data's own /NAME/strain_reference)")
        sensors: dict[str, SensorEvaluation] = {}
        notes = list(self.notes)
        for name, cal in self.calibration.sensors.items():
            if name not in self.names:
                notes.append(f"{name}: calibrated but not in the data")
            elif name not in referenced:
                notes.append(f"{name}: no strain_reference in the data, not scored")
            else:
                sensors[name] = self.scores[name].evaluation(
                    name, cal, self.engine.input_gain(name), self.fused.get(name))
                if name not in self.with_temperature:
                    notes += _temperature_missing(name, cal)
                notes += _crosstalk_off_tick(name, cal, same_tick.get(name, set()))
        return EvaluationResult(sensors, notes)

    def _input(self, topic: str, contents: BagContents) -> _Input | None:
        """A resistance topic as ``load_recordings`` reads it, tared from its first piece."""
        prefix = topic[:-len(RESISTANCE)]
        series = contents.series[topic]
        single = series.values.ndim == 1
        labels, problem = topic_sensors(topic, contents)
        if problem is not None:
            self._problem(problem)
        names: list[str] = []
        columns: list[int] = []
        for j, name in enumerate(labels):
            if name in self.names:
                self._problem(f"{topic}: sensor {name} appears twice; column {j} skipped")
                continue
            self.names.append(name)
            if name in self.calibration.sensors:
                names.append(name)
                columns.append(j)
        if not names:
            return None
        values = series.values if not single else series.values[:, None]
        tared = tare_engine(self.engine, {n: (series.t, values[:, j])
                                          for n, j in zip(names, columns, strict=True)},
                            self.tare)
        self.notes += [f"{name}: {line}" for name, line in tared.items()]
        for name in names:
            self.scores[name] = _Score(self.plot_points)
            if self.references_every is not None:
                self.fused[name] = SparseFusion.for_calibration(self.calibration.sensors[name],
                                                               self.references_every)
        group = [] if single or len(names) < 2 else \
            [n for n in self.calibration.sensors if n in names]
        effects = any(self.calibration.sensors[n].effects for n in names)
        return _Input(prefix, names, columns, single, group,
                      {n: PieceAlign() for n in names} if effects else {},
                      {n: PieceAlign() for n in names}, r=np.empty((0, len(names))))

    def _add(self, inp: _Input, topic: str, contents: BagContents) -> None:
        """Queue a piece's samples of ``inp`` and feed its alignments."""
        empty = np.empty(0)
        series = contents.series.get(topic)
        t = series.t if series is not None else empty
        if series is not None and t.size:
            values = series.values[:, None] if inp.single else series.values
            inp.t = np.concatenate((inp.t, t))
            inp.r = np.concatenate((inp.r, values[:, inp.columns]))
        for name, align in inp.temperature.items():
            temp = temperature_series(contents, name)
            align.add(t, empty if temp is None else temp.t, empty if temp is None else temp.values)
            if temp is not None and temp.t.size:
                self.with_temperature.add(name)
        ref = contents.series.get(inp.prefix + REFERENCE)
        if ref is not None and inp.ref_columns is None:
            inp.ref_columns, problem = reference_columns(contents, topic)
            if problem is not None:
                self._problem(problem)
        for name, align in inp.reference.items():
            column = (inp.ref_columns or {}).get(name, -1)
            if ref is None or column == -1:
                align.add(t, empty, empty)
            else:
                align.add(t, ref.t, ref.values if column is None else ref.values[:, column])

    def _run(self, inp: _Input) -> None:
        """Compensate and score the queued samples whose reference is known."""
        horizon = min(a.horizon() for a in [*inp.temperature.values(), *inp.reference.values()])
        n = inp.t.size if horizon == math.inf else int(
            np.searchsorted(inp.t, horizon, side="right"))
        if n == 0:
            return
        t, r = inp.t[:n], inp.r[:n]
        inp.t, inp.r = inp.t[n:], inp.r[n:]
        refs = {name: align.take(t) for name, align in inp.reference.items()}
        for name, ref in refs.items():
            check_reference(name, ref, InputError)
        temps = {name: inp.temperature[name].take(t) if inp.temperature else None
                 for name in inp.names}
        column = {name: j for j, name in enumerate(inp.names)}
        if inp.group:
            outs = self.engine.run_array(inp.group, t, r[:, [column[g] for g in inp.group]],
                                         {g: temps[g] for g in inp.group})
        else:
            outs = {name: self.engine.run(name, t, r[:, j], temps[name])
                    for name, j in column.items()}
        for name, fused in self.fused.items():
            if name in outs:
                outs[name] = fused.fuse(t, outs[name], refs[name])
        for name, j in column.items():
            self.scores[name].add(t, r[:, j], refs[name], outs[name])
            if self.series is not None:
                cal, out = self.calibration.sensors[name], outs[name]
                self.series.add(name, t, cal.input.to_ohm(r[:, j]), out.strain, refs[name],
                                out.direction, out.status, unit=cal.strain_unit, bag=self.bag)


def evaluate_recordings(recordings: Mapping[str, Recording], calibration: Calibration, *,
                        tare: str = "calibration", out_of_range: str = "extend",
                        references_every: float | None = None) -> EvaluationResult:
    """Score every calibrated sensor that has a recording with a reference strain, as from
    a bag that holds them (``as_contents``)."""
    scorer = Scorer(calibration, Engine(calibration, out_of_range=out_of_range), tare, None,
                    references_every=references_every)
    scorer.piece(as_contents(recordings))
    result = scorer.finish()
    if not result.sensors:
        raise InputError(nothing_scored(calibration, list(recordings)))
    return result


def evaluate_bag(path: str | os.PathLike[str], calibration: Calibration, *,
                 tare: str = "calibration", window: int = WINDOW,
                 plot_points: int = 0, series: SeriesCSV | None = None,
                 out_of_range: str = "extend",
                 references_every: float | None = None,
                 ) -> tuple[EvaluationResult, list[str]]:
    """``evaluate_recordings`` of the bag at ``path``, streamed in pieces (``iter_bag``)."""
    stream = Scorer(calibration, Engine(calibration, out_of_range=out_of_range),
                    tare, plot_points, series, str(path), references_every)
    for contents in iter_bag(path, window=window):
        stream.piece(contents)
    result = stream.finish()
    problems = stream.bag_problems + located(path, stream.problems)
    if not result.sensors:
        raise InputError("; ".join([f"{path}: {nothing_scored(calibration, stream.names)}",
                                    *problems]))
    return result, problems
