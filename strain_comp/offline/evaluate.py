"""Evaluation: run a calibration over recordings with a reference strain and score it.

Every calibrated sensor that has a recording with ``strain_reference`` is run through the
engine's batch path (``strain_comp.core.engine.Engine.run``, or ``Engine.run_array`` for the
sensors of one array, so cross-talk terms see the same tick's neighbours), the very code
that ``replay`` and the node use, so the numbers here are the numbers a robot would see.
Errors (% strain, ``strain_comp.core.metrics.error_stats``: RMSE per [Electrolycra] eq. (5),
MAE, max |e|, R^2) are taken over the samples the engine *used* (status good, gap reset or
out of range) whose reference is finite; over bad samples (not finite, R <= 0, open or
short circuit, time not increasing) the engine holds its estimate, and those are counted,
not scored.
Out-of-range samples are scored like any other and counted: the flag warns, it does not
hide the error. The engine clamps estimates to the valid strain range plus a margin.

``evaluate_bag`` (the ``evaluate`` command) does the same on a bag read piece by piece
(``strain_comp.io.bag.iter_bag``), in memory bounded independently of the bag's length: the
engine carries its state from piece to piece exactly, the reference and temperature are
aligned across pieces (``strain_comp.io.recording.PieceAlign``), the statistics are running
sums (``strain_comp.core.metrics.ErrorAccumulator``) and the status counts cumulative. Its
numbers are ``evaluate_recordings``'s on the whole recordings (equal to rounding; a bag of
one piece gives the same bits). What waits between pieces is the samples after the latest
reference (or temperature) sample read so far: bounded when the reference runs with the
resistance, the whole tail when a reference stops before the bag ends. Arrays for plots are
kept only when asked for, decimated to at most ``PLOT_POINTS`` evenly spaced samples per
sensor (the statistics use every sample). ``in_run_bound`` fits a model to the whole run:
it needs the recordings loaded whole (``load_recordings``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import Calibration, SensorCalibration, strain_unit_words
from strain_comp.core.engine import Engine
from strain_comp.core.fusion import SparseFusion, check_every, fusion_note
from strain_comp.core.metrics import ErrorAccumulator, ErrorStats, error_stats
from strain_comp.core.samples import Status, used_mask
from strain_comp.core.tare import tare_engine
from strain_comp.core.tracking import DEFAULT_TRACKING, tracker_for
from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.bag import BagContents, iter_bag, located
from strain_comp.io.bag.reader import WINDOW
from strain_comp.io.recording import (
    REFERENCE,
    RESISTANCE,
    TEMPERATURE,
    PieceAlign,
    Recording,
    array_sensor_names,
)
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.options import model_options

if TYPE_CHECKING:
    from strain_comp.core.outputs import BatchOutput
    from strain_comp.core.tracking import BaselineTracker
    from strain_comp.offline.series import SeriesCSV

PLOT_POINTS = 50_000
"""Most samples per sensor ``evaluate_bag`` keeps for plots (evenly spaced)."""


@dataclass
class SensorEvaluation:
    """One sensor's run: the arrays (for plots) and its error statistics."""

    name: str
    model: str
    stats: ErrorStats
    t: np.ndarray
    r: np.ndarray
    reference: np.ndarray
    estimate: np.ndarray
    direction: np.ndarray
    scored: np.ndarray
    """Boolean mask of the samples the statistics were taken over."""
    n_samples: int
    n_bad: int
    n_out_of_range: int
    bad_by_status: dict[str, int] = field(default_factory=dict)
    in_run_rmse: float | None = None
    """RMSE of the same model fitted on this run itself (``in_run_bound``), if asked."""
    unit: str = "%"
    """The unit of the strain and of the errors: the calibration's ``strain_unit``."""
    out_of_range: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    """Boolean mask (same samples as ``t``): outside the calibration's valid range."""
    input_unit: str = "ohm"
    """The unit of ``r``: ohm, or V for a voltage divider's input."""
    input_gain: float = 1.0
    """The tare's gain: the model saw ``r`` (in ohm) times this."""
    errors: ErrorAccumulator | None = field(default=None, repr=False, compare=False)
    """The running sums behind ``stats`` (streamed evaluation), to pool several bags."""
    tracking: dict[str, float] | None = None
    """What baseline tracking did (``_tracked``), when it ran."""
    references: dict[str, Any] | None = None
    """What the fused references did (``OutputFusion.state`` and ``every``), when fused."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON record: the docs/design.md keys first, then extra keys."""
        record: dict[str, Any] = {k: _json_number(v) for k, v in self.stats.to_dict().items()}
        record.update(model=self.model, n_samples=self.n_samples, n_bad=self.n_bad,
                      n_out_of_range=self.n_out_of_range, bad_by_status=self.bad_by_status,
                      unit=self.unit)
        if self.in_run_rmse is not None:
            record["in_run_rmse"] = _json_number(self.in_run_rmse)
        if self.tracking is not None:
            record["baseline_tracking"] = {k: _json_number(v) for k, v in self.tracking.items()}
        if self.references is not None:
            record["references"] = {k: v if isinstance(v, dict) else _json_number(v)
                                    for k, v in self.references.items()}
        return record


@dataclass
class EvaluationResult:
    """Per-sensor evaluations plus notes (calibrated sensors the data could not score)."""

    sensors: dict[str, SensorEvaluation]
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """``{"sensors": {NAME: {"rmse", "mae", "max_abs", "r2", "n", ...}}}`` (docs/design.md)."""
        return {"sensors": {name: ev.to_dict() for name, ev in self.sensors.items()}}


def _json_number(value: float | int) -> float | int | None:
    """NaN/inf are not JSON: write them as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def evaluate_recordings(recordings: Mapping[str, Recording], calibration: Calibration, *,
                        tare: str = "calibration", out_of_range: str = "extend",
                        tracking: str = DEFAULT_TRACKING,
                        references_every: float | None = None) -> EvaluationResult:
    """Score every calibrated sensor that has a recording with a reference strain.

    ``tare``: ``calibration`` or ``auto`` (``strain_comp.core.tare.tare_engine``; what each
    tare read goes to the notes). ``out_of_range``: the engine's ``OUT_OF_RANGE_MODES``.
    ``tracking``: ``on`` runs each sensor not in an array through a
    ``strain_comp.core.tracking.BaselineTracker``. ``references_every``: the recording's
    own reference every that many seconds fused into the output gain and offset
    (``strain_comp.core.fusion.SparseFusion``: causal, scored on every sample as before);
    InputError when a calibrated sensor in the data has no reference.
    Raises InputError when no calibrated sensor can be scored (names both sides).
    """
    if references_every is not None:
        check_every(references_every)
        _references_needed(calibration, {n: r.s is not None for n, r in recordings.items()},
                           references_every)
    engine = Engine(calibration, out_of_range=out_of_range)
    tared = tare_engine(engine, {n: (rec.t, rec.r) for n, rec in recordings.items()}, tare)
    outputs = _array_outputs(engine, recordings, calibration)
    tracker = tracker_for(engine, tracking)
    sensors: dict[str, SensorEvaluation] = {}
    notes: list[str] = [f"{name}: {line}" for name, line in tared.items()]
    for name, cal in calibration.sensors.items():
        rec = recordings.get(name)
        if rec is None:
            notes.append(f"{name}: calibrated but not in the data")
            continue
        if rec.s is None:
            notes.append(f"{name}: no strain_reference in the data, not scored")
            continue
        t = np.asarray(rec.t, dtype=np.float64)
        r = np.asarray(rec.r, dtype=np.float64)
        s = np.asarray(rec.s, dtype=np.float64)
        out = outputs.get(name) or (tracker or engine).run(name, t, r, rec.temperature)
        fused = None
        if references_every is not None:
            fused = SparseFusion.for_calibration(cal, references_every)
            out = fused.fuse(t, out, s)
        estimate = np.asarray(out.strain, dtype=np.float64)
        status = np.asarray(out.status)
        good = used_mask(status)
        scored = good & np.isfinite(s) & np.isfinite(estimate)
        bad_by_status = {Status(int(v)).name.lower(): int(np.sum(status == v))
                         for v in np.unique(status[~good])}
        sensors[name] = SensorEvaluation(
            name=name, model=cal.model, stats=error_stats(estimate[scored], s[scored]),
            t=t, r=r, reference=s, estimate=estimate,
            direction=np.asarray(out.direction), scored=scored, n_samples=int(t.size),
            n_bad=int(np.sum(~good)), n_out_of_range=int(np.sum(np.asarray(out.out_of_range))),
            bad_by_status=bad_by_status, unit=cal.strain_unit,
            out_of_range=np.asarray(out.out_of_range, bool), input_unit=_input_unit(cal),
            input_gain=engine.input_gain(name), tracking=_tracked(tracker, name),
            references=_fusion_state(fused))
        if rec.temperature is None:
            notes += _temperature_missing(name, calibration.sensors[name])
        notes += _crosstalk_off_tick(name, cal, {
            n for n, other in recordings.items()
            if rec.array is not None and other.array == rec.array})
    if not sensors:
        raise InputError(_nothing_scored(calibration, list(recordings)))
    return EvaluationResult(sensors, notes)


def _references_needed(calibration: Calibration, referenced: Mapping[str, bool],
                       every: float) -> None:
    """InputError naming the calibrated sensors of the data without a reference: the
    references to fuse every ``every`` s are the data's own."""
    missing = [n for n in calibration.sensors if n in referenced and not referenced[n]]
    if missing:
        raise InputError(f"--references-every {every:g}: {', '.join(missing)} has no "
                         "strain_reference in the data (the references fused are the data's "
                         "own /NAME/strain_reference)")


def _fusion_state(fused: SparseFusion | None) -> dict[str, Any] | None:
    """The JSON record of a sensor's fusion: its state and the spacing."""
    return None if fused is None else {"every": fused.every, **fused.fusion.state()}


def _input_unit(cal: SensorCalibration) -> str:
    return "V" if cal.input.kind == "divider" else "ohm"


def _tracked(tracker: BaselineTracker | None, name: str) -> dict[str, float] | None:
    """What tracking did to ``name`` (seconds at rest it moved the zero, total change of
    the tare gain), None without tracking."""
    if tracker is None:
        return None
    h = tracker.engine.health()[name]
    return {"seconds": h.baseline_tracked_s, "correction": h.baseline_correction}


def _crosstalk_off_tick(name: str, cal: SensorCalibration, same_tick: set[str]) -> list[str]:
    """The note for cross-talk terms whose neighbour is not on ``name``'s array topic (the
    sensors of ``same_tick``): offline such a term reads the neighbour's latest estimate of
    the previous batch, not of the same instant (``Engine.run``; the node, stepping each
    message, reads the latest one), so its correction is not the one diagnosed."""
    off = [f"{e.get('name')} ({e['params'].get('neighbour')})" for e in cal.effects
           if e.get("kind") == "crosstalk" and isinstance(e.get("params"), Mapping)
           and str(e["params"].get("neighbour")) not in same_tick]
    if not off:
        return []
    return [f"{name}: cross-talk term {', '.join(off)} reads a sensor not recorded on its "
            "array topic: offline it sees that sensor's estimate batch by batch, not tick by "
            "tick, and this error is not the calibration's (record the array on one topic)"]


def _temperature_missing(name: str, cal: SensorCalibration) -> list[str]:
    """The note for a run without temperature scored through a calibration with a
    temperature term: the term reads g = 0 (``core.effects``), it is not applied."""
    terms = [str(e.get("name")) for e in cal.effects if e.get("kind") == "temperature"]
    if not terms:
        return []
    return [f"{name}: no temperature in the data: the calibration's temperature term "
            f"{', '.join(terms)} is not applied"]


def _nothing_scored(calibration: Calibration, names: list[str]) -> str:
    return ("no calibrated sensor has a strain_reference in the data (calibration: "
            f"{', '.join(calibration.sensors)}; data: {', '.join(names) or 'none'})")


def in_run_bound(result: EvaluationResult, recordings: Mapping[str, Recording],
                 calibration: Calibration) -> None:
    """Set each scored sensor's ``in_run_rmse``: the same model (and fit options) fitted on
    the evaluated run itself and scored on it, i.e. what that model family can reach on
    this run; the gap to ``rmse`` is what does not transfer from the training runs. A run
    the model cannot be fitted to gets NaN and a note."""
    for name, ev in result.sensors.items():
        cal = calibration.sensors[name]
        options = cal.provenance.get("options") or {}
        if isinstance(options, Mapping) and "progress" in model_options(cal.model):
            options = {**options, "progress": False}  # a refit inside evaluate: no grid lines
        try:
            own = fit_sensor([recordings[name]], cal.model, name=name, options=options or None)
            again = evaluate_recordings({name: recordings[name]}, Calibration({name: own}))
            ev.in_run_rmse = again.sensors[name].stats.rmse
        except StrainCompError as err:
            ev.in_run_rmse = math.nan
            result.notes.append(f"{name}: no in-run bound ({err})")


def _array_outputs(engine: Any, recordings: Mapping[str, Recording],
                   calibration: Calibration) -> dict[str, Any]:
    """``Engine.run_array`` outputs of the calibrated, referenced sensors of every array
    whose sensors share one time base (cross-talk terms then read the same tick's
    neighbours, as the node does); other sensors are run one by one by the caller."""
    groups: dict[str, list[str]] = {}
    for name in calibration.sensors:
        rec = recordings.get(name)
        if rec is not None and rec.s is not None and rec.array is not None:
            groups.setdefault(rec.array, []).append(name)
    out: dict[str, Any] = {}
    for names in groups.values():
        recs = [recordings[n] for n in names]
        t = np.asarray(recs[0].t, dtype=np.float64)
        if len(names) < 2 or any(not np.array_equal(rec.t, t) for rec in recs):
            continue
        out.update(engine.run_array(names, t, np.column_stack([rec.r for rec in recs]),
                                    {n: recordings[n].temperature for n in names}))
    return out


def format_table(result: EvaluationResult) -> str:
    """Fixed-width error table, errors in each calibration's strain unit (% strain)."""
    header = (f"{'sensor':<16} {'model':<11} {'n':>8} {'RMSE':>9} {'MAE':>9} {'max':>9} "
              f"{'R^2':>8}")
    lines = [header, "-" * len(header)]
    for name, ev in result.sensors.items():
        st = ev.stats
        lines.append(f"{name:<16} {ev.model:<11} {st.n:>8d} {st.rmse:>9.4f} {st.mae:>9.4f} "
                     f"{st.max_abs:>9.4f} {st.r2:>8.5f}")
        if ev.in_run_rmse is not None:
            lines.append(f"{'':<16} in-run bound (same model fitted on this run): RMSE "
                         f"{ev.in_run_rmse:.4f}")
    units = sorted({ev.unit for ev in result.sensors.values()} or {"%"})
    words = strain_unit_words(units[0])
    if len(units) > 1:
        words = ", ".join(strain_unit_words(u) + " (" + ", ".join(
            n for n, ev in result.sensors.items() if ev.unit == u) + ")" for u in units)
    lines.append(f"errors in {words}; RMSE [Electrolycra] eq. (5)")
    return "\n".join(lines)


def format_notes(result: EvaluationResult) -> list[str]:
    """Lines for what the table does not show: bad samples, out-of-range, unscored sensors."""
    lines = []
    for name, ev in result.sensors.items():
        if ev.n_bad:
            kinds = ", ".join(f"{k} {v}" for k, v in ev.bad_by_status.items())
            lines.append(f"{name}: {ev.n_bad} of {ev.n_samples} samples bad ({kinds}); "
                         "estimate held, not scored")
        if ev.n_out_of_range:
            lines.append(f"{name}: {ev.n_out_of_range} of {ev.n_samples} samples outside the "
                         "calibration's valid range (flagged, scored); if the run's rest "
                         "level moved, try --tare auto, or strain-comp recalibrate")
        if ev.references is not None:
            lines.append(fusion_note(name, ev.references, ev.references["every"], ev.unit))
    return lines + list(result.notes)


# --------------------------------------------------------------------------- streamed


class _Kept:
    """Every ``stride``-th sample of one sensor, for plots: at most ``cap`` samples (when
    more, every other kept sample goes and the stride doubles)."""

    FIELDS = ("t", "r", "reference", "estimate", "direction", "scored", "out_of_range")

    def __init__(self, cap: int) -> None:
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
        for key in self.FIELDS:
            new = columns[key][take]
            self.columns[key] = new if key not in self.columns else \
                np.concatenate((self.columns[key], new))
        while self.index.size > self.cap:
            self.stride *= 2
            take = self.index % self.stride == 0
            self.index = self.index[take]
            self.columns = {k: v[take] for k, v in self.columns.items()}

    def get(self, key: str) -> np.ndarray:
        return self.columns.get(key, np.empty(0))


class _Score:
    """One sensor's running statistics and cumulative status counts."""

    def __init__(self, plot_points: int) -> None:
        self.errors = ErrorAccumulator()
        self.n_samples = 0
        self.n_bad = 0
        self.n_out_of_range = 0
        self.bad: dict[int, int] = {}
        self.kept = _Kept(plot_points) if plot_points > 0 else None

    def add(self, t: np.ndarray, r: np.ndarray, s: np.ndarray, out: BatchOutput) -> None:
        estimate = np.asarray(out.strain, dtype=np.float64)
        status = np.asarray(out.status)
        good = used_mask(status)
        scored = good & np.isfinite(s) & np.isfinite(estimate)
        self.errors.add(estimate[scored], s[scored])
        self.n_samples += int(t.size)
        self.n_bad += int(np.sum(~good))
        self.n_out_of_range += int(np.sum(np.asarray(out.out_of_range)))
        values, counts = np.unique(status[~good], return_counts=True)
        for v, c in zip(values.tolist(), counts.tolist(), strict=True):
            self.bad[int(v)] = self.bad.get(int(v), 0) + int(c)
        if self.kept is not None:
            self.kept.add(t=t, r=r, reference=s, estimate=estimate,
                          direction=np.asarray(out.direction), scored=scored,
                          out_of_range=np.asarray(out.out_of_range, bool))

    def evaluation(self, name: str, model: str, unit: str, input_unit: str = "ohm"
                   ) -> SensorEvaluation:
        kept = self.kept or _Kept(0)
        return SensorEvaluation(
            name=name, model=model, stats=self.errors.stats(), t=kept.get("t"),
            r=kept.get("r"), reference=kept.get("reference"), estimate=kept.get("estimate"),
            direction=kept.get("direction"), scored=kept.get("scored").astype(bool),
            n_samples=self.n_samples, n_bad=self.n_bad, n_out_of_range=self.n_out_of_range,
            bad_by_status={Status(v).name.lower(): c for v, c in sorted(self.bad.items())},
            unit=unit, errors=self.errors,
            out_of_range=kept.get("out_of_range").astype(bool), input_unit=input_unit)


@dataclass
class _Input:
    """One ``/PREFIX/resistance`` topic: its calibrated columns and what waits for the
    reference (or temperature) to arrive."""

    prefix: str
    names: list[str]
    """Calibrated sensors, in column order of ``columns``."""
    columns: list[int]
    single: bool
    group: list[str]
    """Sensors run together by ``Engine.run_array`` (calibration order), else empty."""
    temperature: PieceAlign | None
    """Only when an effect term of a sensor here could read it."""
    reference: dict[str, PieceAlign]
    """Per sensor its reference alignment (PieceAlign)."""
    ref_columns: dict[str, int | None] | None = None
    """Per sensor its reference column (None: a 1-D reference); None until the reference
    topic is first seen; empty when it does not fit."""
    t: np.ndarray = field(default_factory=lambda: np.empty(0))
    r: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))


class _Stream:
    """``evaluate_recordings`` carried from one piece of a bag to the next."""

    def __init__(self, calibration: Calibration, engine: Engine, tare: str,
                 plot_points: int, series: SeriesCSV | None = None, bag: str = "",
                 tracking: str = DEFAULT_TRACKING,
                 references_every: float | None = None) -> None:
        self.calibration = calibration
        self.references_every = references_every
        self.fused: dict[str, SparseFusion] = {}
        self.series = series
        self.bag = bag
        self.engine = engine
        self.tracker = tracker_for(engine, tracking)
        self.tare = tare
        self.plot_points = plot_points
        self.inputs: dict[str, _Input | None] = {}
        self.names: list[str] = []
        """Every sensor found in the data, in ``load_recordings`` order."""
        self.scores: dict[str, _Score] = {}
        self.notes: list[str] = []
        self.bag_problems: list[str] = []
        self.problems: list[str] = []
        self.references: set[str] = set()
        self.with_temperature: set[str] = set()
        """Sensors whose input has a temperature sample in a piece read so far."""

    def _problem(self, line: str) -> None:
        if line not in self.problems:
            self.problems.append(line)

    def piece(self, contents: BagContents) -> None:
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

    def finish(self) -> None:
        for inp in self.inputs.values():
            if inp is not None:
                for align in [inp.temperature, *inp.reference.values()]:
                    if align is not None:
                        align.finish()
                self._run(inp)
        for topic in sorted(self.references):
            if topic[:-len(REFERENCE)] + RESISTANCE not in self.inputs:
                self._problem(f"{topic}: reference without a resistance topic; ignored")

    def _input(self, topic: str, contents: BagContents) -> _Input | None:
        """What a resistance topic first seen in ``contents`` is (as ``load_recordings``
        reads it), tared from this first piece (as ``replay`` does)."""
        prefix = topic[:-len(RESISTANCE)]
        series = contents.series[topic]
        single = series.values.ndim == 1
        if single:
            labels = [prefix.lstrip("/")]
        else:
            labels, problem = array_sensor_names(topic, contents.labels.get(topic) or [],
                                                 series.values.shape[1])
            if problem is not None:
                self._problem(problem)
        names: list[str] = []
        columns: list[int] = []
        for j, name in enumerate(labels):
            if not single and name in self.names:
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
                      PieceAlign() if effects else None,
                      {n: PieceAlign() for n in names}, r=np.empty((0, len(names))))

    def _ref_columns(self, inp: _Input, topic: str, contents: BagContents
                     ) -> dict[str, int | None]:
        """Reference column of each sensor of ``inp`` (``load_recordings``'s rules)."""
        ref = contents.series[inp.prefix + REFERENCE]
        if inp.single:
            if ref.values.ndim == 1:
                return {inp.names[0]: None}
            self._problem(f"{inp.prefix + REFERENCE}: an array reference for a single sensor")
            return {}
        labels, _ = array_sensor_names(topic, contents.labels.get(topic) or [],
                                       contents.series[topic].values.shape[1])
        ref_labels = contents.labels.get(inp.prefix + REFERENCE) or labels
        if ref.values.ndim == 2 and ref.values.shape[1] == len(ref_labels) \
                and set(labels) <= set(ref_labels):
            return {n: ref_labels.index(n) for n in inp.names}
        self._problem(f"{inp.prefix + REFERENCE}: columns do not match {topic}; ignored")
        return {}

    def _add(self, inp: _Input, topic: str, contents: BagContents) -> None:
        """Queue a piece's samples of ``inp`` and feed its alignments."""
        empty = np.empty(0)
        series = contents.series.get(topic)
        t = series.t if series is not None else empty
        if series is not None and t.size:
            values = series.values[:, None] if inp.single else series.values
            inp.t = np.concatenate((inp.t, t))
            inp.r = np.concatenate((inp.r, values[:, inp.columns]))
        if inp.temperature is not None:
            temp = contents.series.get(inp.prefix + TEMPERATURE)
            if temp is not None and temp.values.ndim == 1:
                inp.temperature.add(t, temp.t, temp.values)
                if temp.t.size:
                    self.with_temperature.update(inp.names)
            else:
                inp.temperature.add(t, empty, empty)
        ref = contents.series.get(inp.prefix + REFERENCE)
        if ref is not None and inp.ref_columns is None:
            inp.ref_columns = self._ref_columns(inp, topic, contents)
        for name, align in inp.reference.items():
            column = (inp.ref_columns or {}).get(name, -1)
            if ref is None or column == -1:
                align.add(t, empty, empty)
            else:
                align.add(t, ref.t, ref.values if column is None else ref.values[:, column])

    def _run(self, inp: _Input) -> None:
        """Compensate and score the queued samples whose reference is known."""
        horizon = min(a.horizon() for a in [inp.temperature, *inp.reference.values()]
                      if a is not None)
        n = int(np.searchsorted(inp.t, horizon, side="right"))
        if n == 0:
            return
        t, r = inp.t[:n], inp.r[:n]
        inp.t, inp.r = inp.t[n:], inp.r[n:]
        temp = None if inp.temperature is None else inp.temperature.take(t)
        refs = {name: align.take(t) for name, align in inp.reference.items()}
        column = {name: j for j, name in enumerate(inp.names)}
        if inp.group:
            outs = self.engine.run_array(inp.group, t, r[:, [column[g] for g in inp.group]],
                                         {g: temp for g in inp.group})
        else:
            run = (self.tracker or self.engine).run  # tracking between stretches if on
            outs = {name: run(name, t, r[:, j], temp) for j, name in enumerate(inp.names)}
        for name, fused in self.fused.items():
            if name in outs:
                outs[name] = fused.fuse(t, outs[name], refs[name])
        for name, j in column.items():
            self.scores[name].add(t, r[:, j], refs[name], outs[name])
            if self.series is not None:
                cal, out = self.calibration.sensors[name], outs[name]
                self.series.add(name, t, cal.input.to_ohm(r[:, j]), out.strain, refs[name],
                                out.direction, out.status, unit=cal.strain_unit, bag=self.bag)

    def result(self) -> EvaluationResult:
        referenced = {name for inp in self.inputs.values() if inp is not None
                      for name in inp.ref_columns or {}}
        if self.references_every is not None:
            _references_needed(self.calibration, {n: n in referenced for n in self.names},
                               self.references_every)
        sensors: dict[str, SensorEvaluation] = {}
        notes = list(self.notes)
        for name, cal in self.calibration.sensors.items():
            if name not in self.names:
                notes.append(f"{name}: calibrated but not in the data")
            elif name not in referenced:
                notes.append(f"{name}: no strain_reference in the data, not scored")
            else:
                sensors[name] = self.scores[name].evaluation(name, cal.model,
                                                                cal.strain_unit,
                                                                _input_unit(cal))
                sensors[name].input_gain = self.engine.input_gain(name)
                sensors[name].tracking = _tracked(self.tracker, name)
                sensors[name].references = _fusion_state(self.fused.get(name))
                if name not in self.with_temperature:
                    notes += _temperature_missing(name, cal)
                notes += _crosstalk_off_tick(name, cal, next(
                    (set(inp.names) for inp in self.inputs.values()
                     if inp is not None and not inp.single and name in inp.names), set()))
        return EvaluationResult(sensors, notes)


def evaluate_bag(path: str | os.PathLike[str], calibration: Calibration, *,
                 tare: str = "calibration", window: int = WINDOW,
                 plot_points: int = 0, series: SeriesCSV | None = None,
                 out_of_range: str = "extend", tracking: str = DEFAULT_TRACKING,
                 references_every: float | None = None,
                 ) -> tuple[EvaluationResult, list[str]]:
    """``evaluate_recordings`` of the bag at ``path``, streamed: read in time-ordered pieces
    of about ``window`` messages (``iter_bag``), each compensated and scored before the next
    is read. Returns the result and the bag's problem lines (reader first, then the
    recordings' as ``load_recordings`` gives them).

    ``tare``: as in ``evaluate_recordings``, each input tared from the first piece it
    appears in (``replay_bag``'s rule). ``plot_points``: keep that many evenly spaced
    samples per sensor for plots (0: none). ``series``: every sample's row goes there
    (``evaluate --csv``; rows of a bag that fails are written before the error). Raises
    InputError when no calibrated sensor
    can be scored (names both sides and the bag's problems). ``references_every``: as in
    ``evaluate_recordings``.
    """
    if references_every is not None:
        check_every(references_every)
    stream = _Stream(calibration, Engine(calibration, out_of_range=out_of_range), tare,
                     plot_points, series, str(path), tracking, references_every)
    for contents in iter_bag(path, window=window):
        stream.piece(contents)
    stream.finish()
    problems = stream.bag_problems + located(path, stream.problems)
    result = stream.result()
    if not result.sensors:
        raise InputError("; ".join([f"{path}: {_nothing_scored(calibration, stream.names)}",
                                    *problems]))
    return result, problems
