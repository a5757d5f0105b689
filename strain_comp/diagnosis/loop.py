"""The residual loop (docs/design.md, "The residual loop"): find the effect a calibration lacks,
add it as an explicit online term, and report the error before and after on held-out data.

Per calibrated sensor that has a recording with a reference strain:

1. **Residual.** The calibration, with its effect terms removed, runs through the engine's
   batch path (``Engine.run``, the code replay and the node use) to give the model's own
   estimate S_hat and the published direction d; the sensor's existing effect terms (if
   any) are applied on top, and e = S_corrected - S over the samples the engine used whose
   reference is finite. Effect state restarts at the engine's gap resets, as online.
   A run that starts while its resistance still relaxes from a stretch before the
   recording (``strain_comp.core.tare.unsettled_start``: the rest before the reference
   first moves drifts as the automatic tare refuses; judged on the resistance, and timed
   from the first sample with a reference) leaves that rest out of steps 3-6, in fit and
   validation runs alike: no term whose state starts at the first sample can know that
   earlier stretch, and those samples would decide the intercept every term is fitted
   with. The engine still applies the terms there online; the message says what was left
   out.
2. **Candidates.** Every regressor of ``default_candidates`` (``strain_comp.core.effects``: rate,
   direction, creep (one Prony-series state of the estimate or of 100 ln R each, 0.25-362
   s; ``report.creep_tau``), relaxation after loading or unloading steps only (0.5-128 s),
   a fading memory of the resistance itself (peak, trough of 100 ln R, 1-256 s),
   elapsed-time drift, temperature when a temperature series exists, strain level,
   Mullins-type history incl. the peak strain, cross-talk from array neighbours at index
   +-1, and a per-run ``baseline``) is computed online over each recording, exactly as
   the engine would compute it. Nothing about how the data were made is known.
3. **Blocks.** Each recording is cut by time into ``n_blocks`` contiguous blocks (never
   random samples). Without validation recordings, every ``round(1 / holdout_fraction)``-th
   block is held out for the final report; the other blocks are the fit data.
4. **Scores.** Blocked cross-validation on the fit data (leave one block position out of
   every recording per fold): a model is e ~ c0 + sum_j c_j g_j fitted by least squares on
   the other folds and scored on the held-out fold. A candidate's ``score`` is the share of
   the residual variance it explains on data it was not fitted on, relative to the
   intercept-only model (for ``offset`` and ``baseline``: relative to no correction).
   Scores can be negative (the term only fits noise).
5. **Greedy forward selection.** Add the candidate whose relative drop of the
   cross-validated RMSE is largest, refit, repeat while that gain exceeds ``margin``, the
   fold-wise drop is positive by more than ``SIGNIFICANCE`` standard errors (a term that
   helps in a few stretches of the record and hurts in others fits a coincidence of the
   profile), and at most ``max_effects`` times. The intercept (an effect of kind
   ``offset``) is fitted with any added effect and stored with it; an effect's gain is
   measured against the current model *with* the intercept, so an effect never gets the
   credit of a mere offset (the offset competes as a candidate of its own).
6. **Report.** The selected terms are fitted on all fit data; RMSE before and after is
   measured on the held-out blocks or on the ``validate_recordings``. An effect is kept
   if it lowers that held-out RMSE by more than ``margin``, below both the model before it
   and that model with an intercept (with several validation runs, the median run's RMSE
   too, and no run's may rise by more than ``margin``); one that does not is not added,
   and the later ones are still tried (without a session start; with one, step 8). The result
   says when nothing helps. The output calibration is the input plus
   the added effect entries, with the coefficients whose held-out error is reported.
7. **Per-run baseline.** A ``baseline`` term (the mean S_hat over the first seconds of a
   run, minus the strain runs start at) is a per-run intercept: inside one run it cannot be
   told from a constant ``offset``. It is tested as a second hypothesis: its shift is
   removed whole (coefficient 1, no automatic intercept), steps 5-6 run on what is left,
   and the baseline hypothesis replaces the constant-intercept one only if its held-out
   RMSE is lower by more than ``margin``. That choice is made on the held-out data, like
   the veto of step 6: given a ``--validate`` recording of another run it is a cross-run
   test; on held-out blocks of one run the two tie and the constant hypothesis stays.

8. **Session start.** With ``validate_recordings`` (and ``session_start``), every held-out
   figure of steps 6-7 is the validation run's RMSE as the product is used: the calibration
   with the terms started on that run as ``strain-comp start`` starts it (its second load
   and unload after a warm-up one, else its first: ``strain_comp.offline.session_start``,
   the benchmark's procedure; a run it refuses as it is), then evaluated over the whole
   run. The per-run ``baseline`` hypothesis is then not tried: that recalibration
   re-zeroes every run itself, and a baseline term (whose steady output is the rest
   strain at any resistance) would leave it no input span to make. Nor are an intercept
   (``offset``) or a plain gain (``strain_level`` of power 1) written or scored: the
   output map of that recalibration makes its own, and through the steady outputs the
   input span reads they would only move where that span lands. The terms are still
   fitted with the intercept (steps 4-5), so their coefficients are not biased by a mean.
   A validation run whose stretches allow neither step is measured as calibrated.
   Steps 5-6 are then one (``selection.select_carried``): at each step the candidates
   that pass step 5 on the diagnosed run, the ``LoopPolicy.tried`` best, are each fitted
   there and scored on every validation run after its session start; the one whose log
   RMSE ratios on the validation runs have the
   lowest upper bound, the prediction bound of one more run's (``LoopPolicy.level``,
   Student's t over the validation runs), is added if that bound is below ln(1 - margin):
   it lowers the error beyond the spread between runs. The terms are thus chosen by what
   carries, not by what fits the diagnosed run best (a drift that two runs share and a
   third does not, a memory that ratchets on another run's noise, are seen as the spread
   they make). Where none carries, the message says why and what to record instead
   (``findings.instead``).

Decisions: the regressors read the engine's clamped estimate (identical to the online
input as long as the estimate is inside the valid strain range widened by the engine's
margin); effect state is reset at the engine's gap resets, in diagnosis as online.

The package: ``candidates`` (step 2), ``residuals`` and ``rows`` (steps 1-3),
``selection`` (steps 4-6 and 8, testable alone) with its numbers in ``policy``,
``session`` (the session start), ``findings`` (the message and records), ``report``
(results, readings, plots), this module (the per-sensor loop) and ``conditions`` (tare
and measurement-chain hypotheses around the whole loop).
"""

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
from strain_comp.diagnosis.policy import LOOP_POLICY, LoopPolicy
from strain_comp.diagnosis.report import DiagnoseResult, SensorDiagnosis
from strain_comp.diagnosis.residuals import (
    Run,
    as_bags,
    base_runs,
    holdout_period,
    rmse_stats,
    series_of,
    stride_of,
)
from strain_comp.diagnosis.rows import Candidates, Rows, candidates_of, rows_of
from strain_comp.diagnosis.selection import (
    Gram,
    HeldOut,
    Tried,
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


def _choose(gram: Gram, rows: Rows, cands: Candidates, scores: dict[int, float],
            policy: LoopPolicy, held_out: HeldOut, runs: np.ndarray | None) -> Any:
    """Forward selection kept on the held-out rows, and for each baseline candidate the
    per-run hypothesis (the start-of-run shift removed whole) when it wins by the margin
    (without a session start: steps 5-7)."""
    n, offset, baselines = len(cands.names), cands.offset, cands.baselines
    margin, max_effects = policy.margin, policy.max_effects
    chosen = select_forward(gram, n, offset, margin, max_effects, skip=baselines)
    best = keep_on_held_out(gram, chosen, None, offset, rows.n_folds, margin, held_out, runs)
    rmse_none = gram.cv_rmse([])
    for b in baselines:
        shifted = Gram(rows.g_fit, rows.e_fit - rows.g_fit[:, b], rows.fold, rows.n_folds)
        rmse_b = shifted.cv_rmse([])
        selection = select_forward(shifted, n, offset, margin, max_effects - 1,
                                   auto_intercept=False, skip=baselines)
        selection.gains = {b: 1.0 - rmse_b / rmse_none if rmse_none > 0 else 0.0,
                           **selection.gains}
        branch = keep_on_held_out(shifted, selection, b, offset, rows.n_folds, margin,
                                  held_out, runs)
        if branch.shift is not None and branch.rmse < (1.0 - margin) * best.rmse:
            best = branch
    return best


def _baseline_scores(gram: Gram, rows: Rows, cands: Candidates, scores: dict[int, float]
                     ) -> None:
    """``scores`` of the per-run baseline candidates: the share of the cross-validated
    residual variance their start-of-run shift, removed whole, explains (step 7)."""
    rmse_none = gram.cv_rmse([])
    for b in cands.baselines:
        shifted = Gram(rows.g_fit, rows.e_fit - rows.g_fit[:, b], rows.fold, rows.n_folds)
        scores[b] = 1.0 - (shifted.cv_rmse([]) / rmse_none) ** 2 if rmse_none > 0 else 0.0


@dataclass
class _Selected:
    """The terms one sensor's loop adds (columns, coefficients), their gains, the terms
    selected on the diagnosed run alone (without a session start) and the best candidate
    scored after the session start and not added."""

    terms: list[int]
    coefs: list[float]
    gains: dict[int, float]
    chosen: list[int]
    refused: Tried | None


def _select(gram: Gram, rows: Rows, cands: Candidates, scores: dict[int, float],
            policy: LoopPolicy, held_out: HeldOut, runs: np.ndarray | None,
            session: SessionHeldOut | None) -> _Selected:
    """Steps 5-7, or with a session start step 8 (what the session start makes itself,
    the per-run baseline among it, is neither tried nor written)."""
    if session is not None:
        n = len(cands.names)
        skip = [j for j in range(n) if j in cands.baselines or session.redundant(j)]
        carried = select_carried(gram, n, cands.offset, session.per_run, policy, skip)
        kept = [k for k, j in enumerate(carried.kept) if not session.redundant(j)]
        return _Selected([carried.kept[k] for k in kept], [float(carried.coef[k]) for k in kept],
                         carried.selection.gains, carried.selection.chosen, carried.refused)
    best = _choose(gram, rows, cands, scores, policy, held_out, runs)
    rmse_before = rms(held_out([], np.zeros(0)))
    terms = ([best.shift] if best.shift is not None and best.rmse < rmse_before else []) \
        + best.kept
    coefs = ([1.0] if terms[:1] == [best.shift] else []) + [float(c) for c in best.coef]
    return _Selected(terms, coefs, best.selection.gains, best.selection.chosen, None)


@dataclass
class _Setup:
    """One sensor's candidates, rows, cross-validation sums and first-round scores, and
    the held-out measure (the validation runs after their session start, or linear)."""

    cands: Candidates
    rows: Rows
    gram: Gram
    scores: dict[int, float]
    session: SessionHeldOut | None
    strides: tuple[int, int | None]


def _setup(sensor: str, calibration: Calibration, bags: list[Mapping[str, Recording]],
           validate: list[Mapping[str, Recording]] | None, base_fit: list[dict[str, Run]],
           base_val: list[dict[str, Run]], candidates: Sequence[dict[str, Any]] | None,
           holdout_fraction: float, n_blocks: int, stretch_history: bool,
           session_start: bool) -> _Setup | None:
    """Steps 1-4 for one sensor (None: no usable recording)."""
    cands = candidates_of(sensor, bags, base_fit, candidates, stretch_history)
    session = (None if validate is None or not session_start
               else SessionHeldOut(calibration, sensor, validate, cands.entries))
    if session is not None and not session.usable():
        session = None
    stride = stride_of(bags, sensor)
    val_stride = 1 if validate is None else stride_of(validate, sensor)
    series = [s for b, runs in zip(bags, base_fit, strict=True) if sensor in b
              for s in [series_of(sensor, b, runs, cands.entries, n_blocks, stride)]
              if s is not None]
    if not series:
        return None
    period = holdout_period(holdout_fraction) if validate is None else 0
    rows = rows_of(sensor, series, validate, base_val, cands.entries, n_blocks, period,
                   val_stride)
    gram = Gram(rows.g_fit, rows.e_fit, rows.fold, rows.n_folds)
    scores = candidate_scores(gram, len(cands.names), cands.offset)
    _baseline_scores(gram, rows, cands, scores)
    return _Setup(cands, rows, gram, scores, session,
                  (stride, val_stride if validate is not None else None))


def _diagnose_sensor(sensor: str, calibration: Calibration, setup: _Setup,
                     policy: LoopPolicy) -> SensorDiagnosis:
    """One sensor's loop (module docstring) on its ``setup``."""
    cal = calibration.sensors[sensor]
    cands, rows, session = setup.cands, setup.rows, setup.session
    linear = linear_held_out(rows.e_out, rows.g_out)
    held_out: HeldOut = linear if session is None else session
    runs = None  # the validation run of each held-out sample (without a session start)
    if session is None and rows.val_series:
        runs = np.concatenate([np.full(s.e.size, k) for k, s in enumerate(rows.val_series)])
    picked = _select(setup.gram, rows, cands, setup.scores, policy, held_out, runs, session)
    terms, coefs = picked.terms, picked.coefs
    e_before = held_out([], np.zeros(0))
    e_after = held_out(terms, np.array(coefs))
    order = [j for j in terms if j != cands.offset] or terms
    message = message_of(cal, cands, rows, picked.chosen, picked.refused, setup.scores, order,
                         picked.gains, policy.margin, rms(e_before), rms(e_after),
                         session is not None, setup.strides)
    e_linear = linear(terms, np.array(coefs))
    winner = cands.names[order[0]] if order else None
    plot = {}
    if winner is not None:
        plot = {"t": rows.t_out, "e_before": rows.e_out, "e_after": e_linear,
                "g": rows.g_out[:, order[0]], "s": rows.s_out}
    found = SensorDiagnosis(
        name=sensor, before=rmse_stats(e_before), after=rmse_stats(e_after),
        scores=score_rows(sensor, cal, cands, rows, setup.scores, terms, coefs, picked.gains),
        added=added_effects(cands.entries, terms, coefs, cal.effects), message=message,
        plot=plot, winner=winner)
    if session is not None:
        found.as_calibrated = {"before": rmse_stats(rows.e_out), "after": rmse_stats(e_linear)}
        found.session = session_record(cal, session, rows.e_out, e_before, policy.margin)
        found.runs_after = [rms(e) for e in session.per_run(terms, np.array(coefs))]
    return found


def diagnose(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]],
             calibration: Calibration, *,
             validate_recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             | None = None, holdout_fraction: float = 0.3,
             candidates: Sequence[dict[str, Any]] | None = None, n_blocks: int = 10,
             policy: LoopPolicy = LOOP_POLICY, tare: str = "calibration",
             stretch_history: bool = False,
             session_start: bool = True,
             on_sensor: Callable[[str], None] | None = None) -> DiagnoseResult:
    """Run the residual loop (module docstring) on every calibrated sensor with a reference."""
    if not 0.0 < holdout_fraction < 1.0:
        raise InputError(f"holdout_fraction must be in (0, 1), got {holdout_fraction}")
    if n_blocks < 3:
        raise InputError(f"n_blocks must be >= 3, got {n_blocks}")
    bags = as_bags(recordings)
    validate = None if validate_recordings is None else as_bags(validate_recordings)
    base_fit = [base_runs(b, calibration, tare=tare) for b in bags]
    base_val = (None if validate is None
                else [base_runs(b, calibration, tare=tare) for b in validate])
    results: dict[str, SensorDiagnosis] = {}
    for sensor in calibration.sensors:
        setup = _setup(sensor, calibration, bags, validate, base_fit, base_val or [],
                       candidates, holdout_fraction, n_blocks, stretch_history, session_start)
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
        validation = {"kind": "held-out time blocks of the input", "n_blocks": n_blocks,
                      "held_out_every": holdout_period(holdout_fraction)}
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
