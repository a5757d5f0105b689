"""Fitting: recordings with a reference strain -> calibration (``fit_sensor`` one sensor,
``fit_runs`` / ``fit_bags`` every named one), the training data screened and cut as the engine
does, several runs pooled (``fit --pool``; docs/results.md "Pooling and the session start")."""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from itertools import pairwise
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from strain_comp.base.compensator import Compensator
from strain_comp.base.samples import DEFAULT_GAP_RESET, GAP_INTERVALS, gap_for, good_mask
from strain_comp.core.calibration import (
    PARAM_MAX,
    STRAIN_MAX,
    Calibration,
    InputSettings,
    SensorCalibration,
    ValidRange,
    check_reference,
    provenance,
)
from strain_comp.core.calibration_file import check_calibration
from strain_comp.core.chain import pair_values
from strain_comp.core.engine import Engine
from strain_comp.core.metrics import error_stats
from strain_comp.core.tare import rest_resistance_from_reference
from strain_comp.errors import CalibrationError, FitError, InputError, StrainCompError
from strain_comp.io.recording import load_recordings
from strain_comp.models import MODEL_NAMES, Normalisation, Segment, model_class
from strain_comp.offline.deadzone import direction_settings, resistance_sign
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.evaluation import EvaluationResult
from strain_comp.offline.input_chain import input_chain
from strain_comp.offline.options import (
    DIRECTION_OPTIONS,
    FIT_OPTIONS,
    check_fit_options,
    model_options,
)
from strain_comp.offline.reduce import FIT_SAMPLE_BUDGET, reduce_segments
from strain_comp.offline.session_start import (
    Line,
    calibration_stretch,
    choose_space,
    cut,
    run_line,
    started_error,
)
from strain_comp.offline.uncertainty import learn

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

Fitter = Callable[..., SensorCalibration]
"""``fit_auto`` with its choice bound (``auto_fitter``), as ``fit_runs`` calls it."""

CHOICE_RUNS = 3
"""Runs a pooled fit needs to choose its session start: each fold a pooled fit of two."""
_OWN_OPTIONS = (*DIRECTION_OPTIONS, *FIT_OPTIONS)
"""Options ``fit_sensor`` takes itself; the others go to the model's ``fit``."""


MIN_SEGMENT = 8
"""Segments with fewer good samples are not used for fitting."""
MIN_SPAN = 1e-9
"""Smallest span of the training resistance [ohm] and strain (a finer one: LAPACK fails)."""
TRAINING_WIDENING = 0.05
"""Valid range = training range widened by this fraction of its span on each side."""


def split_segments(t: np.ndarray, r: np.ndarray, s: np.ndarray, *,
                   gap: float = DEFAULT_GAP_RESET) -> list[Segment]:
    """Good, referenced samples cut where the time steps back or forward by over ``gap``."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    keep = good_mask(t, r) & np.isfinite(s)
    t, r, s = t[keep], r[keep], s[keep]
    if t.size < 2:
        return []
    step = np.diff(t)
    cuts = np.flatnonzero((step > gap) | (step < 0.0)) + 1
    bounds = np.concatenate(([0], cuts, [t.size]))
    return [Segment(t[a:b], r[a:b], s[a:b]) for a, b in pairwise(bounds)
            if b - a >= MIN_SEGMENT]


def training_segments(recordings: Sequence[Recording], name: str,
                      interval: float | None) -> list[Segment]:
    """Every recording's segments (``split_segments``, the gap of ``interval``)."""
    segments: list[Segment] = []
    for rec in recordings:
        if rec.s is None:
            raise FitError(f"sensor {name!r}: recording has no strain_reference to fit to")
        segments.extend(split_segments(rec.t, rec.r, rec.s, gap=gap_for(interval)))
    if not segments:
        raise FitError(f"sensor {name!r}: no stretch of {MIN_SEGMENT} or more good samples "
                       "with a finite reference strain")
    return segments


def check_training_span(segments: Sequence[Segment], name: str) -> None:
    """Check that the training data can be fitted in float64."""
    r_all = np.concatenate([seg.r for seg in segments])
    s_all = np.concatenate([seg.s for seg in segments])
    if not (np.ptp(r_all) > 0 and np.ptp(s_all) > 0):
        raise FitError(f"sensor {name!r}: the training data span no range of resistance "
                       "or strain")
    check_reference(name, s_all, FitError)
    span = valid_range(r_all, s_all)
    if not max(abs(span.s_lo), abs(span.s_hi)) <= STRAIN_MAX:  # widened beyond it
        raise FitError(f"sensor {name!r}: the reference strain spans {s_all.min():.4g} to "
                       f"{s_all.max():.4g}, beyond the +/- {STRAIN_MAX:g} a calibration "
                       "holds once widened; import it in a larger unit (microstrain to %: "
                       "import-csv --scales strain=1e-4)")
    for what, values, top in (("resistance", r_all, PARAM_MAX), ("strain", s_all, STRAIN_MAX)):
        # a span a float64 fit cannot resolve (1e-300) or values a calibration cannot hold
        if np.ptp(values) < MIN_SPAN or np.abs(values).max() > top:
            raise FitError(f"sensor {name!r}: the training {what} spans "
                           f"[{values.min():.3g}, {values.max():.3g}]: a fit needs a span of "
                           f"at least {MIN_SPAN:g} and values within +/- {top:g} "
                           "(a unit or scale mistake?)")


def valid_range(r: np.ndarray, s: np.ndarray) -> ValidRange:
    """Training range of R and S widened by ``TRAINING_WIDENING`` (R kept > 0)."""
    r_lo, r_hi = float(r.min()), float(r.max())
    s_lo, s_hi = float(s.min()), float(s.max())
    r_pad, s_pad = TRAINING_WIDENING * (r_hi - r_lo), TRAINING_WIDENING * (s_hi - s_lo)
    return ValidRange(max(r_lo - r_pad, 0.5 * r_lo), r_hi + r_pad, s_lo - s_pad, s_hi + s_pad)


def slow_sample_interval(recordings: Sequence[Recording]) -> float | None:
    """The median interval between good samples, where a slow instrument's (else None)."""
    steps = [np.diff(np.asarray(rec.t, dtype=np.float64)[good_mask(rec.t, rec.r)])
             for rec in recordings]
    dt = np.concatenate(steps) if steps else np.empty(0)
    dt = dt[dt > 0.0]
    if not dt.size:
        return None
    interval = float(np.median(dt))
    return interval if GAP_INTERVALS * interval > DEFAULT_GAP_RESET else None


def training_rest_resistance(recordings: Sequence[Recording], *, pair: str = "mean",
                             ) -> float | None:
    """The median over the runs of each one's leading rest level, as an automatic tare's."""
    levels = [rest_resistance_from_reference(rec.t, rec.r, rec.s, pair=pair)
              for rec in recordings
              if rec.s is not None]
    found = [level for level in levels if level is not None]
    return float(np.median(found)) if found else None


POOLS = ("spanned", "joint", "stretch", "raw")
"""How ``fit_sensor`` pools several runs (``fit --pool``)."""
POOL_GAIN = 0.7
"""The maps are kept where they lower the pooled cubic's RMSE to this share (``gate``)."""
POOL_DEGREE = 3
"""Degree of the pooled curve of strain on mapped resistance (``joint_maps``): a cubic."""
POOL_SAMPLES = 4000
"""Samples of each run (evenly thinned) the input maps are fitted on."""

Map = tuple[float, float]
"""(z, k) of a run's map R' = R_0,ref + k (R - z)."""
Joint = tuple[list[Map], float]
"""The joint space: each run's map and R_0,ref (``joint_maps``)."""


@dataclass
class Pooled:
    """Training runs as a pooled fit reads them."""

    runs: list[Recording]
    """The runs, mapped (or as recorded)."""
    maps: list[dict[str, float]]
    """Each run's map (``rest``, ``rest_calibrated``, ``span_gain``); empty as recorded."""
    record: dict[str, Any]
    """The provenance's ``pooling``."""
    stretch_line: Line | None = None
    """The line the stretches share (``InputSettings.stretch_line``), for ``stretch``."""


def _thinned(recordings: Sequence[Recording]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each run's good, referenced (R, S), evenly thinned to about ``POOL_SAMPLES``."""
    data = []
    for rec in recordings:
        assert rec.s is not None  # the runs have lines
        ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
        step = max(1, int(ok.sum()) // POOL_SAMPLES)
        data.append((np.asarray(rec.r, dtype=np.float64)[ok][::step],
                     np.asarray(rec.s, dtype=np.float64)[ok][::step]))
    return data


def _misfit(data: Sequence[tuple[np.ndarray, np.ndarray]], maps: Sequence[Map], r_ref: float,
            scale: float | None = None) -> np.ndarray:
    """The pooled cubic of strain on mapped resistance (over ``scale``, else its median) - S."""
    mapped = np.concatenate([r_ref + k * (r - z) for (r, _), (z, k) in zip(data, maps,
                                                                          strict=True)])
    s_all = np.concatenate([s for _, s in data])
    mapped = mapped / (float(np.median(np.abs(mapped))) if scale is None else scale)
    fitted: np.ndarray = np.polyval(np.polyfit(mapped, s_all, POOL_DEGREE), mapped)
    return np.asarray(fitted - s_all, dtype=np.float64)


def curve_rmse(recordings: Sequence[Recording], maps: Sequence[Map], r_ref: float) -> float:
    """RMSE of the pooled cubic of strain on mapped resistance through the mapped runs."""
    return float(np.sqrt(np.mean(_misfit(_thinned(recordings), maps, r_ref) ** 2)))


def joint_maps(recordings: Sequence[Recording]) -> Joint | None:
    """Each run's affine map onto the median-sensitivity run, fitted jointly with a cubic."""
    from scipy.optimize import least_squares

    lines = [run_line(rec.t, rec.r, rec.s) for rec in recordings]
    found = [line for line in lines if line is not None]
    if len(found) < len(lines) or len({np.sign(g) for _, g in found}) > 1:
        return None
    # the run of median sensitivity (the lower middle one of an even count)
    anchor = int(np.argsort([abs(g) for _, g in found])[(len(found) - 1) // 2])
    r0_ref, g_ref = found[anchor]
    data = _thinned(recordings)
    # map of run i: R' = r0_ref + k_i (R - z_i); started on the lines: z = R_0, k = g_ref / g
    start = np.array([v for i, (r0, g) in enumerate(found) if i != anchor
                      for v in (r0, g_ref / g)])
    scale = float(np.median(np.concatenate([np.abs(r) for r, _ in data])))

    def unpack(x: np.ndarray) -> list[Map]:
        pairs = iter(zip(x[::2], x[1::2], strict=True))
        return [(r0_ref, 1.0) if i == anchor else next(pairs) for i in range(len(data))]

    def residual(x: np.ndarray) -> np.ndarray:  # the cubic solved for, given the maps
        return _misfit(data, unpack(x), r0_ref, scale)

    gains = start[1::2]
    lower = np.ravel([(-np.inf, 0.2 * k) for k in gains])
    upper = np.ravel([(np.inf, 5.0 * k) for k in gains])
    fitted = least_squares(residual, start, x_scale=np.ravel([(scale, 1.0)] * gains.size),
                           bounds=(lower, upper), xtol=1e-10)
    x = fitted.x if fitted.success and np.all(np.isfinite(fitted.x)) else start
    return unpack(x), r0_ref


def stretch_space(recordings: Sequence[Recording], maps: Sequence[Map], r_ref: float
                  ) -> Line | None:
    """The line the runs' calibration stretches share once mapped."""
    parts = []
    for rec, (z, k) in zip(recordings, maps, strict=True):
        stretch = None if rec.s is None else calibration_stretch(rec.t, rec.s)
        if stretch is None:
            return None
        part = cut(rec, *stretch)
        parts.append(replace(part, r=r_ref + k * (np.asarray(part.r, dtype=np.float64) - z)))
    line = run_line(np.arange(sum(p.t.size for p in parts), dtype=np.float64),
                    np.concatenate([p.r for p in parts]),
                    np.concatenate([p.s for p in parts if p.s is not None]))
    return line if line is not None and line[0] > 0 else None


def gate(recordings: Sequence[Recording]) -> tuple[dict[str, Any], Joint | None]:
    """The ``joint`` maps where they lower the pooled cubic's RMSE to ``POOL_GAIN`` of it."""
    joint = joint_maps(recordings)
    if joint is None:
        return {"why": "a run has no line, or the runs' lines disagree in sign"}, None
    maps, r_ref = joint
    rmse = {"raw": curve_rmse(recordings, [(r_ref, 1.0)] * len(maps), r_ref),
            "spanned": curve_rmse(recordings, maps, r_ref)}
    reading = {"curve_rmse": {k: round(v, 6) for k, v in rmse.items()}}
    return reading, joint if rmse["spanned"] <= POOL_GAIN * rmse["raw"] else None


def pooled_input(recordings: Sequence[Recording], pool: str, joint: Joint | None = None
                 ) -> Pooled:
    """The runs in one input space (``joint``, ``stretch``) or as recorded (``raw``)."""
    if pool not in POOLS or pool == "spanned":
        raise InputError(f"--pool {pool!r}: expected one of {', '.join(POOLS)}")
    as_recorded = Pooled(list(recordings), [], {"pool": "raw"})
    if pool == "raw" or not recordings or (pool == "joint" and len(recordings) < 2):
        return as_recorded
    if len(recordings) < 2:  # stretch: the run's own stretch line, the run as recorded
        own = stretch_space(recordings, [(0.0, 1.0)], 0.0)
        return replace(as_recorded, record={"pool": "stretch"}, stretch_line=own) \
            if own is not None else as_recorded
    joint = joint if joint is not None else joint_maps(recordings)
    if joint is None:
        return replace(as_recorded, record={"pool": "raw", "why": "no line of resistance on "
                                            "strain, or lines that disagree in sign"})
    maps, r_ref = joint
    line = None if pool == "joint" else stretch_space(recordings, maps, r_ref)
    if pool == "stretch" and line is None:
        return replace(as_recorded, record={"pool": "raw", "why": "a run with no stretch"})
    out = [replace(rec, r=r_ref + k * (np.asarray(rec.r, dtype=np.float64) - z))
           for rec, (z, k) in zip(recordings, maps, strict=True)]
    return Pooled(out, [{"rest": z, "rest_calibrated": r_ref, "span_gain": k}
                        for z, k in maps], {"pool": pool}, line)


def parse_options(items: Iterable[str]) -> dict[str, Any]:
    """``["N=11", "mode=split", "sigmas=[0.1, 0.3]"]`` -> dict; values are parsed as YAML."""
    options: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"--option {item!r}: expected key=value")
        try:
            options[key] = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            raise InputError(f"--option {item!r}: value is not valid YAML") from None
    return options


def training_error(calibration: SensorCalibration, segments: Sequence[Segment]) -> float:
    """RMSE on the training segments through the engine's batch path."""
    engine = Engine(Calibration({calibration.name: calibration}))
    estimates, references = [], []
    for seg in segments:
        engine.reset()
        estimates.append(engine.run(calibration.name, seg.t, seg.r).strain)
        references.append(seg.s)
    return error_stats(np.concatenate(estimates), np.concatenate(references)).rmse


def pool_runs(recordings: Sequence[Recording], pool: str, name: str,
              options: Mapping[str, Any]) -> Pooled:
    """The training runs pooled (``pooled_input``); ``spanned``: as ``choose_space`` says."""
    if pool != "spanned":
        return pooled_input(recordings, pool)
    if len(recordings) < 2:
        return pooled_input(recordings, "raw")
    gated, joint = gate(recordings)
    if joint is None:
        return Pooled(list(recordings), [], {"pool": "raw", **gated})
    own = {k: v for k, v in options.items() if k in _OWN_OPTIONS}

    def cubic(runs: Sequence[Recording]) -> SensorCalibration:
        return fit_sensor(runs, "cubic", name=name, options=own, pool="stretch")

    space, measured = (choose_space(recordings, cubic) if len(recordings) >= CHOICE_RUNS else
                       ("joint", {"why": f"fewer than {CHOICE_RUNS} runs: a run left out "
                                         "leaves no pooled fit to start"}))
    pooled = pooled_input(recordings, space, joint)
    pooled.record.update(gated, chosen_by=measured)
    return pooled


def fit_sensor(recordings: Sequence[Recording], model: str, *, name: str,
               bags: Sequence[str | Path] = (), options: Mapping[str, Any] | None = None,
               pool: str = "spanned") -> SensorCalibration:
    """Fit ``model`` to one sensor's runs, several pooled as ``pool`` says."""
    options, cls = dict(options or {}), model_class(model)
    check_fit_options(model, options)
    pooled = pool_runs(recordings, pool, name, options)
    recordings, pool_maps, pooling = pooled.runs, pooled.maps, pooled.record
    interval = slow_sample_interval(recordings)
    segments = training_segments(recordings, name, interval)
    check_training_span(segments, name)
    chain, alternating, pair = input_chain(recordings, name, options)
    if alternating:  # the models learn what the engine will feed them
        segments = [Segment(seg.t, pair_values(seg.r, branch=pair), seg.s) for seg in segments]
    r_all = np.concatenate([seg.r for seg in segments])
    s_all = np.concatenate([seg.s for seg in segments])
    normalisation = Normalisation.fit(r_all, s_all)
    direction, direction_source = direction_settings(segments, options)
    direction = replace(direction, sign=resistance_sign(r_all, s_all))
    model_options = {k: v for k, v in options.items() if k not in _OWN_OPTIONS}
    budget = options.get("fit_budget", FIT_SAMPLE_BUDGET)
    start = time.perf_counter()
    fit_segments, factor = ((segments, 1) if cls.fit_full_rate
                            else reduce_segments(segments, budget))
    compensator = cls.fit(fit_segments, normalisation, direction=direction, **model_options)
    fit_seconds = time.perf_counter() - start
    calibration = SensorCalibration(
        name=name, model=model, params=compensator.to_params(), normalisation=normalisation,
        valid_range=valid_range(r_all, s_all), direction=direction,
        input=InputSettings(alternation=alternating, pair=pair,
                            stretch_line=pooled.stretch_line),
        rest_resistance=training_rest_resistance(recordings, pair=pair),
        sample_interval=interval)
    _check_usable(calibration)
    memory = memory_reading(compensator)
    rmse = training_error(calibration, segments)
    chain_words = chain.reading() if chain.present else "no alternation found"
    if chain.present and alternating:
        chain_words += f", read through the pair {pair}"
    if not np.isfinite(rmse):
        raise FitError(f"sensor {name!r}: model {model!r} gives non-finite strain on its "
                       "own training data")
    calibration.provenance = provenance(
        [str(b) for b in bags], fit_rmse=rmse, n_samples=r_all.size, segments=len(segments),
        fit_seconds=round(fit_seconds, 3), direction_from=direction_source,
        measurement_chain=chain_words,
        options=model_options,
        **({"pooling": pooling} if len(recordings) > 1 else {}),
        **({"pooled_runs": [{k: round(v, 6) for k, v in m.items()} for m in pool_maps]}
           if pool_maps else {}),
        **({"fit_reduction": {"factor": factor,
                              "samples": sum(seg.t.size for seg in fit_segments)}}
           if factor > 1 else {}),
        **({"memory": memory} if memory else {}))
    return calibration


def _check_usable(calibration: SensorCalibration) -> None:
    """FitError, in the user's terms, where the fit fails the checks every reader applies."""
    name = calibration.name
    try:
        check_calibration(Calibration({name: calibration}))
    except CalibrationError as err:
        raise FitError(f"sensor {name!r}: the {calibration.model} fit cannot be used, nothing "
                       f"written: {err.field.removeprefix(f'sensors.{name}.')}: "
                       f"{err.problem}; try another model (apl, cubic)") from None


def memory_reading(compensator: Compensator) -> dict[str, Any] | None:
    """What a model with memory cells (APL, PL, MPI) kept of its memory, from its fit report."""
    report = compensator.fit_report
    if not report or "memoryless" not in report:
        return None
    return {"memory_share": round(float(report["memory_share"]), 4),
            "memoryless": bool(report["memoryless"]), "loop": str(report["loop"])}


def memoryless_note(name: str, calibration: SensorCalibration) -> str | None:
    """The one-line note for a fit whose memory model ended up memoryless."""
    memory = calibration.provenance.get("memory")
    if not memory or not memory.get("memoryless"):
        return None
    return (f"note: sensor {name!r}: {calibration.model} ended up memoryless (its cells give "
            f"{100 * memory['memory_share']:.2g} % of the output): on these data it is a "
            f"static map of R (the cells' sign: --option cell_weights=lead|lag|free)")


Run = tuple[str, int, "Recording"]
"""One run of a sensor: (its source, the index of that input, the recording)."""


def fit_bags(paths: Sequence[str | Path], model: str, sensors: Sequence[str] | None = None,
             options: Mapping[str, Any] | None = None, *,
             report: Callable[[str], None] | None = None,
             pool: str = "spanned", fitter: Fitter | None = None) -> Calibration:
    """``fit_runs`` on the recordings of every bag, the damage skipped to ``report``."""
    runs: list[tuple[str | None, Mapping[str, Recording]]] = []
    for path in paths:
        recordings, problems = load_recordings(path)
        for problem in problems:
            if report is not None:
                report(problem)
        runs.append((str(path), recordings))
    return fit_runs(runs, model, sensors, options, where=", ".join(map(str, paths)),
                    report=report, pool=pool, fitter=fitter)


def fit_runs(inputs: Sequence[tuple[str | None, Mapping[str, Recording]]], model: str,
             sensors: Sequence[str] | None = None, options: Mapping[str, Any] | None = None,
             *, where: str, report: Callable[[str], None] | None = None,
             pool: str = "spanned", fitter: Fitter | None = None) -> Calibration:
    """One calibration of ``sensors`` (default, ``all``: each referenced one) from each
    run's (source, recordings by sensor), a source None: ``(arrays: NAME, run K)``."""
    by_sensor: dict[str, list[Run]] = {}
    for i, (source, recordings) in enumerate(inputs):
        for name, rec in recordings.items():
            by_sensor.setdefault(name, []).append((source or f"(arrays: {name}, run {i + 1})",
                                                   i, rec))
    referenced = [n for n, runs in by_sensor.items()
                  if any(rec.s is not None for _, _, rec in runs)]
    found = ", ".join(by_sensor) or "none"
    every = not sensors or "all" in sensors
    if every:
        if not referenced:
            raise InputError(f"{where}: no sensor with a strain reference "
                             f"(sensors found: {found})")
        names = referenced
    else:
        names = list(dict.fromkeys(sensors or ()))
        for sensor in names:
            if sensor not in by_sensor:
                raise InputError(f"sensor {sensor!r} is not in {where} (sensors found: {found})")
            if sensor not in referenced:
                raise InputError(f"sensor {sensor!r} has no strain_reference in {where}")
    calibrations = {}
    for sensor in names:
        used = [run for run in by_sensor[sensor] if run[2].s is not None]
        runs, bags = [rec for _, _, rec in used], [source for source, _, _ in used]
        try:
            calibrations[sensor] = (
                fit_sensor(runs, model, name=sensor, bags=bags, options=options, pool=pool)
                if fitter is None else
                fitter(runs, name=sensor, bags=bags, options=options, pool=pool,
                       index=[i for _, i, _ in used]))
        except FitError as err:
            if not every or len(names) == 1:
                raise
            if report is not None:  # "all": the sensors that can be fitted are
                report(f"not fitted: {err}")
    if not calibrations:
        raise FitError(f"{where}: no sensor could be fitted")
    return Calibration(calibrations)


def in_run_bound(result: EvaluationResult, recordings: Mapping[str, Recording],
                 calibration: Calibration) -> None:
    """Set each scored sensor's ``in_run_rmse``: its model fitted and scored on the run itself."""
    for name, ev in result.sensors.items():
        cal = calibration.sensors[name]
        options = options_of(cal.model, cal.provenance.get("options") or {})  # no grid lines
        try:
            own = fit_sensor([recordings[name]], cal.model, name=name, options=options)
            again = evaluate_recordings({name: recordings[name]}, Calibration({name: own}))
            ev.in_run_rmse = again.sensors[name].stats.rmse
        except StrainCompError as err:
            ev.in_run_rmse = math.nan
            result.notes.append(f"{name}: no in-run bound ({err})")


# ``fit --model auto`` (docs/design.md): the lowest median RMSE after a start on each run (or
# group) left out, a simpler model within ``TIE`` before it; one run or group: ``ONE_RUN_ORDER``.

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
        started, error = started_error(cal, recordings[i])
        out.started.append(started)
        out.errors.append(error)
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
    """``--model auto``'s model, record, and folds started on each run left out (for ``learn``)."""
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
    """``choose_model``'s model fitted on every run; ``index``: each run's input (``groups``)."""
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
