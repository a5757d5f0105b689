"""The residual loop's findings for one sensor, in words and records: every candidate's
evidence, the message, and what the session start did on the validation runs."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from strain_comp.core.calibration import SensorCalibration, strain_unit_words
from strain_comp.core.effects import regressor_from_dict
from strain_comp.core.tare import REST_WINDOW
from strain_comp.diagnosis.report import SESSION_RECORDS, EffectScore, creep_tau
from strain_comp.diagnosis.residuals import ROW_BUDGET, Candidates, Rows
from strain_comp.diagnosis.selection import Tried, column_std, rms
from strain_comp.diagnosis.session import SessionHeldOut, window_flag

GAIN_CHANGE = 0.05
"""A session start's input span this far from 1, which it corrects: a gain change between runs."""


def score_rows(sensor: str, cal: SensorCalibration, cands: Candidates, rows: Rows,
                scores: dict[int, float], terms: list[int], coefs: np.ndarray,
                gains: Mapping[int, float]) -> list[EffectScore]:
    """Every candidate's score and, for an added one, its rank, gain, coefficient and size."""
    std_fit = column_std(rows.g_fit)
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
            row.lag = lags(cands, rows, j, row.coef)
        found.append(row)
    return found


def lags(cands: Candidates, rows: Rows, j: int, coef: float) -> bool | None:
    """Does creep term ``j`` stand for an estimate that lags the reference after a change?"""
    # it does where its correction runs against the same tau's state of the estimate
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


def message_of(cal: SensorCalibration, cands: Candidates, rows: Rows, chosen: list[int],
               refused: Tried | None, scores: dict[int, float], order: list[int],
               gains: Mapping[int, float], margin: float, before: float, after: float,
               session: bool, strides: tuple[int, int | None]) -> str:
    """The loop's finding for one sensor, in words."""
    names = cands.names
    if not order:
        top = max((j for j in scores if j not in cands.baselines), key=scores.__getitem__)
        message = (f"no candidate effect lowers the held-out error by more than "
                   f"{100 * margin:.0f} %; nothing added (best: {names[top]}, "
                   f"score {scores[top]:.3f})")
        if chosen:
            message = (f"{names[chosen[0]]} looked useful in cross-validation "
                       "but did not lower the held-out error; nothing added")
        if session:
            message = (f"after the session start, what remains on the validation runs is "
                       f"{before:.4g} {cal.strain_unit} (as calibrated {rms(rows.e_out):.4g}) "
                       f"and {not_carried(cands, scores, refused, margin)}: "
                       "nothing added")
    else:
        parts = ", ".join(f"{names[j]} ({family(cands, j)}gain {gains[j]:.1%})"
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
                    f"stretch ({100 * drift:+.2f} % over {REST_WINDOW:g} s)")
    stride, val_stride = strides
    if stride > 1 or (val_stride or 1) > 1:
        message += (f"; fitted and scored on every {stride}-th sample"
                    + (f" (validation: every {val_stride}-th)" if val_stride is not None
                       else "")
                    + f" of a run longer than {ROW_BUDGET:,} samples")
    return message


def not_carried(cands: Candidates, scores: dict[int, float], refused: Tried | None,
                margin: float) -> str:
    """Why no term is added after the session start, in one clause."""
    if refused is None:
        top = max((j for j in scores if j not in cands.baselines and j != cands.offset),
                  key=scores.__getitem__)
        return (f"no candidate explains it (best in cross-validation: {cands.names[top]}, "
                f"score {scores[top]:.3f})")
    first = 100.0 * (math.exp(refused.fit_ratio) - 1.0)
    changes = ", ".join(f"{100.0 * (math.exp(x) - 1.0):+.0f} %" for x in refused.log_ratios)
    if len(refused.log_ratios) < 2:
        return (f"{cands.names[refused.column]} ({first:+.0f} % on the diagnosed run, "
                f"{changes} on the validation run) cannot be told from the spread between "
                "runs with one validation run (give two or more)")
    return (f"{cands.names[refused.column]} ({first:+.0f} % on the diagnosed run) changes "
            f"them by {changes}: not {100 * margin:.0f} % lower beyond the spread between "
            f"runs; {instead(refused.log_ratios, margin)}")


def instead(log_ratios: list[float], margin: float) -> str:
    """Why a term fitted on the diagnosed run does not carry, and what to record instead."""
    low = math.log(1.0 - margin)
    if all(x < low for x in log_ratios):
        return ("the validation runs disagree on how much it lowers them: record more "
                "validation runs (diagnose --validate RUN1 RUN2 RUN3 ...)")
    which = ("between the validation runs" if any(x < low for x in log_ratios)
             else "from the diagnosed run's on every validation run")
    return (f"the change differs {which}, so no term fitted on one run carries it: record "
            "known strains during the run (evaluate --references-every SECONDS)")


def family(cands: Candidates, j: int) -> str:
    """``creep, tau X s, `` for a creep term, else ``""``."""
    tau = creep_tau(cands.kinds[j], cands.entries[j].get("params", {}))
    return "" if tau is None else f"creep, tau {tau:g} s, "


def session_record(cal: SensorCalibration, session: SessionHeldOut, e_raw: np.ndarray,
                    e_start: np.ndarray, margin: float) -> dict[str, Any]:
    """What the session start did on the validation runs, and the gain change it shows."""
    starts = session.starts
    spans = [s.calibration.sensors[session.sensor].input.zero_span for s in starts]
    # the input span gain k: the sensor reads 1 / k - 1 more
    changes = [100.0 * (1.0 / span[2] - 1.0) for span, s in zip(spans, starts, strict=True)
               if span is not None and "input" in s.steps]
    before, after = rms(e_raw), rms(e_start)
    shown = bool(changes) and max(abs(c) for c in changes) >= 100.0 * GAIN_CHANGE \
        and after < (1.0 - margin) * before
    read = ", ".join(window_flag(s.window) for s in starts)
    u = strain_unit_words(cal.strain_unit)
    made = "; ".join(line.removeprefix(f"{session.sensor}: ")
                     for s in starts for line in [*s.lines(), *s.notes])
    reading = (f"{session.sensor}: session start on the validation run ({read}: {made}); "
               f"validation RMSE before the loop {before:.4g} -> {after:.4g} {u}"
               f"; {remains(before, after, u)}")
    if shown:
        window = next(s.window for s in starts if s.window is not None)
        which = ("its first load and unload" if window[0] == 0.0
                 else "a warm-up load and unload, then the next one")
        reading = (f"{session.sensor}: sensitivity differs from the calibration by "
                   + ", ".join(f"{c:+.1f} %" for c in changes) + " on the validation run: "
                   f"strain-comp start CAL.yaml RUN --out TODAY.yaml at the start of each "
                   f"session (here it read {which}, {window_flag(window)}); " + reading)
    return {"name": SESSION_RECORDS[1] if shown else SESSION_RECORDS[0],
            "reading": reading, "before": before, "after": after, "chosen": False,
            "sensitivity_change": changes,
            "windows": [None if s.window is None else list(s.window) for s in starts],
            "steps": [s.steps for s in starts]}


def remains(before: float, after: float, unit_words: str) -> str:
    """What the session start leaves: the share of the error that was each run's gain and offset."""
    if not before > 0 or not after < before:
        return (f"after the session start, what remains is all of the error and more ("
                f"{before:.4g} -> {after:.4g} {unit_words}): the runs' own gain and offset are "
                "not what the calibration lacks")
    share = 1.0 - (after / before) ** 2
    return (f"after the session start, what remains is {after:.4g} of {before:.4g} "
            f"{unit_words}: {100 * share:.0f} % of the squared error was each run's own gain "
            "and offset, which the session start removes and no term need make")

