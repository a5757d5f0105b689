"""The residual loop per sensor (docs/design.md, "The residual loop", "The loop's steps"):
find the effect a calibration lacks, add it as an online term, report the held-out error."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.candidates import added_effects
from strain_comp.diagnosis.findings import message_of, score_rows, session_record
from strain_comp.diagnosis.report import DiagnoseResult, SensorDiagnosis
from strain_comp.diagnosis.residuals import (
    HELD_OUT_EVERY,
    N_BLOCKS,
    Candidates,
    Rows,
    Run,
    as_bags,
    base_runs,
    candidates_of,
    rmse_stats,
    rows_of,
    series_all,
    stride_of,
)
from strain_comp.diagnosis.selection import (
    LOOP_POLICY,
    Branch,
    Gram,
    HeldOut,
    LoopPolicy,
    candidate_scores,
    keep_on_held_out,
    linear_held_out,
    rms,
    select_carried,
    select_forward,
)
from strain_comp.diagnosis.session import SessionHeldOut
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording


@dataclass
class _Setup:
    """One sensor's candidates, rows, cross-validation sums, first-round scores, held-out."""

    cands: Candidates
    rows: Rows
    gram: Gram
    scores: dict[int, float]
    shifted: dict[int, Gram]
    """Each baseline candidate's Gram with its shift removed whole (step 7)."""
    session: SessionHeldOut | None
    strides: tuple[int, int | None]


def _select(setup: _Setup, policy: LoopPolicy, held_out: HeldOut, runs: np.ndarray | None
            ) -> Branch:
    """The terms added (``kept``, with ``coef``): steps 5-7, or with a session start step 8."""
    gram, cands, session = setup.gram, setup.cands, setup.session
    n, offset, baselines = len(cands.names), cands.offset, cands.baselines
    if session is not None:
        skip = [j for j in range(n) if j in baselines or session.redundant(j)]
        carried = select_carried(gram, n, offset, session.per_run, policy, skip)
        kept = [k for k, j in enumerate(carried.kept) if not session.redundant(j)]
        return dataclasses.replace(carried, kept=[carried.kept[k] for k in kept],
                                   coef=carried.coef[kept])
    margin, max_effects = policy.margin, policy.max_effects
    chosen = select_forward(gram, n, offset, margin, max_effects, skip=baselines,
                            sigmas=policy.significance)
    best = keep_on_held_out(gram, chosen, None, offset, margin, held_out, runs)
    rmse_none = gram.cv_rmse([])
    for b, shifted in setup.shifted.items():
        selection = select_forward(shifted, n, offset, margin, max_effects - 1,
                                   auto_intercept=False, skip=baselines,
                                   sigmas=policy.significance)
        selection.gains = {b: 1.0 - shifted.cv_rmse([]) / rmse_none if rmse_none > 0 else 0.0,
                           **selection.gains}
        branch = keep_on_held_out(shifted, selection, b, offset, margin, held_out, runs)
        if branch.shift is not None and branch.rmse < (1.0 - margin) * best.rmse:
            best = branch
    if best.shift is not None and best.rmse < rms(held_out([], np.zeros(0))):
        return dataclasses.replace(best, kept=[best.shift, *best.kept],
                                   coef=np.concatenate(([1.0], best.coef)))
    return best


def _setup(sensor: str, calibration: Calibration, bags: list[Mapping[str, Recording]],
           validate: list[Mapping[str, Recording]] | None, base_fit: list[dict[str, Run]],
           base_val: list[dict[str, Run]], candidates: Sequence[dict[str, Any]] | None,
           stretch_history: bool, session_start: bool) -> _Setup | None:
    """Steps 1-4 for one sensor (None: no usable recording)."""
    cands = candidates_of(sensor, bags, base_fit, candidates, stretch_history)
    session = (None if validate is None or not session_start
               else SessionHeldOut(calibration, sensor, validate, cands.entries))
    if session is not None and not any(start.steps for start in session.starts):
        session = None
    stride = stride_of(bags, sensor)
    val_stride = 1 if validate is None else stride_of(validate, sensor)
    series = series_all(sensor, bags, base_fit, cands.entries, stride)
    if not series:
        return None
    rows = rows_of(sensor, series, validate, base_val, cands.entries, val_stride)
    gram = Gram(rows.g_fit, rows.e_fit, rows.fold, rows.n_folds)
    scores = candidate_scores(gram, len(cands.names), cands.offset)
    shifted = {b: Gram(rows.g_fit, rows.e_fit - rows.g_fit[:, b], rows.fold, rows.n_folds)
               for b in cands.baselines}
    rmse_none = gram.cv_rmse([])
    for b, shifted_b in shifted.items():  # the share its shift, removed whole, explains
        scores[b] = 1.0 - (shifted_b.cv_rmse([]) / rmse_none) ** 2 if rmse_none > 0 else 0.0
    return _Setup(cands, rows, gram, scores, shifted, session,
                  (stride, val_stride if validate is not None else None))


def _diagnose_sensor(sensor: str, calibration: Calibration, setup: _Setup,
                     policy: LoopPolicy) -> SensorDiagnosis:
    """One sensor's loop (docs/design.md, "The loop's steps") on its ``setup``."""
    cal = calibration.sensors[sensor]
    cands, rows, session = setup.cands, setup.rows, setup.session
    linear = linear_held_out(rows.e_out, rows.g_out)
    held_out: HeldOut = linear if session is None else session
    runs = None  # the validation run of each held-out sample (without a session start)
    if session is None and rows.val_series:
        runs = np.concatenate([np.full(s.e.size, k) for k, s in enumerate(rows.val_series)])
    picked = _select(setup, policy, held_out, runs)
    terms, coefs = picked.kept, picked.coef
    e_before = held_out([], np.zeros(0))
    e_after = held_out(terms, coefs)
    order = [j for j in terms if j != cands.offset] or terms
    message = message_of(cal, cands, rows, picked.selection.chosen, picked.refused,
                         setup.scores, order, picked.selection.gains, policy.margin,
                         rms(e_before), rms(e_after), session is not None, setup.strides)
    e_linear = linear(terms, coefs)
    winner = cands.names[order[0]] if order else None
    plot = {}
    if winner is not None:
        plot = {"t": rows.t_out, "e_before": rows.e_out, "e_after": e_linear,
                "g": rows.g_out[:, order[0]], "s": rows.s_out}
    found = SensorDiagnosis(
        name=sensor, before=rmse_stats(e_before), after=rmse_stats(e_after),
        scores=score_rows(sensor, cal, cands, rows, setup.scores, terms, coefs,
                          picked.selection.gains),
        added=added_effects(cands.entries, terms, coefs.tolist(), cal.effects), message=message,
        plot=plot, winner=winner)
    if session is not None:
        found.as_calibrated = {"before": rmse_stats(rows.e_out), "after": rmse_stats(e_linear)}
        found.session = session_record(cal, session, rows.e_out, e_before, policy.margin)
        found.runs_after = [rms(e) for e in session.per_run(terms, coefs)]
    return found


def diagnose(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]],
             calibration: Calibration, *,
             validate_recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             | None = None, candidates: Sequence[dict[str, Any]] | None = None,
             policy: LoopPolicy = LOOP_POLICY, tare: str = "calibration",
             stretch_history: bool = False,
             session_start: bool = True,
             on_sensor: Callable[[str], None] | None = None) -> DiagnoseResult:
    """Run the residual loop on every calibrated sensor with a reference (docs/design.md)."""
    bags = as_bags(recordings)
    validate = None if validate_recordings is None else as_bags(validate_recordings)
    base_fit = [base_runs(b, calibration, tare=tare) for b in bags]
    base_val = (None if validate is None
                else [base_runs(b, calibration, tare=tare) for b in validate])
    results: dict[str, SensorDiagnosis] = {}
    for sensor in calibration.sensors:
        setup = _setup(sensor, calibration, bags, validate, base_fit, base_val or [],
                       candidates, stretch_history, session_start)
        if setup is not None:
            results[sensor] = _diagnose_sensor(sensor, calibration, setup, policy)
        if on_sensor is not None:  # progress (strain_comp.progress)
            on_sensor(sensor)
    if not results:
        raise InputError("no calibrated sensor has a recording with a strain_reference "
                         f"(calibrated: {', '.join(calibration.sensors)})")
    sensors_out = dict(calibration.sensors)
    for name, d in results.items():
        if d.added:
            sensors_out[name] = dataclasses.replace(
                sensors_out[name], effects=[*sensors_out[name].effects, *d.added])
    pooled_before = _pool(results, "before")
    pooled_after = _pool(results, "after")
    if validate is None:
        validated_on = "holdout"
        validation = {"kind": "held-out time blocks of the input", "n_blocks": N_BLOCKS,
                      "held_out_every": HELD_OUT_EVERY}
    else:
        validated_on = "validate"
        validation = {"kind": "validation recordings",
                      "sensors": sorted({n for b in validate for n in b}),
                      "session_start": sorted(n for n, d in results.items() if d.session)}
        if validation["session_start"]:
            validation["session_start_procedure"] = (
                "before and after measured on the whole validation run after recalibrate "
                "--input --from RUN --window START:END, then recalibrate --from RUN --window "
                "START:END on its second load and unload (else --first END on its first)")
    return DiagnoseResult(sensors=results, before=pooled_before, after=pooled_after,
                          validated_on=validated_on, validation=validation,
                          calibration=Calibration(sensors_out))


def _pool(results: Mapping[str, SensorDiagnosis], which: str) -> dict[str, float]:
    """RMSE and MAE pooled over every sensor's held-out samples."""
    n = sum(getattr(d, which)["n"] for d in results.values())
    sse = sum(getattr(d, which)["rmse"] ** 2 * getattr(d, which)["n"] for d in results.values())
    sae = sum(getattr(d, which)["mae"] * getattr(d, which)["n"] for d in results.values())
    return {"rmse": math.sqrt(sse / n), "mae": sae / n, "n": n}
