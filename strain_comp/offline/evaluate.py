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
sensor (the statistics use every sample). The in-run bound (``fit.in_run_bound``) fits a
model to the whole run: it needs the recordings loaded whole (``load_recordings``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.base.samples import Status, used_mask
from strain_comp.core.calibration import Calibration, check_reference
from strain_comp.core.engine import Engine
from strain_comp.core.fusion import SparseFusion, check_every
from strain_comp.core.metrics import band_counts, error_stats
from strain_comp.core.tare import tare_engine
from strain_comp.errors import InputError
from strain_comp.io.bag import iter_bag, located
from strain_comp.io.bag.reader import WINDOW
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate_stream import EvaluationStream
from strain_comp.offline.evaluation import (
    EvaluationResult,
    SensorEvaluation,
    crosstalk_off_tick,
    fusion_state,
    input_unit,
    nothing_scored,
    references_needed,
    temperature_missing,
)

if TYPE_CHECKING:
    from strain_comp.core.outputs import BatchOutput
    from strain_comp.offline.series import SeriesCSV

PLOT_POINTS = 50_000
"""Most samples per sensor ``evaluate_bag`` keeps for plots (evenly spaced)."""


def evaluate_recordings(recordings: Mapping[str, Recording], calibration: Calibration, *,
                        tare: str = "calibration", out_of_range: str = "extend",
                        references_every: float | None = None) -> EvaluationResult:
    """Score every calibrated sensor that has a recording with a reference strain."""
    if references_every is not None:
        check_every(references_every)
        references_needed(calibration, {n: r.s is not None for n, r in recordings.items()},
                          references_every)
    engine = Engine(calibration, out_of_range=out_of_range)
    tared = tare_engine(engine, {n: (rec.t, rec.r) for n, rec in recordings.items()}, tare)
    outputs = _array_outputs(engine, recordings, calibration)
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
        check_reference(name, s, InputError)
        out = outputs.get(name) or engine.run(name, t, r, rec.temperature)
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
            out_of_range=np.asarray(out.out_of_range, bool), input_unit=input_unit(cal),
            input_gain=engine.input_gain(name),
            references=fusion_state(fused), **band_of(out, estimate, s, scored))
        if rec.temperature is None:
            notes += temperature_missing(name, calibration.sensors[name])
        notes += crosstalk_off_tick(name, cal, {
            n for n, other in recordings.items()
            if rec.array is not None and other.array == rec.array})
    if not sensors:
        raise InputError(nothing_scored(calibration, list(recordings)))
    return EvaluationResult(sensors, notes)


def band_of(out: BatchOutput, estimate: np.ndarray, reference: np.ndarray,
            scored: np.ndarray) -> dict[str, Any]:
    """``SensorEvaluation``'s ``std`` and ``coverage_95`` of a run (none without a band)."""
    if out.std is None:
        return {}
    banded, inside = band_counts(estimate[scored], reference[scored], out.std[scored])
    return {"std": out.std, "coverage_95": inside / banded if banded else None}


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


def evaluate_bag(path: str | os.PathLike[str], calibration: Calibration, *,
                 tare: str = "calibration", window: int = WINDOW,
                 plot_points: int = 0, series: SeriesCSV | None = None,
                 out_of_range: str = "extend",
                 references_every: float | None = None,
                 ) -> tuple[EvaluationResult, list[str]]:
    """``evaluate_recordings`` of the bag at ``path``, streamed: read in time-ordered pieces
    of about ``window`` messages (``iter_bag``), each compensated and scored before the next
    is read."""
    if references_every is not None:
        check_every(references_every)
    stream = EvaluationStream(calibration, Engine(calibration, out_of_range=out_of_range),
                              tare, plot_points, series, str(path),
                              references_every)
    for contents in iter_bag(path, window=window):
        stream.piece(contents)
    stream.finish()
    problems = stream.bag_problems + located(path, stream.problems)
    result = stream.result()
    if not result.sensors:
        raise InputError("; ".join([f"{path}: {nothing_scored(calibration, stream.names)}",
                                    *problems]))
    return result, problems
