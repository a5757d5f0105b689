"""Selection statistics of the residual loop (docs/design.md, "The loop's steps", 4-8) on any
regressor matrix, and their numbers (``LoopPolicy``; docs/results.md, "Residual loop")."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import t as student_t

from strain_comp._numba import njit


@dataclass(frozen=True)
class LoopPolicy:
    """How the loop decides (``studies/measured_diagnose.py --policy FIELD=VALUE`` varies it)."""

    margin: float = 0.03
    """[1, relative RMSE] least fall of the error for a term (or a condition) to count."""
    significance: float = 1.0
    """[standard errors over the folds] least fold-wise drop on the diagnosed run."""
    level: float = 0.95
    """[one-sided probability] of the prediction bound of one more run's log RMSE ratio."""
    tried: int = 16
    """[candidates per step] scored on the validation runs at each step."""
    max_effects: int = 3
    """[terms] the most terms one diagnosis adds to a sensor."""


LOOP_POLICY = LoopPolicy()
"""The product's policy."""


RESOLUTION = 1e-6
"""Selection stops below this fraction of the residual's RMSE: what is left is rounding."""


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


def column_std(g: np.ndarray) -> np.ndarray:
    """Each column's standard deviation (NaN, without numpy's warning, with no rows)."""
    return np.std(g, axis=0) if g.shape[0] else np.full(g.shape[1], np.nan)


class Gram:
    """Per-fold sums X'X, X'e, e'e: any subset's fit on some folds and error on the others."""

    def __init__(self, g: np.ndarray, e: np.ndarray, fold: np.ndarray, n_folds: int) -> None:
        std = column_std(g)
        self.scale = np.where(std > 0, std, 1.0)
        x = np.ascontiguousarray(g / self.scale)
        self.xx, self.xe, self.ee, self.n = _fold_sums(
            x, np.ascontiguousarray(e, dtype=np.float64), fold.astype(np.int64), n_folds)
        self.xx_all = self.xx.sum(axis=0)
        self.xe_all = self.xe.sum(axis=0)

    def solve(self, cols: Sequence[int]) -> np.ndarray:
        """Least-squares coefficients of ``cols`` on every fold, in the columns' own units."""
        if not cols:
            return np.zeros(0)
        idx = np.asarray(cols)
        folds = np.arange(self.n.size)
        a = self.xx[np.ix_(folds, idx, idx)].sum(axis=0)
        b = self.xe[np.ix_(folds, idx)].sum(axis=0)
        coef: np.ndarray = np.linalg.lstsq(a, b, rcond=1e-12)[0] / self.scale[idx]
        return coef

    def fold_sse(self, cols: Sequence[int]) -> np.ndarray:
        """Each fold's squared error under the fit on the others (0 for an empty fold)."""
        if not cols:
            return np.copy(self.ee)
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
        """Blocked cross-validated RMSE of e ~ X[:, cols] c; NaN without rows."""
        if not self.n.sum() > 0:
            return math.nan
        return math.sqrt(self.fold_sse(cols).sum() / self.n.sum())


def significant(before: np.ndarray, after: np.ndarray, n: np.ndarray,
                sigmas: float = LOOP_POLICY.significance) -> bool:
    """Is the fold-wise drop of the cross-validated squared error consistently > 0?"""
    d = (before - after)[n > 0]
    if d.size < 2:
        return bool(d.sum() > 0)
    return bool(d.mean() > sigmas * d.std(ddof=1) / math.sqrt(d.size))


def _gains(gram: Gram, trials: Mapping[int, np.ndarray], ref: np.ndarray, margin: float,
           sigmas: float = LOOP_POLICY.significance) -> dict[int, float]:
    """The gain over ``ref`` of each trial that is beyond ``margin`` and significant."""
    gains = {j: 1.0 - math.sqrt(after.sum() / ref.sum()) for j, after in trials.items()}
    return {j: gain for j, gain in gains.items()
            if gain > margin and significant(ref, trials[j], gram.n, sigmas)}


@dataclass
class Selection:
    chosen: list[int]
    gains: dict[int, float]


def select_forward(gram: Gram, n_cols: int, offset: int, margin: float, max_effects: int, *,
                   auto_intercept: bool = True, skip: Sequence[int] = (),
                   sigmas: float = LOOP_POLICY.significance) -> Selection:
    """Greedy forward selection (docs/design.md, "The loop's steps", 5)."""

    def model(cols: Sequence[int]) -> list[int]:
        return with_intercept(cols, offset) if auto_intercept else list(dict.fromkeys(cols))

    chosen: list[int] = []
    gains: dict[int, float] = {}
    current = gram.fold_sse([])
    floor = RESOLUTION ** 2 * current.sum()
    while len([c for c in chosen if c != offset]) < max_effects and current.sum() > floor:
        ref = current
        passing: dict[int, float] = {}
        if auto_intercept:
            ref = gram.fold_sse(model([*chosen, offset]))
            if offset not in chosen:
                passing = _gains(gram, {offset: ref}, current, margin, sigmas)
        if ref.sum() > 0:
            passing |= _gains(gram, {j: gram.fold_sse(model([*chosen, j]))
                                     for j in range(n_cols) if j not in chosen
                                     and j not in skip and not (auto_intercept and j == offset)},
                              ref, margin, sigmas)
        if not passing:
            break
        best = max(passing, key=passing.__getitem__)
        chosen.append(best)
        gains[best] = passing[best]
        current = gram.fold_sse(model(chosen))
    return Selection(chosen, gains)


def candidate_scores(gram: Gram, n_cols: int, offset: int) -> dict[int, float]:
    """First-round scores: held-out share of the residual variance each candidate explains."""
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


def with_intercept(cols: Sequence[int], offset: int) -> list[int]:
    """The columns of a model: ``cols`` plus the intercept once any other term is in."""
    cols = list(dict.fromkeys(cols))
    if any(c != offset for c in cols) and offset not in cols:
        cols.insert(0, offset)
    return cols


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


@dataclass
class Tried:
    """A candidate scored on the validation runs: its log RMSE ratios and their bound."""

    column: int
    fit_ratio: float
    log_ratios: list[float]
    bound: float


@dataclass
class Branch:
    """One hypothesis after selection and the held-out veto (``shift``: a baseline at coef 1)."""

    shift: int | None
    selection: Selection
    kept: list[int]
    coef: np.ndarray
    rmse: float
    refused: Tried | None = None


HeldOut = Callable[[Sequence[int], np.ndarray], np.ndarray]
"""The held-out residual of a set of terms: (columns, coefficients) -> errors."""


def linear_held_out(e: np.ndarray, g: np.ndarray) -> HeldOut:
    """``HeldOut`` of held-out residuals ``e`` and regressors ``g``: e - g[:, cols] c."""
    return lambda cols, coef: e - g[:, list(cols)] @ coef if len(cols) else e


def held_out_better(e_new: np.ndarray, e_old: np.ndarray, margin: float,
                    runs: np.ndarray | None = None) -> bool:
    """Does ``e_new`` lower the held-out RMSE (and the median run's) by more than ``margin``?"""
    if not rms(e_new) < (1.0 - margin) * rms(e_old):
        return False
    if runs is None or not e_new.size == e_old.size == runs.size or runs.max() < 1:
        return True
    ratios = [rms(e_new[runs == k]) / rms(e_old[runs == k]) for k in np.unique(runs)]
    return bool(np.median(ratios) < 1.0 - margin and max(ratios) <= 1.0 + margin)


def keep_on_held_out(gram: Gram, selection: Selection, shift: int | None, offset: int,
                     margin: float, held_out: HeldOut, runs: np.ndarray | None = None) -> Branch:
    """The held-out veto (docs/design.md, "The loop's steps", 6) on one branch's terms."""
    head = [] if shift is None else [shift]
    auto = shift is None

    def trial(cols: list[int]) -> tuple[np.ndarray, np.ndarray]:
        c = gram.solve(cols)
        return c, held_out([*head, *cols], np.concatenate([np.ones(len(head)), c]))

    kept: list[int] = []
    e_none = held_out([], np.zeros(0))
    current = e_none
    if shift is not None:
        e_shift = held_out(head, np.ones(1))
        if not held_out_better(e_shift, current, margin, runs):
            return Branch(None, selection, [], np.zeros(0), rms(e_none))
        current = e_shift
    for j in selection.chosen:
        cols = with_intercept([*kept, j], offset) if auto else [*kept, j]
        e_j = trial(cols)[1]
        helps = held_out_better(e_j, current, margin, runs)
        if auto and j != offset:  # it must also beat the intercept alone
            helps = helps and rms(e_j) < rms(trial(with_intercept([*kept, offset], offset))[1])
        if helps:  # one that does not is left out; the later ones are still tried
            kept, current = cols, e_j
    coef, e_after = trial(kept)
    return Branch(shift, selection, kept, coef, rms(e_after))


def upper_bound(log_ratios: Sequence[float], level: float) -> float:
    """The one-sided prediction bound at ``level`` of one more run's log RMSE ratio."""
    x = np.asarray(log_ratios, dtype=np.float64)
    if x.size < 2 or not np.all(np.isfinite(x)):
        return math.inf
    # Student's t: with two runs' sd the normal quantile would trust a spread they hardly show
    quantile = float(student_t.ppf(level, x.size - 1))
    return float(x.mean() + quantile * x.std(ddof=1) * math.sqrt(1.0 + 1.0 / x.size))


RunsHeldOut = Callable[[Sequence[int], np.ndarray], list[np.ndarray]]
"""``HeldOut`` kept apart by validation run (``session.SessionHeldOut.per_run``)."""


def run_log_ratios(e_new: Sequence[np.ndarray], e_old: Sequence[np.ndarray]) -> list[float]:
    """ln(RMSE new / RMSE old) of each run."""
    return [math.log(rms(a) / rms(b)) if rms(a) > 0 and rms(b) > 0 else math.inf
            for a, b in zip(e_new, e_old, strict=True)]


def _passing(gram: Gram, cols: list[int], offset: int, n_cols: int, skip: Sequence[int],
             policy: LoopPolicy) -> dict[int, float]:
    """The candidates that lower the cross-validated RMSE beyond the margin: their gain."""
    ref = gram.fold_sse(with_intercept([*cols, offset], offset))
    if not ref.sum() > RESOLUTION ** 2 * gram.ee.sum():
        return {}
    return _gains(gram, {j: gram.fold_sse(with_intercept([*cols, j], offset))
                         for j in range(n_cols) if j not in cols and j not in skip and j != offset},
                  ref, policy.margin, policy.significance)


def select_carried(gram: Gram, n_cols: int, offset: int, held_out: RunsHeldOut,
                   policy: LoopPolicy = LOOP_POLICY, skip: Sequence[int] = ()) -> Branch:
    """Greedy selection scored on the validation runs (docs/design.md, "The loop's steps", 8)."""
    chosen: list[int] = []
    gains: dict[int, float] = {}
    current = held_out([], np.zeros(0))
    coef = np.zeros(0)
    refused: Tried | None = None
    while len(chosen) < policy.max_effects:
        passing = _passing(gram, chosen, offset, n_cols, skip, policy)
        tried: list[tuple[Tried, np.ndarray, list[np.ndarray]]] = []
        for j in sorted(passing, key=passing.__getitem__, reverse=True)[:policy.tried]:
            cols = with_intercept([*chosen, j], offset)
            c = gram.solve(cols)
            e_j = held_out(cols, c)
            ratios = run_log_ratios(e_j, current)
            tried.append((Tried(j, math.log(1.0 - passing[j]), ratios,
                                upper_bound(ratios, policy.level)), c, e_j))
        if not tried:
            break
        best, c, e_j = min(tried, key=lambda x: (x[0].bound, float(np.mean(x[0].log_ratios))))
        if not best.bound < math.log(1.0 - policy.margin):
            refused = best
            break
        chosen.append(best.column)
        gains[best.column] = 1.0 - rms(np.concatenate(e_j)) / rms(np.concatenate(current))
        current, coef, refused = e_j, c, None
    kept = with_intercept(chosen, offset) if chosen else []
    return Branch(None, Selection(chosen, gains), kept, coef, rms(np.concatenate(current)),
                  refused)
