"""The model chosen by leaving runs out (``fit A B C ... --model auto``; docs/design.md): the
lowest median RMSE after a start on each run (or group) left out, a simpler one within ``TIE``
before it; with one run or group, ``ONE_RUN_ORDER`` decides.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.errors import FitError, InputError, StrainCompError
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import Fitter, fit_sensor
from strain_comp.offline.options import (
    DIRECTION_OPTIONS,
    FIT_OPTIONS,
    check_fit_options,
    model_options,
)
from strain_comp.offline.session_start import start_or_keep
from strain_comp.offline.uncertainty import learn

if TYPE_CHECKING:
    from pathlib import Path

    from strain_comp.io.recording import Recording

CANDIDATES = ("cubic", "mpi", "apl", "creep_pi")
"""The models ``--model auto`` tries unless ``--candidates`` says otherwise."""
SIMPLER = ("cubic", "mpi", "creep_pi", "apl", "pl", "sinh_pl", "rational", "spike_decay")
"""Simplest first (a tie goes to the earlier)."""
TIE = 0.02
"""Medians within this share of the lowest are a tie, won by the simpler model."""
ONE_RUN_ORDER = ("apl", "mpi", "creep_pi", "cubic")
"""With one run or group, the first of these among the candidates (docs/results.md, ``pair``)."""


@dataclass(frozen=True)
class Fold:
    """One candidate fitted on all groups but one and scored on that group's runs."""

    model: str
    held: tuple[int, ...]
    """The indices of the runs left out."""


@dataclass(frozen=True)
class Scored:
    """A fold's RMSE on each run left out and its calibration started on each."""

    errors: list[float]
    started: list[Calibration]


def parse_candidates(text: str | Sequence[str] | None) -> tuple[str, ...]:
    """``--candidates cubic,apl`` -> the models; ``CANDIDATES`` for None."""
    if text is None:
        return CANDIDATES
    names = [n.strip() for n in (text.split(",") if isinstance(text, str) else text)]
    names = list(dict.fromkeys(n for n in names if n))
    bad = [n for n in names if n not in MODEL_NAMES]
    if bad or not names:
        raise InputError(f"--candidates {','.join(bad) or text!r}: expected models from "
                         f"{', '.join(MODEL_NAMES)}, comma-separated")
    return tuple(names)


def parse_groups(text: str | Sequence[Any] | None, runs: int) -> list[str] | None:
    """``--groups 1,1,1,2,2`` -> one label per run; None for None."""
    if text is None:
        return None
    labels = [str(x).strip() for x in (text.split(",") if isinstance(text, str) else text)]
    if len(labels) != runs or not all(labels):
        raise InputError(f"--groups {text if isinstance(text, str) else ','.join(labels)!r}: "
                         f"expected one label per run ({runs} runs), e.g. "
                         f"{','.join(['1'] * max(runs - 1, 1) + ['2'])}")
    return labels


def _takes(model: str, key: str) -> bool:
    """Whether ``model``'s fit takes the option ``key``."""
    return key in model_options(model) or key in DIRECTION_OPTIONS or key in FIT_OPTIONS


def check_auto_options(candidates: Sequence[str], options: Mapping[str, Any]) -> None:
    """Every option must be one some candidate takes (each gets only its own)."""
    for key, value in options.items():
        takers = [m for m in candidates if _takes(m, key)]
        if not takers:
            raise InputError(f"--option {key}: no candidate model takes it "
                             f"(candidates: {', '.join(candidates)})")
        check_fit_options(takers[0], {key: value})


def options_of(model: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The options ``model`` takes of ``options`` (no grid lines of an APL-family fit)."""
    out = {k: v for k, v in options.items() if _takes(model, k)}
    if "progress" in model_options(model):
        out["progress"] = False
    return out


def fold_errors(recordings: Sequence[Recording], name: str, fold: Fold,
                options: Mapping[str, Any], pool: str) -> Scored | str:
    """``fold.model`` fitted on the other runs and started on each left out, or why not."""
    rest = [rec for i, rec in enumerate(recordings) if i not in fold.held]
    try:
        cal = fit_sensor(rest, fold.model, name=name, options=options_of(fold.model, options),
                         pool=pool)
    except StrainCompError as err:
        return str(err)
    out = Scored([], [])
    for i in fold.held:
        held = {name: recordings[i]}
        started = start_or_keep(Calibration({name: cal}), held).calibration
        out.started.append(started)
        try:
            ev = evaluate_recordings(held, started, tare="calibration").sensors[name]
            out.errors.append(float(ev.stats.rmse))
        except StrainCompError:
            out.errors.append(float("nan"))
    return out


def _cell(model: str, folds: Sequence[Fold], results: Sequence[Scored | str],
          runs: int) -> dict[str, Any]:
    """A candidate's row of the table: its median, worst and errors, or why it failed."""
    errors = np.full(runs, np.nan)
    failed = None
    for fold, result in zip(folds, results, strict=True):
        if fold.model != model:
            continue
        if isinstance(result, str):
            failed = failed or result
        else:
            errors[list(fold.held)] = result.errors
    if failed is not None or not np.isfinite(errors).all():
        return {"failed": failed or "no score on a run left out"}
    return {"median": round(float(np.median(errors)), 6),
            "worst": round(float(np.max(errors)), 6),
            "errors": [round(float(e), 6) for e in errors]}


def choose_model(recordings: Sequence[Recording], name: str, *,
                 candidates: Sequence[str] = CANDIDATES, groups: Sequence[str] | None = None,
                 options: Mapping[str, Any] | None = None, pool: str = "spanned", jobs: int = 1,
                 ) -> tuple[str, dict[str, Any], list[tuple[Calibration, dict[str, Recording]]]]:
    """The model of ``--model auto``, its record, and its folds started on each run left out
    (the pairs ``uncertainty.learn`` takes)."""
    options = dict(options or {})
    labels = list(groups) if groups is not None else [str(i) for i in range(len(recordings))]
    held = [tuple(i for i, g in enumerate(labels) if g == label)
            for label in dict.fromkeys(labels)]
    if len(held) < 2:
        model = next((m for m in ONE_RUN_ORDER if m in candidates), candidates[0])
        why = (f"one {'group' if groups is not None and len(recordings) > 1 else 'run'}: "
               f"nothing to leave out, so {model}, the candidate that carried best from one "
               "run to another on the benchmark (docs/results.md)")
        return model, {"chosen": model, "why": why}, []
    folds = [Fold(m, h) for m in candidates for h in held]
    tasks = [(recordings, name, fold, options, pool) for fold in folds]
    if jobs > 1:
        with ProcessPoolExecutor(min(jobs, len(tasks)),
                                 mp_context=get_context("spawn")) as workers:
            results = list(workers.map(fold_errors, *zip(*tasks, strict=True)))
    else:
        results = [fold_errors(*task) for task in tasks]
    table = {model: _cell(model, folds, results, len(recordings)) for model in candidates}
    scored = {m: c for m, c in table.items() if "median" in c}
    if not scored:
        reasons = "; ".join(f"{m}: {c['failed']}" for m, c in table.items())
        raise FitError(f"sensor {name!r}: --model auto: no candidate could be fitted and "
                       f"scored on the runs left out ({reasons})")
    best = min(c["median"] for c in scored.values())
    tied = [m for m, c in scored.items() if c["median"] <= (1.0 + TIE) * best]
    chosen = min(tied, key=lambda m: SIMPLER.index(m) if m in SIMPLER else len(SIMPLER))
    lowest = min(scored, key=lambda m: scored[m]["median"])
    why = (f"the lowest median RMSE over the runs left out ({scored[chosen]['median']:.4g})"
           if chosen == lowest else
           f"within {TIE:.0%} of the lowest median ({lowest} {best:.4g}), and simpler")
    pairs = [(started, {name: recordings[i]}) for fold, result in zip(folds, results,
                                                                      strict=True)
             if fold.model == chosen and not isinstance(result, str)
             for i, started in zip(fold.held, result.started, strict=True)]
    return chosen, {"chosen": chosen, "why": why, "tie": TIE, "candidates": table,
                    "groups": labels if groups is not None else None,
                    "expected": {"median": scored[chosen]["median"],
                                 "worst": scored[chosen]["worst"],
                                 "runs": len(recordings)}}, pairs


def fit_auto(recordings: Sequence[Recording], *, name: str, bags: Sequence[str | Path] = (),
             options: Mapping[str, Any] | None = None, pool: str = "spanned",
             candidates: Sequence[str] = CANDIDATES, groups: Sequence[str] | None = None,
             jobs: int = 1, index: Sequence[int] | None = None) -> SensorCalibration:
    """``choose_model``'s model fitted on every run, with its record and uncertainty;
    ``index``: which input each run is, for ``groups`` given per input."""
    if groups is not None and index is not None:
        groups = [groups[i] for i in index]
    model, record, pairs = choose_model(recordings, name, candidates=candidates,
                                        groups=groups, options=options, pool=pool, jobs=jobs)
    cal = fit_sensor(recordings, model, name=name, bags=bags,
                     options=options_of(model, options or {}), pool=pool)
    if not pairs and len(recordings) > 1:  # one group: the band from each run left out
        for j in range(len(recordings)):
            scored = fold_errors(recordings, name, Fold(model, (j,)), options or {}, pool)
            if not isinstance(scored, str):
                pairs.append((scored.started[0], {name: recordings[j]}))
    if pairs:
        cal.uncertainty = learn(pairs).get(name)
    expected = record.pop("expected", None)
    cal.provenance["model_choice"] = record
    if expected is not None:
        cal.provenance["expected_error"] = {**expected, "unit": cal.strain_unit,
                                            "model": model}
    return cal


def auto_fitter(candidates: Sequence[str] = CANDIDATES, groups: Sequence[str] | None = None,
                jobs: int = 1) -> Fitter:
    """``fit_auto`` as ``fit_runs``' ``fitter`` (``fit --model auto``)."""
    return functools.partial(fit_auto, candidates=candidates, groups=groups, jobs=jobs)
