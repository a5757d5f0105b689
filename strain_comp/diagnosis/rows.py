"""One sensor's rows for the residual loop (docs/design.md, "The loop's steps", 2-3): its
candidate effects (``candidates_of``) and the fit and held-out rows of their regressors
and its residual (``rows_of``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from strain_comp.diagnosis.candidates import default_candidates
from strain_comp.diagnosis.residuals import (
    HELD_OUT_EVERY,
    N_BLOCKS,
    Run,
    Series,
    baseline_rest,
    neighbours_of,
    series_all,
)
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording


@dataclass
class Candidates:
    """The candidate effects of one sensor, with an offset always among them."""

    entries: list[dict[str, Any]]
    names: list[str]
    kinds: list[str]
    offset: int
    """Index of the offset."""
    baselines: list[int]
    """Indices of the per-run baseline candidates."""


def candidates_of(sensor: str, bags: list[Mapping[str, Recording]],
                  base_fit: list[dict[str, Run]],
                  candidates: Sequence[dict[str, Any]] | None, stretch_history: bool
                  ) -> Candidates:
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
    """Fit rows (not held out, within the range the terms read) with their fold (the
    position of the block among the fit blocks of its recording), and the held-out rows:
    the validation recordings', or every ``HELD_OUT_EVERY``-th block's without them."""
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

