"""The residual loop's selection statistics alone, on regressor matrices with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from strain_comp.diagnosis.selection import (
    Gram,
    candidate_scores,
    held_out_better,
    keep_on_held_out,
    linear_held_out,
    select_forward,
    significant,
)


def problem(seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Columns: 0 intercept, 1 the true effect, 2-4 unrelated; e = 0.5 + 2 g1 + noise."""
    rng = np.random.default_rng(seed)
    g = np.column_stack([np.ones(n), np.sin(np.linspace(0, 20, n)),
                         *(rng.standard_normal((3, n)))])
    e = 0.5 + 2.0 * g[:, 1] + 0.3 * rng.standard_normal(n)
    fold = np.repeat(np.arange(6), n // 6)
    return g, e, fold


def test_cross_validated_rmse_equals_a_direct_leave_one_fold_out_fit() -> None:
    g, e, fold = problem(0)
    gram = Gram(g, e, fold, 6)
    sse = 0.0
    for f in range(6):
        fit, test = fold != f, fold == f
        c = np.linalg.lstsq(g[fit][:, [0, 1]], e[fit], rcond=None)[0]
        sse += float(np.sum((e[test] - g[test][:, [0, 1]] @ c) ** 2))
    assert gram.cv_rmse([0, 1]) == pytest.approx(np.sqrt(sse / e.size), rel=1e-9)


def test_forward_selection_finds_the_true_effect_only() -> None:
    g, e, fold = problem(1)
    gram = Gram(g, e, fold, 6)
    selection = select_forward(gram, g.shape[1], 0, 0.03, 3)
    assert selection.chosen == [1]  # the intercept comes with it, not as a choice
    scores = candidate_scores(gram, g.shape[1], 0)
    assert scores[1] > 0.9 and max(scores[j] for j in (2, 3, 4)) < 0.01
    branch = keep_on_held_out(gram, selection, None, 0, 0.03, linear_held_out(e, g))
    assert sorted(branch.kept) == [0, 1]
    assert branch.coef[branch.kept.index(0)] == pytest.approx(0.5, abs=0.05)
    assert branch.coef[branch.kept.index(1)] == pytest.approx(2.0, abs=0.05)
    assert branch.rmse == pytest.approx(0.3, abs=0.02)


def test_forward_selection_honours_the_significance_asked_for() -> None:
    g, e, fold = problem(1)
    gram = Gram(g, e, fold, 6)
    assert select_forward(gram, g.shape[1], 0, 0.03, 3, sigmas=1.0).chosen == [1]
    # no fold-wise drop is a million standard errors above zero: nothing is chosen
    assert select_forward(gram, g.shape[1], 0, 0.03, 3, sigmas=1e6).chosen == []


def test_significance_rejects_a_gain_of_one_fold() -> None:
    before = np.full(6, 10.0)
    assert significant(before, before - 1.0 + 0.01 * np.arange(6), np.ones(6))
    lucky = before.copy()
    lucky[0] -= 6.0
    lucky[1:] += 1.0
    assert not significant(before, lucky, np.ones(6))


def test_several_validation_runs_decide_by_their_median() -> None:
    """A term that lowers the pooled validation error through one run while the others
    get worse is not kept; one that lowers most runs' errors is (one run: pooled only)."""
    runs = np.repeat([0, 1, 2], 100)
    old = np.concatenate([np.full(100, 10.0), np.ones(100), np.ones(100)])
    one_run = old * np.repeat([0.5, 1.1, 1.1], 100)
    most_runs = old * np.repeat([0.9, 0.9, 1.02], 100)
    assert held_out_better(one_run, old, 0.03)  # pooled alone, it would pass
    assert not held_out_better(one_run, old, 0.03, runs)
    assert held_out_better(most_runs, old, 0.03, runs)
    assert held_out_better(one_run[:100], old[:100], 0.03, np.zeros(100, dtype=int))
