"""The residual loop (DESIGN.md, "The residual loop"): find the effect a calibration lacks,
add it as an explicit online term, and report the error before and after on held-out data.

Per calibrated sensor that has a recording with a reference strain:

1. **Residual.** The calibration, with its effect terms removed, runs through the engine's
   batch path (``Engine.run``, the code replay and the node use) to give the model's own
   estimate S_hat and the published direction d; the sensor's existing effect terms (if
   any) are applied on top, and e = S_corrected - S over the samples the engine used whose
   reference is finite. Effect state restarts at the engine's gap resets, as online.
2. **Candidates.** Every regressor of ``default_candidates`` (``strain_comp.core.effects``: rate,
   direction, relaxation over time constants 0.5-128 s and three branches, elapsed-time
   drift, temperature when a temperature series exists, strain level, Mullins-type history
   incl. the peak strain, cross-talk from array neighbours at index +-1, and a per-run
   ``baseline``) is computed online over each recording, exactly as the engine would
   compute it. Nothing about how the data were made is known.
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
   measured on the held-out blocks or on the ``validate_recordings``. Added effects are
   kept only while each one lowers that held-out RMSE by more than ``margin``, below both
   the model before it and that model with an intercept (an effect that does not is not
   added); the result says when nothing helps. The output calibration is the input plus
   the added effect entries, with the coefficients whose held-out error is reported.
7. **Per-run baseline.** A ``baseline`` term (the mean S_hat over the first seconds of a
   run, minus the strain runs start at) is a per-run intercept: inside one run it cannot be
   told from a constant ``offset``. It is tested as a second hypothesis: its shift is
   removed whole (coefficient 1, no automatic intercept), steps 5-6 run on what is left,
   and the baseline hypothesis replaces the constant-intercept one only if its held-out
   RMSE is lower by more than ``margin``. That choice is made on the held-out data, like
   the veto of step 6: given a ``--validate`` recording of another run it is a cross-run
   test; on held-out blocks of one run the two tie and the constant hypothesis stays.

Decisions: the regressors read the engine's clamped estimate (identical to the online
input as long as the estimate is inside the valid strain range widened by the engine's
margin); effect state is reset at the engine's gap resets, in diagnosis as online.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from strain_comp._numba import njit
from strain_comp.core.calibration import Calibration, SensorCalibration, save_calibration
from strain_comp.core.effects import (
    Batch,
    EffectTerms,
    effect_dict,
    regressor_from_dict,
    run_segments,
)
from strain_comp.core.engine import Engine, used_mask
from strain_comp.core.metrics import error_stats
from strain_comp.core.tare import tare_engine
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording, hold_latest, load_recordings

RELAXATION_TAUS = tuple(round(2.0 ** (k / 2), 2) for k in range(-2, 15))
"""Time constants [s] of the relaxation candidates: 0.5 s to 128 s, a factor sqrt(2) apart
(fine enough that the nearest one is within 19 % of any time constant in that span)."""
BASELINE_WINDOW = 5.0
"""Seconds at the start of a run over which a ``baseline`` candidate averages S_hat."""
SIGNIFICANCE = 1.0
"""A term is added only if its fold-wise cross-validated gain exceeds this many standard
errors (``_significant``)."""


def default_candidates(*, temperature_ref: float | None = None,
                       neighbours: Sequence[str] = (),
                       baseline_rest: float = 0.0) -> list[dict[str, Any]]:
    """The generic candidate effects (calibration-file dicts with ``coef: 0``).

    ``temperature_ref`` [deg C]: include temperature terms around it (None: no temperature
    series); ``neighbours``: array neighbours to test for cross-talk; ``baseline_rest`` [%]:
    the strain runs start at (the ``rest`` of the per-run ``baseline`` candidate).
    """
    out: list[dict[str, Any]] = [{"name": "offset", "kind": "offset", "params": {}}]
    out += [{"name": f"rate_{mode}", "kind": "rate", "params": {"tau": 1.0, "mode": mode}}
            for mode in ("signed", "direction")]
    out += [{"name": "direction", "kind": "direction", "params": {"mode": "sign", "hold": False}},
            {"name": "direction_held", "kind": "direction",
             "params": {"mode": "sign", "hold": True}},
            {"name": "direction_strain", "kind": "direction",
             "params": {"mode": "strain", "hold": True}}]
    for branch in ("both", "loading", "unloading"):
        out += [{"name": f"relaxation_{branch}_tau{tau:g}", "kind": "relaxation",
                 "params": {"tau": tau, "branch": branch}} for tau in RELAXATION_TAUS]
    out += [{"name": f"drift_{form}", "kind": "elapsed", "params": {"form": form, "scale": 100.0}}
            for form in ("linear", "sqrt", "log", "linear_strain")]
    if temperature_ref is not None:
        out += [{"name": f"temperature_{form}", "kind": "temperature",
                 "params": {"form": form, "t_ref": float(temperature_ref)}}
                for form in ("offset", "strain")]
    out += [{"name": f"strain_level_{p}", "kind": "strain_level", "params": {"power": p}}
            for p in (1, 2, 3)]
    out += [{"name": "mullins_gap", "kind": "mullins", "params": {"form": "gap", "n0": 1.0}},
            {"name": "mullins_gap_strain", "kind": "mullins",
             "params": {"form": "gap_strain", "n0": 1.0}},
            {"name": "mullins_cycles_log", "kind": "mullins",
             "params": {"form": "cycles_log", "n0": 1.0}}]
    out += [{"name": f"mullins_cycles_exp_n{n0:g}", "kind": "mullins",
             "params": {"form": "cycles_exp", "n0": n0}} for n0 in (1.0, 3.0)]
    out.append({"name": "mullins_peak_strain", "kind": "mullins",
                "params": {"form": "peak_strain", "n0": 1.0}})
    out.append({"name": "baseline", "kind": "baseline",
                "params": {"window": BASELINE_WINDOW, "rest": float(baseline_rest)}})
    out += [{"name": f"crosstalk_{nb}", "kind": "crosstalk", "params": {"neighbour": nb}}
            for nb in neighbours]
    for entry in out:
        entry["coef"] = 0.0
    return out


@dataclass
class EffectScore:
    """One candidate's evidence."""

    sensor: str
    name: str
    kind: str
    params: dict[str, Any]
    score: float
    """Held-out share of residual variance explained (first round, see module doc)."""
    added: bool = False
    gain: float | None = None
    """Relative drop of the cross-validated RMSE in the round it was added."""
    coef: float | None = None
    magnitude: float | None = None
    """coef * std(g) over the fit data: the typical size of the correction [% strain]."""
    rank: int | None = None
    """Order of addition (0 first); None when not added."""

    def to_json(self) -> dict[str, Any]:
        record: dict[str, Any] = {"name": self.name, "score": _num(self.score),
                                  "added": self.added, "sensor": self.sensor, "kind": self.kind,
                                  "params": self.params}
        if self.params.get("tau") is not None:
            record["time_constant"] = self.params["tau"]
        for key in ("gain", "coef", "magnitude"):
            value = getattr(self, key)
            if value is not None:
                record[key] = _num(value)
        if self.added and self.coef is not None:
            record["reading"] = effect_reading(self.kind, self.params, self.coef,
                                               self.magnitude)
        return record


def effect_reading(kind: str, params: Mapping[str, Any], coef: float,
                   magnitude: float | None = None) -> str:
    """An added term in physical words. The model's output carries + coef g (the term
    removes it), so the reading describes the sensor against its calibration."""
    size = "" if magnitude is None else f", typically {abs(magnitude):.2g} % strain"
    if kind == "offset":
        return f"output offset {coef:+.3g} % strain"
    if kind == "strain_level":
        if params.get("power", 1) == 1 and coef < 1.0:
            return f"sensitivity {100.0 * (1.0 / (1.0 - coef) - 1.0):+.1f} % against calibration"
        return f"curvature error (strain^{params.get('power')}){size}"
    if kind == "rate":
        return f"rate-dependent lag {coef:+.3g} s (filter tau {params.get('tau')} s){size}"
    if kind == "direction" and params.get("mode") == "strain":
        return f"hysteresis +-{100.0 * abs(coef):.3g} % of the strain, loading vs unloading"
    if kind == "direction":
        return f"hysteresis +-{abs(coef):.3g} % strain between loading and unloading"
    if kind == "relaxation":
        return (f"relaxation tau {params.get('tau')} s after {params.get('branch')} "
                f"steps{size}")
    if kind == "elapsed":
        scale = float(params.get("scale", 100.0))
        if params.get("form", "linear") == "linear":
            return f"drift {coef * 3600.0 / scale:+.3g} % strain/h"
        if params.get("form") == "linear_strain":
            return f"gain drift {100.0 * coef * 3600.0 / scale:+.3g} %/h"
        return f"drift ({params.get('form')} in time){size}"
    if kind == "temperature":
        if params.get("form") == "strain":
            return f"temperature sensitivity {100.0 * coef:+.3g} %/K"
        return f"temperature offset {coef:+.3g} % strain/K"
    if kind == "mullins":
        return f"Mullins-type softening ({params.get('form')}){size}"
    if kind == "crosstalk":
        return f"cross-talk {100.0 * coef:+.3g} % of {params.get('neighbour')}'s strain"
    if kind == "baseline":
        return f"per-run baseline: each run re-zeroed at its start{size}"
    return f"{kind}{size}"


@dataclass
class SensorDiagnosis:
    """One sensor's diagnosis, with the held-out arrays the plots show."""

    name: str
    before: dict[str, float]
    after: dict[str, float]
    scores: list[EffectScore]
    added: list[dict[str, Any]]
    """Effect entries added to the calibration (with the intercept, if any)."""
    message: str
    plot: dict[str, np.ndarray] = field(default_factory=dict)
    """Held-out t, s (reference), e_before, e_after and ``g`` = the winning regressor
    (empty: none)."""
    winner: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"before": self.before, "after": self.after, "message": self.message,
                "winner": self.winner, "added": self.added}


@dataclass
class DiagnoseResult:
    """The outcome: per-sensor detail, pooled before/after and the output calibration."""

    sensors: dict[str, SensorDiagnosis]
    before: dict[str, float]
    after: dict[str, float]
    validated_on: str
    validation: dict[str, Any]
    calibration: Calibration
    conditions: list[dict[str, Any]] = field(default_factory=list)
    """Measurement-chain and tare hypotheses tried (``strain_comp.diagnosis.conditions``)."""

    @property
    def effects(self) -> list[EffectScore]:
        """All candidates: added ones first (in order added, the intercept last), then the
        rest by score."""
        rows = [s for d in self.sensors.values() for s in d.scores]
        added = sorted((s for s in rows if s.added),
                       key=lambda s: (s.kind == "offset", s.sensor, s.rank))
        rest = sorted((s for s in rows if not s.added),
                      key=lambda s: -s.score if math.isfinite(s.score) else math.inf)
        return added + rest

    @property
    def added(self) -> list[EffectScore]:
        return [s for s in self.effects if s.added]

    def to_json(self) -> dict[str, Any]:
        """The DESIGN.md ``diagnose --json`` record, then extra keys."""
        return {"before": self.before, "after": self.after,
                "effects": [s.to_json() for s in self.effects],
                "validated_on": self.validated_on, "validation": self.validation,
                "sensors": {n: d.to_json() for n, d in self.sensors.items()},
                "conditions": self.conditions}

    def summary(self) -> str:
        """A few lines for the terminal."""
        lines = [f"held-out RMSE ({self.validated_on}): before {self.before['rmse']:.4g} %, "
                 f"after {self.after['rmse']:.4g} %"]
        for c in self.conditions:
            if c["name"] == "measurement chain":
                lines.append(f"  measurement chain: {c['reading']}")
                continue
            verdict = "chosen" if c["chosen"] else "not chosen"
            lines.append(f"  {c['name']}: {c['reading']}; held-out RMSE after the loop "
                         f"{c['after']:.4g} % ({verdict})")
        for name, d in self.sensors.items():
            lines.append(f"  {name}: {d.message}")
            for e in d.scores:
                if e.added and e.coef is not None:
                    lines.append(f"    + {e.name}: "
                                 f"{effect_reading(e.kind, e.params, e.coef, e.magnitude)}")
        return "\n".join(lines)


def _num(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


@dataclass
class _Series:
    """One recording of one sensor after the engine: used samples only."""

    e: np.ndarray
    """Residual S_corrected - S."""
    g: np.ndarray
    """Candidate regressors, (n, k)."""
    t: np.ndarray
    block: np.ndarray
    s: np.ndarray
    """Reference strain [%]."""


def _as_bags(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             ) -> list[Mapping[str, Recording]]:
    if isinstance(recordings, Mapping):
        return [recordings]
    return list(recordings)


@dataclass
class _Run:
    """The stripped calibration's engine output for one sensor of one bag."""

    s_hat: np.ndarray
    direction: np.ndarray
    used: np.ndarray
    starts: list[int]
    """Positions among the used samples where the engine reset after a gap."""


def _base_runs(bag: Mapping[str, Recording], calibration: Calibration, *,
               tare: str = "calibration") -> dict[str, _Run]:
    """S_hat without effects, direction, used mask and gap resets per calibrated sensor
    (each run tared by ``tare``, as ``evaluate`` does)."""
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
        dt = np.diff(np.asarray(rec.t, dtype=np.float64)[used])
        starts = (np.flatnonzero((dt > engine.gap_reset) | (dt <= -engine.gap_reset))
                  + 1).tolist()
        out[name] = _Run(result.strain, result.direction.astype(np.float64), used, starts)
    return out


def _neighbours(rec: Recording, bag: Mapping[str, Recording]) -> list[str]:
    """Array neighbours at index +-1 of ``rec``, in index order."""
    if rec.array is None or rec.index is None:
        return []
    found = {other.index: name for name, other in bag.items()
             if other.array == rec.array and other.index in (rec.index - 1, rec.index + 1)}
    return [found[i] for i in sorted(found)]


def _block_ids(t: np.ndarray, n_blocks: int) -> np.ndarray:
    """Contiguous time blocks 0..n_blocks-1 of equal duration."""
    if t.size == 0:
        return np.zeros(0, dtype=np.intp)
    span = t[-1] - t[0]
    if not span > 0:
        return np.zeros(t.size, dtype=np.intp)
    return np.minimum(((t - t[0]) / span * n_blocks).astype(np.intp), n_blocks - 1)


def _segmented(run: Callable[[Batch], np.ndarray], reset: Callable[[], None], batch: Batch,
               starts: Sequence[int]) -> np.ndarray:
    """``run`` over the segments between the engine's gap resets, ``reset`` between them
    (the engine resets effect state where it resets the model)."""
    return run_segments(
        lambda k: run(Batch(batch.t[k], batch.r[k], batch.s_hat[k], batch.direction[k],
                            None if batch.temperature is None else batch.temperature[k],
                            {name: v[k] for name, v in batch.neighbours.items()})),
        reset, batch.t.size, starts)


def _series(sensor: str, cal: SensorCalibration, bag: Mapping[str, Recording],
            runs: Mapping[str, _Run], candidates: Sequence[dict[str, Any]],
            n_blocks: int) -> _Series | None:
    """Residual and candidate regressors of one sensor in one bag (None: nothing usable)."""
    rec = bag[sensor]
    if rec.s is None or sensor not in runs:
        return None
    run = runs[sensor]
    used = run.used
    ok = used & np.isfinite(np.asarray(rec.s, dtype=np.float64))
    if ok.sum() < 2 * n_blocks:
        return None
    t = np.asarray(rec.t, dtype=np.float64)[used]
    temperature = None if rec.temperature is None else np.asarray(rec.temperature)[used]
    nbrs = {}
    for name in _neighbours(rec, bag):
        if name in runs:
            nbrs[name] = hold_latest(np.asarray(rec.t, np.float64),
                                  np.asarray(bag[name].t, np.float64), runs[name].s_hat)[used]
    batch = Batch.of(t, np.asarray(rec.r)[used], run.s_hat[used], run.direction[used],
                     temperature, nbrs)
    terms = EffectTerms.from_dicts(cal.effects)
    corrected = _segmented(
        lambda b: terms.run(b.t, b.r, b.s_hat, b.direction, b.temperature, b.neighbours),
        terms.reset, batch, run.starts)
    keep = ok[used]
    regressors = [regressor_from_dict(c) for c in candidates]
    g = np.column_stack([_segmented(reg.run, reg.reset, batch, run.starts)
                         for reg in regressors])
    s = np.asarray(rec.s, dtype=np.float64)[used]
    e = corrected - s
    return _Series(e=e[keep], g=g[keep], t=t[keep], block=_block_ids(t[keep], n_blocks),
                   s=s[keep])


@njit
def _fold_sums(x: np.ndarray, e: np.ndarray, fold: np.ndarray, n_folds: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-fold X'X, X'e, e'e and counts in one pass (a plain loop: no BLAS threads)."""
    n, k = x.shape
    xx = np.zeros((n_folds, k, k))
    xe = np.zeros((n_folds, k))
    ee = np.zeros(n_folds)
    count = np.zeros(n_folds)
    for i in range(n):
        f = fold[i]
        count[f] += 1.0
        ee[f] += e[i] * e[i]
        for a in range(k):
            xa = x[i, a]
            xe[f, a] += xa * e[i]
            for b in range(a, k):
                xx[f, a, b] += xa * x[i, b]
    for f in range(n_folds):
        for a in range(k):
            for b in range(a + 1, k):
                xx[f, b, a] = xx[f, a, b]
    return xx, xe, ee, count


class _Gram:
    """Per-fold sums X'X, X'e, e'e over all candidate columns: any subset's least-squares
    fit on some folds and its error on the others, without touching the samples again."""

    def __init__(self, g: np.ndarray, e: np.ndarray, fold: np.ndarray, n_folds: int) -> None:
        std = np.std(g, axis=0)
        self.scale = np.where(std > 0, std, 1.0)
        x = np.ascontiguousarray(g / self.scale)
        self.xx, self.xe, self.ee, self.n = _fold_sums(
            x, np.ascontiguousarray(e, dtype=np.float64), fold.astype(np.int64), n_folds)
        self.xx_all = self.xx.sum(axis=0)
        self.xe_all = self.xe.sum(axis=0)

    def solve(self, cols: Sequence[int], folds: np.ndarray) -> np.ndarray:
        """Least-squares coefficients (scaled columns) on ``folds``."""
        if not cols:
            return np.zeros(0)
        idx = np.asarray(cols)
        a = self.xx[np.ix_(folds, idx, idx)].sum(axis=0)
        b = self.xe[np.ix_(folds, idx)].sum(axis=0)
        return np.linalg.lstsq(a, b, rcond=1e-12)[0]

    def fold_sse(self, cols: Sequence[int]) -> np.ndarray:
        """Blocked cross-validation: each fold's squared error under the fit on the others
        (0 for an empty fold)."""
        if not cols:
            return self.ee.copy()
        idx = np.asarray(cols)
        xx_f = self.xx[:, idx[:, None], idx[None, :]]
        xe_f = self.xe[:, idx]
        a = self.xx_all[np.ix_(idx, idx)] - xx_f
        b = self.xe_all[idx] - xe_f
        # leave-one-fold-out fits, batched; a tiny ridge keeps collinear columns solvable
        ridge = 1e-10 * np.maximum(np.trace(a, axis1=1, axis2=2), 1e-300) / idx.size
        a = a + ridge[:, None, None] * np.eye(idx.size)
        c = np.linalg.solve(a, b[..., None])[..., 0]
        sse = self.ee - 2.0 * np.einsum("fi,fi->f", c, xe_f) \
            + np.einsum("fi,fij,fj->f", c, xx_f, c)
        return np.where(self.n > 0, np.maximum(sse, 0.0), 0.0)

    def cv_rmse(self, cols: Sequence[int]) -> float:
        """Blocked cross-validated RMSE of e ~ X[:, cols] c (leave one fold out)."""
        return math.sqrt(self.fold_sse(cols).sum() / self.n.sum())


def _significant(before: np.ndarray, after: np.ndarray, n: np.ndarray) -> bool:
    """Is the fold-wise drop of the cross-validated squared error consistently > 0?

    One-sided test over the folds: mean drop > ``SIGNIFICANCE`` standard errors. A term
    that explains variance in some stretches of the record and hurts in others (it fits a
    coincidence of the profile, not a physical effect) fails it even when the pooled
    error falls a little.
    """
    d = (before - after)[n > 0]
    if d.size < 2:
        return bool(d.sum() > 0)
    return bool(d.mean() > SIGNIFICANCE * d.std(ddof=1) / math.sqrt(d.size))


@dataclass
class _Selection:
    chosen: list[int]
    gains: dict[int, float]


def _select(gram: _Gram, n_cols: int, offset: int, margin: float, max_effects: int, *,
            auto_intercept: bool = True, skip: Sequence[int] = ()) -> _Selection:
    """Greedy forward selection (module docstring, step 5)."""

    def model(cols: Sequence[int]) -> list[int]:
        return _with_intercept(cols, offset) if auto_intercept else list(dict.fromkeys(cols))

    chosen: list[int] = []
    gains: dict[int, float] = {}
    current = gram.fold_sse([])
    while len([c for c in chosen if c != offset]) < max_effects and current.sum() > 0:
        ref = current
        trials: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        if auto_intercept:
            ref = gram.fold_sse(model([*chosen, offset]))
            if offset not in chosen:
                trials[offset] = (current, ref)
        if ref.sum() > 0:
            for j in range(n_cols):
                if j in chosen or j in skip or (auto_intercept and j == offset):
                    continue
                trials[j] = (ref, gram.fold_sse(model([*chosen, j])))
        gain = {j: 1.0 - math.sqrt(after.sum() / before.sum())
                for j, (before, after) in trials.items()}
        passing = [j for j, (before, after) in trials.items()
                   if gain[j] > margin and _significant(before, after, gram.n)]
        if not passing:
            break
        best = max(passing, key=gain.__getitem__)
        chosen.append(best)
        gains[best] = gain[best]
        current = gram.fold_sse(model(chosen))
    return _Selection(chosen, gains)


def _scores(gram: _Gram, n_cols: int, offset: int) -> dict[int, float]:
    """First-round scores: held-out share of the residual variance each candidate explains
    (relative to the intercept-only model; the intercept relative to no correction)."""
    rmse_none = gram.cv_rmse([])
    rmse_offset = gram.cv_rmse([offset])
    scores = {}
    for j in range(n_cols):
        if j == offset:
            scores[j] = 1.0 - (rmse_offset / rmse_none) ** 2 if rmse_none > 0 else 0.0
        else:
            rmse_j = gram.cv_rmse([offset, j])
            scores[j] = 1.0 - (rmse_j / rmse_offset) ** 2 if rmse_offset > 0 else 0.0
    return scores


def _with_intercept(cols: Sequence[int], offset: int) -> list[int]:
    """The columns of a model: ``cols`` plus the intercept once any other term is in."""
    cols = list(dict.fromkeys(cols))
    if any(c != offset for c in cols) and offset not in cols:
        cols.insert(0, offset)
    return cols


def _rmse_stats(e: np.ndarray) -> dict[str, float]:
    stats = error_stats(e, np.zeros_like(e))
    return {"rmse": stats.rmse, "mae": stats.mae, "max_abs": stats.max_abs, "n": stats.n}


def _unique(name: str, taken: set[str]) -> str:
    out, k = name, 2
    while out in taken:
        out, k = f"{name}_{k}", k + 1
    taken.add(out)
    return out


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


@dataclass
class _Branch:
    """One hypothesis after selection and the held-out veto: ``shift`` is the baseline
    column removed with coefficient 1 (None: a constant intercept instead)."""

    shift: int | None
    selection: _Selection
    kept: list[int]
    coef: np.ndarray
    e_after: np.ndarray
    rmse: float


def _keep(gram: _Gram, selection: _Selection, shift: int | None, offset: int,
          e_out: np.ndarray, g_out: np.ndarray, n_folds: int, margin: float) -> _Branch:
    """The held-out veto (module docstring, step 6) on one branch's selected terms."""
    all_folds = np.arange(n_folds)
    target = e_out - g_out[:, shift] if shift is not None else e_out
    auto = shift is None

    def held_out(cols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        c = gram.solve(cols, all_folds) / gram.scale[cols] if cols else np.zeros(0)
        return c, target - g_out[:, cols] @ c

    kept: list[int] = []
    current = _rms(e_out)
    if shift is not None:
        rmse = _rms(target)
        if not rmse < (1.0 - margin) * current:
            return _Branch(None, selection, [], np.zeros(0), e_out, current)
        current = rmse
    for j in selection.chosen:
        trial = _with_intercept([*kept, j], offset) if auto else [*kept, j]
        rmse = _rms(held_out(trial)[1])
        helps = rmse < (1.0 - margin) * current
        if auto and j != offset:  # it must also beat the intercept alone
            helps = helps and rmse < _rms(held_out(_with_intercept([*kept, offset], offset))[1])
        if not helps:
            break
        kept, current = trial, rmse
    coef, e_after = held_out(kept)
    return _Branch(shift, selection, kept, coef, e_after, _rms(e_after))


def _holdout_period(holdout_fraction: float) -> int:
    """Every how many-th time block is held out (module docstring, step 3)."""
    return max(2, round(1.0 / holdout_fraction))


def _baseline_rest(bags: Sequence[Mapping[str, Recording]], sensor: str) -> float:
    """Mean reference strain over the first ``BASELINE_WINDOW`` s of the fit recordings:
    the strain a run starts at (what a baseline term should read at rest)."""
    values = []
    for bag in bags:
        rec = bag.get(sensor)
        if rec is None or rec.s is None or rec.t.size == 0:
            continue
        s = np.asarray(rec.s, dtype=np.float64)[rec.t - rec.t[0] <= BASELINE_WINDOW]
        values.extend(s[np.isfinite(s)].tolist())
    return float(np.mean(values)) if values else 0.0


def _diagnose_sensor(sensor: str, cal: SensorCalibration, bags: list[Mapping[str, Recording]],
                     validate: list[Mapping[str, Recording]] | None,
                     base_fit: list[dict[str, _Run]], base_val: list[dict[str, _Run]],
                     candidates: Sequence[dict[str, Any]] | None, holdout_fraction: float,
                     n_blocks: int, margin: float, max_effects: int
                     ) -> SensorDiagnosis | None:
    if candidates is None:
        temps = [np.asarray(b[sensor].temperature, np.float64) for b in bags
                 if sensor in b and b[sensor].temperature is not None]
        temps = [x[np.isfinite(x)] for x in temps]
        have_temp = any(x.size and np.ptp(x) > 0 for x in temps)
        t_ref = float(np.mean(np.concatenate(temps))) if have_temp else None
        nbrs = sorted({n for b, runs in zip(bags, base_fit, strict=True) if sensor in b
                       for n in _neighbours(b[sensor], b) if n in runs})
        candidates = default_candidates(temperature_ref=t_ref, neighbours=nbrs,
                                        baseline_rest=_baseline_rest(bags, sensor))
    candidates = [dict(c, coef=0.0) for c in candidates]
    names = [str(c["name"]) for c in candidates]
    kinds = [str(c["kind"]) for c in candidates]
    if "offset" not in kinds:
        candidates.append({"name": "offset", "kind": "offset", "params": {}, "coef": 0.0})
        names.append("offset")
        kinds.append("offset")
    offset = kinds.index("offset")
    baselines = [j for j, k in enumerate(kinds) if k == "baseline"]
    series = [s for b, runs in zip(bags, base_fit, strict=True) if sensor in b
              for s in [_series(sensor, cal, b, runs, candidates, n_blocks)] if s is not None]
    if not series:
        return None
    period = _holdout_period(holdout_fraction) if validate is None else 0
    held_out = [(s.block % period == period - 1) if period else np.zeros(s.e.size, bool)
                for s in series]
    # folds: position of the block among the fit blocks of its recording
    fold_of_block = np.cumsum([not (period and b % period == period - 1)
                               for b in range(n_blocks)]) - 1
    n_folds = int(fold_of_block.max()) + 1
    e_fit = np.concatenate([s.e[~h] for s, h in zip(series, held_out, strict=True)])
    g_fit = np.concatenate([s.g[~h] for s, h in zip(series, held_out, strict=True)])
    fold = np.concatenate([fold_of_block[s.block[~h]]
                           for s, h in zip(series, held_out, strict=True)])
    gram = _Gram(g_fit, e_fit, fold, n_folds)
    scores = _scores(gram, len(names), offset)

    if validate is not None:
        val_series = [s for b, runs in zip(validate, base_val, strict=True) if sensor in b
                      for s in [_series(sensor, cal, b, runs, candidates, n_blocks)]
                      if s is not None]
        if not val_series:
            raise InputError(f"sensor {sensor!r}: the validation recordings have no usable "
                             "samples with a reference strain")
        e_out = np.concatenate([s.e for s in val_series])
        g_out = np.concatenate([s.g for s in val_series])
        t_out = np.concatenate([s.t for s in val_series])
        s_out = np.concatenate([s.s for s in val_series])
    else:
        e_out = np.concatenate([s.e[h] for s, h in zip(series, held_out, strict=True)])
        g_out = np.concatenate([s.g[h] for s, h in zip(series, held_out, strict=True)])
        t_out = np.concatenate([s.t[h] for s, h in zip(series, held_out, strict=True)])
        s_out = np.concatenate([s.s[h] for s, h in zip(series, held_out, strict=True)])

    best = _keep(gram, _select(gram, len(names), offset, margin, max_effects, skip=baselines),
                 None, offset, e_out, g_out, n_folds, margin)
    rmse_none = gram.cv_rmse([])
    for b in baselines:  # the per-run hypothesis: the start-of-run shift removed whole
        shifted = _Gram(g_fit, e_fit - g_fit[:, b], fold, n_folds)
        rmse_b = shifted.cv_rmse([])
        scores[b] = 1.0 - (rmse_b / rmse_none) ** 2 if rmse_none > 0 else 0.0
        selection = _select(shifted, len(names), offset, margin, max_effects - 1,
                            auto_intercept=False, skip=baselines)
        selection.gains = {b: 1.0 - rmse_b / rmse_none if rmse_none > 0 else 0.0,
                           **selection.gains}
        branch = _keep(shifted, selection, b, offset, e_out, g_out, n_folds, margin)
        if branch.shift is not None and branch.rmse < (1.0 - margin) * best.rmse:
            best = branch

    rmse_before = _rms(e_out)
    terms = ([best.shift] if best.shift is not None and best.rmse < rmse_before else []) \
        + best.kept
    coefs = ([1.0] if terms[:1] == [best.shift] else []) + list(best.coef)
    gains = best.selection.gains
    taken = {str(e["name"]) for e in cal.effects}
    added = [effect_dict(_unique(names[j], taken), regressor_from_dict(candidates[j]), c)
             for j, c in zip(terms, coefs, strict=True)]
    std_fit = np.std(g_fit, axis=0)
    coef_of = dict(zip(terms, coefs, strict=True))
    rows = []
    for j in range(len(names)):
        row = EffectScore(sensor=sensor, name=names[j], kind=kinds[j],
                          params=regressor_from_dict(candidates[j]).params(), score=scores[j])
        if j in coef_of:
            row.added = True
            row.rank = terms.index(j)
            row.gain = gains.get(j)
            row.coef = float(coef_of[j])
            row.magnitude = float(abs(coef_of[j]) * (std_fit[j] if j != offset else 1.0))
            if kinds[j] == "baseline":
                row.magnitude = float(np.sqrt(np.mean(g_out[:, j] ** 2)))
        rows.append(row)
    e_after = best.e_after
    order = [j for j in terms if j != offset] or terms
    winner = names[order[0]] if order else None
    if winner is None:
        top = max((j for j in scores if j not in baselines), key=scores.__getitem__)
        message = (f"no candidate effect lowers the held-out error by more than "
                   f"{100 * margin:.0f} %; nothing added (best: {names[top]}, "
                   f"score {scores[top]:.3f})")
        if best.selection.chosen:
            message = (f"{names[best.selection.chosen[0]]} looked useful in cross-validation "
                       "but did not lower the held-out error; nothing added")
    else:
        parts = ", ".join(f"{names[j]} (gain {gains[j]:.1%})" for j in order if j in gains)
        message = (f"added {parts}; held-out RMSE {rmse_before:.4g} -> "
                   f"{_rms(e_after):.4g} %")
    plot = {}
    if winner is not None:
        plot = {"t": t_out, "e_before": e_out, "e_after": e_after, "g": g_out[:, order[0]],
                "s": s_out}
    return SensorDiagnosis(name=sensor, before=_rmse_stats(e_out), after=_rmse_stats(e_after),
                           scores=rows, added=added, message=message, plot=plot, winner=winner)


def diagnose(recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]],
             calibration: Calibration, *,
             validate_recordings: Mapping[str, Recording] | Sequence[Mapping[str, Recording]]
             | None = None, holdout_fraction: float = 0.3,
             candidates: Sequence[dict[str, Any]] | None = None, n_blocks: int = 10,
             margin: float = 0.03, max_effects: int = 3,
             tare: str = "calibration") -> DiagnoseResult:
    """Run the residual loop (module docstring) on every calibrated sensor with a reference.

    ``recordings``: one bag's recordings by sensor name, or a list of such (several bags).
    ``candidates``: effect dicts to test instead of ``default_candidates``. ``margin``: the
    least relative drop of the cross-validated RMSE for an effect to be added. ``tare``:
    ``calibration`` or ``auto`` (every run, fit and validation alike, tared at its start).
    """
    if not 0.0 < holdout_fraction < 1.0:
        raise InputError(f"holdout_fraction must be in (0, 1), got {holdout_fraction}")
    if n_blocks < 3:
        raise InputError(f"n_blocks must be >= 3, got {n_blocks}")
    bags = _as_bags(recordings)
    validate = None if validate_recordings is None else _as_bags(validate_recordings)
    base_fit = [_base_runs(b, calibration, tare=tare) for b in bags]
    base_val = (None if validate is None
                else [_base_runs(b, calibration, tare=tare) for b in validate])
    results: dict[str, SensorDiagnosis] = {}
    for sensor, cal in calibration.sensors.items():
        found = _diagnose_sensor(sensor, cal, bags, validate, base_fit, base_val or [],
                                 candidates, holdout_fraction, n_blocks, margin, max_effects)
        if found is not None:
            results[sensor] = found
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
                      "held_out_every": _holdout_period(holdout_fraction)}
    else:
        validated_on = "validate"
        validation = {"kind": "validation recordings",
                      "sensors": sorted({n for b in validate for n in b})}
    return DiagnoseResult(sensors=results, before=pooled_before, after=pooled_after,
                          validated_on=validated_on, validation=validation,
                          calibration=Calibration(sensors_out))


def _pool(results: Mapping[str, SensorDiagnosis], which: str) -> dict[str, float]:
    """RMSE and MAE pooled over every sensor's held-out samples."""
    n = sum(getattr(d, which)["n"] for d in results.values())
    sse = sum(getattr(d, which)["rmse"] ** 2 * getattr(d, which)["n"] for d in results.values())
    sae = sum(getattr(d, which)["mae"] * getattr(d, which)["n"] for d in results.values())
    return {"rmse": math.sqrt(sse / n), "mae": sae / n, "n": n}


def write_plots(result: DiagnoseResult, out_dir: str | Path) -> list[Path]:
    """Residual before and after against the winning regressor, time and strain (one PNG
    per sensor)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, d in result.sensors.items():
        if not d.plot:
            continue
        fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(16, 4.2))
        p = d.plot
        ax1.plot(p["g"], p["e_before"], ".", ms=2, alpha=0.4, label="before")
        ax1.plot(p["g"], p["e_after"], ".", ms=2, alpha=0.4, label="after")
        ax1.set_xlabel(f"regressor {d.winner}")
        ax1.set_ylabel("residual S_hat - S [%]")
        ax1.legend(markerscale=4)
        ax2.plot(p["t"], p["e_before"], ".", ms=2, label="before")
        ax2.plot(p["t"], p["e_after"], ".", ms=2, label="after")
        ax2.set_xlabel("time [s] (held-out samples)")
        ax2.set_ylabel("residual [%]")
        ax2.legend(markerscale=4)
        ax3.plot(p["s"], p["e_before"], ".", ms=2, alpha=0.4, label="before")
        ax3.plot(p["s"], p["e_after"], ".", ms=2, alpha=0.4, label="after")
        ax3.set_xlabel("reference strain [%] (held-out samples)")
        ax3.set_ylabel("residual [%]")
        ax3.legend(markerscale=4)
        fig.suptitle(f"{name}: {d.message}", fontsize=8)
        fig.tight_layout()
        path = out_dir / f"diagnose_{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def diagnose_bag(bag: str | Path, calibration: Calibration, *,
                 validate: str | Path | None = None, out: str | Path | None = None,
                 plots: str | Path | None = None, **options: Any) -> DiagnoseResult:
    """``strain-comp diagnose``: load the bag(s), diagnose, write CAL2 and the plots."""
    from strain_comp.diagnosis.conditions import diagnose_conditions

    recordings, _ = load_recordings(bag)
    val = None if validate is None else load_recordings(validate)[0]
    result = diagnose_conditions(recordings, calibration, validate_recordings=val,
                                 **options)
    if out is not None:
        save_calibration(result.calibration, out,
                         inputs=[p for p in (bag, validate) if p is not None])
    if plots is not None:
        write_plots(result, plots)
    return result
