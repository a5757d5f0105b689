"""Error metrics and the normalised hysteresis area ([ReducedPL] eq. (5))."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strain_comp.core.metrics import error_stats, hysteresis_area


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


@pytest.mark.parametrize("phi", [0.3, 1.0, math.pi / 2])
def test_hysteresis_area_of_an_ellipse(phi: float) -> None:
    n_periods = 3
    theta = np.linspace(0.0, 2 * np.pi * n_periods, 30001)
    x = 5.0 + 2.0 * np.cos(theta)  # offsets and scales vanish in the min-max normalisation
    y = -1.0 + 0.5 * np.cos(theta - phi)
    # the loop of (cos t, cos(t - phi)) encloses pi sin(phi), counter-clockwise for phi > 0;
    # min-max normalisation scales both axes by 1/2
    want = math.pi * math.sin(phi) / 4.0
    assert hysteresis_area(x, y, n_periods) == pytest.approx(want, rel=1e-4)
    assert hysteresis_area(x[::-1], y[::-1], n_periods) == pytest.approx(-want, rel=1e-4)


def test_hysteresis_area_of_a_single_valued_curve_is_zero() -> None:
    theta = np.linspace(0.0, 4 * np.pi, 2001)
    x = np.cos(theta)
    assert hysteresis_area(x, x**3, 2) == pytest.approx(0.0, abs=1e-12)
