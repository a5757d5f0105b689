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
   and the later ones are still tried. The result
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
   with the terms recalibrated on that run's first load and unload (``recalibrate --input``,
   then the output map; ``strain_comp.diagnosis.session``), then evaluated over the whole
   run. The per-run ``baseline`` hypothesis is then not tried: that recalibration re-zeroes
   every run itself, and a baseline term (whose steady output is the rest strain at any
   resistance) would leave it no input span to make. Nor are an intercept (``offset``) or
   a plain gain (``strain_level`` of power 1) written or scored: the output map of that
   recalibration makes its own, and through the steady outputs the input span reads
   they would only move where that span lands. The terms are still fitted with the
   intercept (steps 4-5), so their coefficients are not biased by a mean. A validation
   run whose first cycle allows neither step is measured as calibrated.

Decisions: the regressors read the engine's clamped estimate (identical to the online
input as long as the estimate is inside the valid strain range widened by the engine's
margin); effect state is reset at the engine's gap resets, in diagnosis as online.

The package: ``candidates`` (step 2), ``selection`` (steps 4-6, testable alone),
``report`` (results, readings, plots), this module (residuals, blocks, the per-sensor
loop) and ``conditions`` (tare and measurement-chain hypotheses around the whole loop).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration, SensorCalibration, strain_unit_words
from strain_comp.core.effects import (
    regressor_from_dict,
)
from strain_comp.core.tare import TARE_WINDOW
from strain_comp.diagnosis.candidates import (
    added_effects,
    default_candidates,
)
from strain_comp.diagnosis.report import (
    SESSION_RECORDS,
    DiagnoseResult,
    EffectScore,
    SensorDiagnosis,
    creep_tau,
)
from strain_comp.diagnosis.residuals import (
    ROW_BUDGET,
    Run,
    Series,
    as_bags,
    base_runs,
    baseline_rest,
    holdout_period,
    neighbours_of,
    rmse_stats,
    series_of,
    stride_of,
)
from strain_comp.diagnosis.selection import (
    Gram,
    candidate_scores,
    keep_on_held_out,
    linear_held_out,
    rms,
    select_forward,
)
from strain_comp.diagnosis.session import SessionHeldOut
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording

GAIN_CHANGE = 0.05
"""A sensitivity against the calibration this far from 1 (the session start's input span
on the validation run), which that session start corrects, is read as a gain change
between runs."""


@dataclass
class _Candidates:
    """The candidate effects of one sensor, with an offset always among them."""

    entries: list[dict[str, Any]]
    names: list[str]
    kinds: list[str]
    offset: int
    """Index of the offset."""
    baselines: list[int]
    """Indices of the per-run baseline candidates."""


def _candidates(sensor: str, bags: list[Mapping[str, Recording]], base_fit: list[dict[str, Run]],
                candidates: Sequence[dict[str, Any]] | None, stretch_history: bool
                ) -> _Candidates:
    """The given candidates, or ``default_candidates`` for what the recordings hold
    (temperature, array neighbours), each with coefficient 0, plus an offset."""
    if candidates is None:
        temps = [np.asarray(b[sensor].temperature, np.float64) for b in bags
                 if sensor in b and b[sensor].temperature is not None]
        temps = [x[np.isfinite(x)] for x in temps]
        have_temp = any(x.size and np.ptp(x) > 0 for x in temps)
        t_ref = float(np.mean(np.concatenate(temps))) if have_temp else None
        nbrs = sorted({n for b, runs in zip(bags, base_fit, strict=True) if sensor in b
                       for n in neighbours_of(b[sensor], b) if n in runs})
        candidates = default_candidates(temperature_ref=t_ref, neighbours=nbrs,
                                        baseline_rest=baseline_rest(bags, sensor),
                                        stretch_history=stretch_history)
    entries = [dict(c, coef=0.0) for c in candidates]
    if "offset" not in [str(c["kind"]) for c in entries]:
        entries.append({"name": "offset", "kind": "offset", "params": {}, "coef": 0.0})
    kinds = [str(c["kind"]) for c in entries]
    return _Candidates(entries, [str(c["name"]) for c in entries], kinds,
                       kinds.index("offset"), [j for j, k in enumerate(kinds) if k == "baseline"])


@dataclass
class _Rows:
    """The loop's rows: the fit rows (cross-validation folds) and the held-out rows."""

    series: list[Series]
    val_series: list[Series]
    g_fit: np.ndarray
    e_fit: np.ndarray
    fold: np.ndarray
    n_folds: int
    e_out: np.ndarray
    g_out: np.ndarray
    t_out: np.ndarray
    s_out: np.ndarray


def _rows(sensor: str, series: list[Series], validate: list[Mapping[str, Recording]] | None,
          base_val: list[dict[str, Run]], entries: list[dict[str, Any]], n_blocks: int,
          period: int, val_stride: int) -> _Rows:
    """Fit rows (not held out, within the range the terms read) with their fold (the
    position of the block among the fit blocks of its recording), and the held-out rows:
    the validation recordings', or every ``period``-th block's without them."""
    held_out = [(s.block % period == period - 1) if period else np.zeros(s.e.size, bool)
                for s in series]
    fold_of_block = np.cumsum([not (period and b % period == period - 1)
                               for b in range(n_blocks)]) - 1
    fits = [~h & ~s.extended for s, h in zip(series, held_out, strict=True)]
    e_fit = np.concatenate([s.e[f] for s, f in zip(series, fits, strict=True)])
    g_fit = np.concatenate([s.g[f] for s, f in zip(series, fits, strict=True)])
    fold = np.concatenate([fold_of_block[s.block[f]]
                           for s, f in zip(series, fits, strict=True)])
    if validate is not None:
        val_series = [s for b, runs in zip(validate, base_val, strict=True) if sensor in b
                      for s in [series_of(sensor, b, runs, entries, n_blocks, val_stride)]
                      if s is not None]
        if not val_series:
            raise InputError(f"sensor {sensor!r}: the validation recordings have no usable "
                             "samples with a reference strain")
        out = [(s.e, s.g, s.t, s.s) for s in val_series]
    else:
        val_series = []
        out = [(s.e[h], s.g[h], s.t[h], s.s[h]) for s, h in zip(series, held_out, strict=True)]
    e_out, g_out, t_out, s_out = (np.concatenate([o[k] for o in out]) for k in range(4))
    return _Rows(series, val_series, g_fit, e_fit, fold, int(fold_of_block.max()) + 1,
                 e_out, g_out, t_out, s_out)


def _choose(gram: Gram, rows: _Rows, cands: _Candidates, scores: dict[int, float],
            margin: float, max_effects: int, held_out: Any, runs: np.ndarray | None,
            session: SessionHeldOut | None) -> Any:
    """Forward selection kept on the held-out rows, and for each baseline candidate the
    per-run hypothesis (the start-of-run shift removed whole) when it wins by ``margin``;
    ``scores`` of the baselines are set here."""
    n, offset, baselines = len(cands.names), cands.offset, cands.baselines
    chosen = select_forward(gram, n, offset, margin, max_effects, skip=baselines)
    best = keep_on_held_out(gram, chosen, None, offset, rows.n_folds, margin, held_out, runs)
    rmse_none = gram.cv_rmse([])
    for b in baselines:
        shifted = Gram(rows.g_fit, rows.e_fit - rows.g_fit[:, b], rows.fold, rows.n_folds)
        rmse_b = shifted.cv_rmse([])
        scores[b] = 1.0 - (rmse_b / rmse_none) ** 2 if rmse_none > 0 else 0.0
        if session is not None:  # the session start re-zeroes every run itself (step 8)
            continue
        selection = select_forward(shifted, n, offset, margin, max_effects - 1,
                                   auto_intercept=False, skip=baselines)
        selection.gains = {b: 1.0 - rmse_b / rmse_none if rmse_none > 0 else 0.0,
                           **selection.gains}
        branch = keep_on_held_out(shifted, selection, b, offset, rows.n_folds, margin,
                                  held_out, runs)
        if branch.shift is not None and branch.rmse < (1.0 - margin) * best.rmse:
            best = branch
    return best


def _score_rows(sensor: str, cal: SensorCalibration, cands: _Candidates, rows: _Rows,
                scores: dict[int, float], terms: list[int], coefs: list[float],
                gains: Mapping[int, float]) -> list[EffectScore]:
    """The evidence of every candidate: its score and, for an added one, its rank, gain,
    coefficient and magnitude."""
    std_fit = np.std(rows.g_fit, axis=0)
    coef_of = dict(zip(terms, coefs, strict=True))
    vr = cal.valid_range
    found = []
    for j, name in enumerate(cands.names):
        row = EffectScore(sensor=sensor, name=name, kind=cands.kinds[j],
                          params=regressor_from_dict(cands.entries[j]).params(),
                          score=scores[j], unit=cal.strain_unit, span=vr.s_hi - vr.s_lo)
        if j in coef_of:
            row.added = True
            row.rank = terms.index(j)
            row.gain = gains.get(j)
            row.coef = float(coef_of[j])
            row.magnitude = float(abs(coef_of[j]) * (std_fit[j] if j != cands.offset else 1.0))
            if cands.kinds[j] == "baseline":
                row.magnitude = float(np.sqrt(np.mean(rows.g_out[:, j] ** 2)))
            row.lag = _lags(cands, rows, j, row.coef)
        found.append(row)
    return found


def _lags(cands: _Candidates, rows: _Rows, j: int, coef: float) -> bool | None:
    """Does creep term ``j`` (``report.creep_tau``) stand for an estimate that lags the
    reference after a change? Its correction coef g set against the same time constant's
    state of the estimate (S_hat minus its low-pass, positive after a rise of the strain):
    of opposite sign on the fit rows, the estimate stays behind. None: not a creep term, or
    no such state among the candidates."""
    tau = creep_tau(cands.kinds[j], cands.entries[j].get("params", {}))
    if tau is None:
        return None
    if cands.kinds[j] == "relaxation":
        return coef < 0
    for k, entry in enumerate(cands.entries):
        if cands.kinds[k] == "relaxation" and creep_tau("relaxation", entry.get("params", {})) \
                == tau:
            h, g = rows.g_fit[:, k], coef * rows.g_fit[:, j]
            if np.std(h) > 0 and np.std(g) > 0:
                return bool(np.corrcoef(h, g)[0, 1] < 0)
    return None


def _message(cal: SensorCalibration, cands: _Candidates, rows: _Rows, best: Any,
             scores: dict[int, float], order: list[int], gains: Mapping[int, float],
             margin: float, before: float, after: float, session: bool,
             strides: tuple[int, int | None]) -> str:
    """The loop's finding for one sensor, in words."""
    names = cands.names
    if not order:
        top = max((j for j in scores if j not in cands.baselines), key=scores.__getitem__)
        message = (f"no candidate effect lowers the held-out error by more than "
                   f"{100 * margin:.0f} %; nothing added (best: {names[top]}, "
                   f"score {scores[top]:.3f})")
        if best.selection.chosen:
            message = (f"{names[best.selection.chosen[0]]} looked useful in cross-validation "
                       "but did not lower the held-out error; nothing added")
        if session:
            chosen = best.selection.chosen
            why = (f"{names[chosen[0]]}, useful in cross-validation on the diagnosed run, "
                   "does not carry to them" if chosen else
                   f"no candidate explains it (best in cross-validation: {names[top]}, "
                   f"score {scores[top]:.3f})")
            if chosen and all(_gain_or_offset(cands, j) for j in chosen):
                why = ("what helped on the diagnosed run is an output gain or offset, which "
                       "the session start makes itself")
            message = (f"after the session start, what remains on the validation runs is "
                       f"{before:.4g} {cal.strain_unit} (as calibrated {rms(rows.e_out):.4g}) "
                       f"and {why}: nothing added")
    else:
        parts = ", ".join(f"{names[j]} ({_family(cands, j)}gain {gains[j]:.1%})"
                          for j in order if j in gains)
        message = (f"added {parts}; held-out RMSE {before:.4g} -> {after:.4g} "
                   f"{cal.strain_unit}"
                   + ("" if not session else " after the session-start recalibration"))
    left_out = [x.unsettled for x in [*rows.series, *rows.val_series] if x.unsettled[0] > 0]
    if left_out:
        seconds, drift = left_out[0]
        others = (f" (and the start of {len(left_out) - 1} more runs)" if len(left_out) > 1
                  else "")
        message += (f"; the first {seconds:.0f} s{others}, before the reference first moves, "
                    f"are left out: the resistance still relaxes there from an earlier "
                    f"stretch ({100 * drift:+.2f} % over {TARE_WINDOW:g} s)")
    stride, val_stride = strides
    if stride > 1 or (val_stride or 1) > 1:
        message += (f"; fitted and scored on every {stride}-th sample"
                    + (f" (validation: every {val_stride}-th)" if val_stride is not None
                       else "")
                    + f" of a run longer than {ROW_BUDGET:,} samples")
    return message


def _gain_or_offset(cands: _Candidates, j: int) -> bool:
    """Is candidate ``j`` an output offset or a plain gain (what the session start makes)?"""
    return cands.kinds[j] == "offset" or (
        cands.kinds[j] == "strain_level" and cands.entries[j].get("params", {}).get("power", 1)
        == 1)


def _family(cands: _Candidates, j: int) -> str:
    """``creep, tau X s, `` for a creep term (its family named in the message), else ``""``."""
    tau = creep_tau(cands.kinds[j], cands.entries[j].get("params", {}))
    return "" if tau is None else f"creep, tau {tau:g} s, "


def _diagnose_sensor(sensor: str, calibration: Calibration,
                     bags: list[Mapping[str, Recording]],
                     validate: list[Mapping[str, Recording]] | None,
                     base_fit: list[dict[str, Run]], base_val: list[dict[str, Run]],
                     candidates: Sequence[dict[str, Any]] | None, holdout_fraction: float,
                     n_blocks: int, margin: float, max_effects: int,
                     stretch_history: bool = False, session_start: bool = True,
                     ) -> SensorDiagnosis | None:
    """One sensor's loop (module docstring)."""
    cal = calibration.sensors[sensor]
    cands = _candidates(sensor, bags, base_fit, candidates, stretch_history)
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
    rows = _rows(sensor, series, validate, base_val, cands.entries, n_blocks, period,
                 val_stride)
    gram = Gram(rows.g_fit, rows.e_fit, rows.fold, rows.n_folds)
    scores = candidate_scores(gram, len(cands.names), cands.offset)
    linear = linear_held_out(rows.e_out, rows.g_out)
    held_out = linear if session is None else session
    runs = None  # the validation run of each held-out sample
    if session is not None:
        runs = session.runs_of_samples()
    elif rows.val_series:
        runs = np.concatenate([np.full(s.e.size, k) for k, s in enumerate(rows.val_series)])
    best = _choose(gram, rows, cands, scores, margin, max_effects, held_out, runs, session)
    e_before = held_out([], np.zeros(0))
    rmse_before = rms(e_before)
    terms = ([best.shift] if best.shift is not None and best.rmse < rmse_before else []) \
        + best.kept
    coefs = ([1.0] if terms[:1] == [best.shift] else []) + list(best.coef)
    if session is not None:  # what the session start makes itself is not written
        kept = [k for k, j in enumerate(terms) if not session.redundant(j)]
        terms, coefs = [terms[k] for k in kept], [coefs[k] for k in kept]
    gains = best.selection.gains
    e_after = held_out(terms, np.array(coefs))
    order = [j for j in terms if j != cands.offset] or terms
    message = _message(cal, cands, rows, best, scores, order, gains, margin, rmse_before,
                       rms(e_after), session is not None,
                       (stride, val_stride if validate is not None else None))
    e_linear = linear(terms, np.array(coefs))
    winner = cands.names[order[0]] if order else None
    plot = {}
    if winner is not None:
        plot = {"t": rows.t_out, "e_before": rows.e_out, "e_after": e_linear,
                "g": rows.g_out[:, order[0]], "s": rows.s_out}
    found = SensorDiagnosis(
        name=sensor, before=rmse_stats(e_before), after=rmse_stats(e_after),
        scores=_score_rows(sensor, cal, cands, rows, scores, terms, coefs, gains),
        added=added_effects(cands.entries, terms, coefs, cal.effects), message=message,
        plot=plot, winner=winner)
    if session is not None:
        found.as_calibrated = {"before": rmse_stats(rows.e_out), "after": rmse_stats(e_linear)}
        found.session = _session_record(cal, session, rows.e_out, e_before, margin)
    return found


def _session_record(cal: SensorCalibration, session: SessionHeldOut, e_raw: np.ndarray,
                    e_start: np.ndarray, margin: float) -> dict[str, Any]:
    """What the session start did on the validation runs, and the gain change between runs
    it shows: the sensitivity against the calibration (the input span gain k: the sensor
    reads 1 / k - 1 more) where it is at least ``GAIN_CHANGE`` and the session start lowers
    the validation error by more than ``margin``."""
    starts = session.starts()
    spans = [s.calibration.sensors[session.sensor].input.zero_span for s in starts]
    changes = [100.0 * (1.0 / span[2] - 1.0) for span, s in zip(spans, starts, strict=True)
               if span is not None and "input" in s.steps]
    before, after = rms(e_raw), rms(e_start)
    shown = bool(changes) and max(abs(c) for c in changes) >= 100.0 * GAIN_CHANGE \
        and after < (1.0 - margin) * before
    seconds = ", ".join(f"{seconds:.3g}" for _, seconds in session.runs)
    first = session.runs[0][1]
    u = strain_unit_words(cal.strain_unit)
    made = "; ".join(line.split(" (from ")[0].removeprefix(f"{session.sensor}: ")
                     for s in starts for line in s.lines)
    reading = (f"{session.sensor}: session start on the first {seconds} s of the validation "
               f"run ({made}); validation RMSE before the loop {before:.4g} -> {after:.4g} {u}"
               f"; {_remains(before, after, u)}")
    if shown:
        reading = (f"{session.sensor}: sensitivity differs from the calibration by "
                   + ", ".join(f"{c:+.1f} %" for c in changes) + " on the validation run: "
                   f"recalibrate --input --from RUN --first {first:.3g}, then recalibrate "
                   f"--from RUN --first {first:.3g} (its first load and unload), at the start "
                   "of each session; " + reading)
    return {"name": SESSION_RECORDS[1] if shown else SESSION_RECORDS[0],
            "reading": reading, "before": before, "after": after, "chosen": False,
            "sensitivity_change": changes, "seconds": [s for _, s in session.runs],
            "steps": [s.steps for s in starts]}


def _remains(before: float, after: float, unit_words: str) -> str:
    """One line on what the session start leaves: the share of the validation runs' squared
    error that was their own gain and offset (their input space), which no term need make."""
    if not before > 0 or not after < before:
        return (f"after the session start, what remains is all of the error and more ("
                f"{before:.4g} -> {after:.4g} {unit_words}): the runs' own gain and offset are "
                "not what the calibration lacks")
    share = 1.0 - (after / before) ** 2
    return (f"after the session start, what remains is {after:.4g} of {before:.4g} "
            f"{unit_words}: {100 * share:.0f} % of the squared error was each run's own gain "
            "and offset, which the session start removes and no term need make")


def diagnose(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]],
             calibration: Calibration, *,
             validate_recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             | None = None, holdout_fraction: float = 0.3,
             candidates: Sequence[dict[str, Any]] | None = None, n_blocks: int = 10,
             margin: float = 0.03, max_effects: int = 3,
             tare: str = "calibration", stretch_history: bool = False,
             session_start: bool = True,
             on_sensor: Callable[[str], None] | None = None) -> DiagnoseResult:
    """Run the residual loop (module docstring) on every calibrated sensor with a reference.

    ``recordings``: one bag's recordings by sensor name, or a list of such (several bags).
    ``candidates``: effect dicts to test instead of ``default_candidates`` (with the
    ``stretch`` terms when ``stretch_history``). ``margin``: the
    least relative drop of the cross-validated RMSE for an effect to be added. ``tare``:
    ``calibration`` or ``auto`` (every run, fit and validation alike, tared at its start).
    ``session_start``: with validation recordings, measure before and after on them after
    the session-start recalibration on their first cycle (``strain_comp.diagnosis.session``;
    a run where it cannot be made is measured as calibrated). ``on_sensor``: called with
    each sensor's name once it is done.
    """
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
        found = _diagnose_sensor(sensor, calibration, bags, validate, base_fit, base_val or [],
                                 candidates, holdout_fraction, n_blocks, margin, max_effects,
                                 stretch_history, session_start)
        if found is not None:
            results[sensor] = found
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
                "--input --from RUN --first SECONDS, then recalibrate --from RUN --first "
                "SECONDS, on its first load and unload")
    return DiagnoseResult(sensors=results, before=pooled_before, after=pooled_after,
                          validated_on=validated_on, validation=validation,
                          calibration=Calibration(sensors_out))


def _pool(results: Mapping[str, SensorDiagnosis], which: str) -> dict[str, float]:
    """RMSE and MAE pooled over every sensor's held-out samples."""
    n = sum(getattr(d, which)["n"] for d in results.values())
    sse = sum(getattr(d, which)["rmse"] ** 2 * getattr(d, which)["n"] for d in results.values())
    sae = sum(getattr(d, which)["mae"] * getattr(d, which)["n"] for d in results.values())
    return {"rmse": math.sqrt(sse / n), "mae": sae / n, "n": n}
