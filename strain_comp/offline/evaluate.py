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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.core.metrics import ErrorStats, error_stats
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording


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

    def to_dict(self) -> dict[str, Any]:
        """The JSON record: the docs/design.md keys first, then extra keys."""
        record: dict[str, Any] = {k: _json_number(v) for k, v in self.stats.to_dict().items()}
        record.update(model=self.model, n_samples=self.n_samples, n_bad=self.n_bad,
                      n_out_of_range=self.n_out_of_range, bad_by_status=self.bad_by_status)
        if self.in_run_rmse is not None:
            record["in_run_rmse"] = _json_number(self.in_run_rmse)
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
                        tare: str = "calibration") -> EvaluationResult:
    """Score every calibrated sensor that has a recording with a reference strain.

    ``tare``: ``calibration`` or ``auto`` (``strain_comp.core.tare.tare_engine``; what each
    tare read goes to the notes). Raises InputError when no calibrated sensor can be scored
    (names both sides).
    """
    from strain_comp.core.engine import Engine, Status, used_mask
    from strain_comp.core.tare import tare_engine

    engine = Engine(calibration)
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
        out = outputs.get(name) or engine.run(name, t, r, temperature=rec.temperature)
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
            bad_by_status=bad_by_status)
    if not sensors:
        raise InputError(
            "no calibrated sensor has a strain_reference in the data (calibration: "
            f"{', '.join(calibration.sensors)}; data: {', '.join(recordings) or 'none'})")
    return EvaluationResult(sensors, notes)


def in_run_bound(result: EvaluationResult, recordings: Mapping[str, Recording],
                 calibration: Calibration) -> None:
    """Set each scored sensor's ``in_run_rmse``: the same model (and fit options) fitted on
    the evaluated run itself and scored on it, i.e. what that model family can reach on
    this run; the gap to ``rmse`` is what does not transfer from the training runs. A run
    the model cannot be fitted to gets NaN and a note."""
    from strain_comp.errors import StrainCompError
    from strain_comp.offline.fit import fit_sensor

    for name, ev in result.sensors.items():
        cal = calibration.sensors[name]
        try:
            own = fit_sensor([recordings[name]], cal.model, name=name,
                             options=cal.provenance.get("options") or None)
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
    """Fixed-width error table, errors in % strain."""
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
    lines.append("errors in % strain; RMSE [Electrolycra] eq. (5)")
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
                         "calibration's valid range (flagged, scored)")
    return lines + list(result.notes)
