"""The residual loop's data (docs/design.md, "The loop's steps", 1-3): the residual and the
candidate regressors in time blocks, one sensor's candidates and its fit and held-out rows."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.effects import (
    Batch,
    EffectTerms,
    regressor_from_dict,
    run_segments,
)
from strain_comp.core.engine import Engine
from strain_comp.core.metrics import error_stats
from strain_comp.core.range_policy import MARGIN
from strain_comp.core.tare import tare_engine, unsettled_start
from strain_comp.diagnosis.candidates import BASELINE_WINDOW, default_candidates
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording, hold_latest

N_BLOCKS = 10
"""Contiguous time blocks each recording is cut into."""
HELD_OUT_EVERY = 3
"""Without validation runs every third block is held out (a holdout fraction of 0.3)."""
ROW_BUDGET = 250_000
"""Samples of one sensor's fit recordings up to which the loop keeps every used sample."""


@dataclass
class Series:
    """One recording of one sensor after the engine: used samples only."""

    e: np.ndarray
    """Residual S_corrected - S."""
    g: np.ndarray
    """Candidate regressors, (n, k)."""
    t: np.ndarray
    block: np.ndarray
    s: np.ndarray
    """Reference strain."""
    extended: np.ndarray
    """Samples extended beyond the valid range (the terms read it clamped): scored, not fitted."""
    unsettled: tuple[float, float] = (0.0, 0.0)
    """Seconds left out at the start and the drift seen there (``tare.unsettled_start``)."""


def as_bags(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             ) -> list[Mapping[str, Recording]]:
    """The runs of ``diagnose``'s argument, one bag or several."""
    if isinstance(recordings, Mapping):
        return [recordings]
    return list(recordings)


@dataclass
class Run:
    """The stripped calibration's engine output for one sensor of one bag."""

    s_hat: np.ndarray
    """The estimate clamped to the valid strain range (what the effect terms read)."""
    direction: np.ndarray
    resistance: np.ndarray
    """What the model read: the effect terms' R."""
    used: np.ndarray
    starts: list[int]
    """Positions among the used samples where the engine reset after a gap."""
    beyond: np.ndarray
    """What the engine adds beyond the valid range (its ``out_of_range`` extension)."""
    cal: SensorCalibration


def base_runs(bag: Mapping[str, Recording], calibration: Calibration, *,
               tare: str = "calibration") -> dict[str, Run]:
    """``Run`` of each calibrated sensor without effect terms, tared as ``evaluate`` tares."""
    stripped = Calibration({n: dataclasses.replace(c, effects=[])
                            for n, c in calibration.sensors.items()})
    engine = Engine(stripped)  # sensors are independent: effect terms (cross-talk) stripped
    tare_engine(engine, {n: (rec.t, rec.r) for n, rec in bag.items()}, tare)
    out = {}
    for name, rec in bag.items():
        if name not in stripped.sensors:
            continue
        result = engine.run(name, rec.t, rec.r, rec.temperature)
        used = used_mask(result.status)
        assert result.reset is not None  # Engine.run reports its gap resets
        starts = np.flatnonzero(result.reset[used]).tolist()
        vr = stripped.sensors[name].valid_range
        margin = MARGIN * (vr.s_hi - vr.s_lo)
        s_hat = np.clip(result.strain, vr.s_lo - margin, vr.s_hi + margin)
        out[name] = Run(s_hat, result.direction.astype(np.float64), result.resistance,
                         used, starts, result.strain - s_hat, calibration.sensors[name])
    return out


def neighbours_of(rec: Recording, bag: Mapping[str, Recording]) -> list[str]:
    """Array neighbours at index +-1 of ``rec``, in index order."""
    if rec.array is None or rec.index is None:
        return []
    found = {other.index: name for name, other in bag.items()
             if other.array == rec.array and other.index in (rec.index - 1, rec.index + 1)}
    return [found[i] for i in sorted(found)]


def block_ids(t: np.ndarray) -> np.ndarray:
    """Contiguous time blocks 0..N_BLOCKS-1 of equal duration."""
    if t.size == 0:
        return np.zeros(0, dtype=np.intp)
    span = t[-1] - t[0]
    if not span > 0:
        return np.zeros(t.size, dtype=np.intp)
    blocks: np.ndarray = np.minimum(((t - t[0]) / span * N_BLOCKS).astype(np.intp), N_BLOCKS - 1)
    return blocks


def _segmented(run: Callable[[Batch], np.ndarray], reset: Callable[[], None], batch: Batch,
               starts: Sequence[int]) -> np.ndarray:
    """``run`` over the segments between the engine's gap resets, ``reset`` between them."""
    return run_segments(
        lambda k: run(Batch(batch.t[k], batch.r[k], batch.s_hat[k], batch.direction[k],
                            None if batch.temperature is None else batch.temperature[k],
                            {name: v[k] for name, v in batch.neighbours.items()})),
        reset, batch.t.size, starts)


def series_of(sensor: str, bag: Mapping[str, Recording], runs: Mapping[str, Run],
            candidates: Sequence[dict[str, Any]], stride: int = 1) -> Series | None:
    """One sensor's residual and regressors in one bag at every ``stride``-th sample kept."""
    rec = bag[sensor]
    if rec.s is None or sensor not in runs:
        return None
    run = runs[sensor]
    cal = run.cal
    used = run.used
    ok = used & np.isfinite(np.asarray(rec.s, dtype=np.float64))
    if ok.sum() < 2 * N_BLOCKS:
        return None
    t = np.asarray(rec.t, dtype=np.float64)[used]
    temperature = None if rec.temperature is None else np.asarray(rec.temperature)[used]
    nbrs = {}
    for name in neighbours_of(rec, bag):
        if name in runs:
            nbrs[name] = hold_latest(np.asarray(rec.t, np.float64),
                                  np.asarray(bag[name].t, np.float64), runs[name].s_hat)[used]
    batch = Batch.of(t, run.resistance[used], run.s_hat[used], run.direction[used],
                     temperature, nbrs)
    terms = EffectTerms.from_dicts(cal.effects)
    corrected = _segmented(
        lambda b: terms.run(b.t, b.r, b.s_hat, b.direction, b.temperature, b.neighbours),
        terms.reset, batch, run.starts)
    keep = ok[used]
    s = np.asarray(rec.s, dtype=np.float64)[used]
    unsettled = unsettled_start(rec.t, cal.input.to_ohm(rec.r), rec.s, pair=cal.input.pair)
    if unsettled[0] > 0:  # seconds from the first sample with a reference
        keep &= t > t[keep][0] + unsettled[0]
    if keep.sum() < 2 * N_BLOCKS:
        return None
    rows = np.flatnonzero(keep)[::stride]
    regressors = [regressor_from_dict(c) for c in candidates]
    g = np.empty((rows.size, len(regressors)))
    for j, reg in enumerate(regressors):  # each online over every sample, then the rows
        g[:, j] = _segmented(reg.run, reg.reset, batch, run.starts)[rows]
    return Series(e=(corrected + run.beyond[used] - s)[rows], g=g, t=t[rows],
                   extended=(run.beyond[used] != 0.0)[rows],
                   block=block_ids(t[rows]), s=s[rows], unsettled=unsettled)


def series_all(sensor: str, bags: Sequence[Mapping[str, Recording]],
               base: Sequence[Mapping[str, Run]], candidates: Sequence[dict[str, Any]],
               stride: int) -> list[Series]:
    """``series_of`` of every bag that has something usable of ``sensor``."""
    return [s for b, runs in zip(bags, base, strict=True) if sensor in b
            for s in [series_of(sensor, b, runs, candidates, stride)] if s is not None]


def stride_of(bags: Sequence[Mapping[str, Recording]], sensor: str) -> int:
    """Every how many-th sample of ``sensor`` the loop keeps in ``bags`` (``ROW_BUDGET``)."""
    # a fixed stride, not a low-pass: that would shrink the noise no term can explain
    total = sum(b[sensor].t.size for b in bags if sensor in b)
    return max(1, math.ceil(total / ROW_BUDGET))


def rmse_stats(e: np.ndarray) -> dict[str, float]:
    """The statistics of errors ``e`` that ``diagnose`` reports before and after."""
    stats = error_stats(e, np.zeros_like(e))
    return {"rmse": stats.rmse, "mae": stats.mae, "max_abs": stats.max_abs, "n": stats.n}


def baseline_rest(bags: Sequence[Mapping[str, Recording]], sensor: str) -> float:
    """Mean reference strain over the first ``BASELINE_WINDOW`` s: the strain runs start at."""
    values = []
    for bag in bags:
        rec = bag.get(sensor)
        if rec is None or rec.s is None or rec.t.size == 0:
            continue
        s = np.asarray(rec.s, dtype=np.float64)[rec.t - rec.t[0] <= BASELINE_WINDOW]
        values.extend(s[np.isfinite(s)].tolist())
    return float(np.mean(values)) if values else 0.0


@dataclass
class Candidates:
    """The candidate effects of one sensor, with an offset always among them."""

    entries: list[dict[str, Any]]
    names: list[str]
    kinds: list[str]
    offset: int
    baselines: list[int]


def candidates_of(sensor: str, bags: list[Mapping[str, Recording]],
                  base_fit: list[dict[str, Run]],
                  candidates: Sequence[dict[str, Any]] | None, stretch_history: bool
                  ) -> Candidates:
    """The given candidates, or the defaults for what the recordings hold, plus an offset."""
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
    return Candidates(entries, [str(c["name"]) for c in entries], kinds,
                       kinds.index("offset"), [j for j, k in enumerate(kinds) if k == "baseline"])


@dataclass
class Rows:
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


def rows_of(sensor: str, series: list[Series], validate: list[Mapping[str, Recording]] | None,
            base_val: list[dict[str, Run]], entries: list[dict[str, Any]], val_stride: int
            ) -> Rows:
    """Fit rows with their fold, and the held-out rows (validation runs' or held-out blocks')."""
    period = HELD_OUT_EVERY if validate is None else 0
    held_out = [(s.block % period == period - 1) if period else np.zeros(s.e.size, bool)
                for s in series]
    fold_of_block = np.cumsum([not (period and b % period == period - 1)
                               for b in range(N_BLOCKS)]) - 1
    fits = [~h & ~s.extended for s, h in zip(series, held_out, strict=True)]
    e_fit = np.concatenate([s.e[f] for s, f in zip(series, fits, strict=True)])
    g_fit = np.concatenate([s.g[f] for s, f in zip(series, fits, strict=True)])
    fold = np.concatenate([fold_of_block[s.block[f]]
                           for s, f in zip(series, fits, strict=True)])
    if validate is not None:
        val_series = series_all(sensor, validate, base_val, entries, val_stride)
        if not val_series:
            raise InputError(f"sensor {sensor!r}: the validation recordings have no usable "
                             "samples with a reference strain")
        out = [(s.e, s.g, s.t, s.s) for s in val_series]
    else:
        val_series = []
        out = [(s.e[h], s.g[h], s.t[h], s.s[h]) for s, h in zip(series, held_out, strict=True)]
    e_out, g_out, t_out, s_out = (np.concatenate([o[k] for o in out]) for k in range(4))
    return Rows(series, val_series, g_fit, e_fit, fold, int(fold_of_block.max()) + 1,
                 e_out, g_out, t_out, s_out)

