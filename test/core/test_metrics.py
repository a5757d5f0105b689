"""Error metrics and the normalised hysteresis area ([ReducedPL] eq. (5))."""

from __future__ import annotations

import math

import pytest

from strain_comp.core.metrics import error_stats


def test_error_stats_hand_computed() -> None:
    est = [1.0, 3.0, 3.0, 5.0, math.nan]
    ref = [1.0, 2.0, 4.0, 5.0, 7.0]
    stats = error_stats(est, ref)
    # errors 0, 1, -1, 0 over the 4 finite pairs; reference mean 3, SS_tot = 10
    assert stats.n == 4
    assert stats.rmse == pytest.approx(math.sqrt(0.5))
    assert stats.mae == pytest.approx(0.5)
    assert stats.max_abs == pytest.approx(1.0)
    assert stats.r2 == pytest.approx(1.0 - 2.0 / 10.0)
    assert stats.to_dict() == {"rmse": stats.rmse, "mae": 0.5, "max_abs": 1.0, "r2": stats.r2,
                               "n": 4}


def test_error_stats_without_finite_pairs() -> None:
    stats = error_stats([math.nan], [1.0])
    assert stats.n == 0 and math.isnan(stats.rmse)

