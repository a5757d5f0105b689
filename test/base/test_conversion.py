"""Voltage-divider input conversion ([Electrolycra] section II.A)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from strain_comp.base import samples as sc
from strain_comp.base.conversion import (
    divider_all,
    divider_ohm,
    divider_to_resistance,
    resistance_to_divider,
)


@settings(max_examples=100, deadline=None)
@given(st.floats(1e-2, 1e7), st.floats(1.0, 1e6), st.floats(0.5, 24.0))
def test_divider_round_trip(r: float, r1: float, vin: float) -> None:
    v = resistance_to_divider(r, r1, vin)
    assert float(divider_to_resistance(v, r1, vin)) == pytest.approx(r, rel=1e-6)


def test_hand_computed_reading() -> None:
    # R1 = 1 kohm, Vin = 5 V, 1 V across R1: R = 1000 * (5 - 1) / 1 = 4 kohm
    assert float(divider_to_resistance(1.0, 1000.0, 5.0)) == 4000.0
    assert float(resistance_to_divider(4000.0, 1000.0, 5.0)) == 1.0


def test_bad_readings_give_nan() -> None:
    v = np.array([0.0, -0.1, 5.0, 5.5, math.nan, math.inf, 2.5])
    r = divider_to_resistance(v, 1000.0, 5.0)
    assert np.all(np.isnan(r[:-1]))
    assert r[-1] == 1000.0


def test_divider_ohm_is_the_divider_formula_and_flags_open_and_short() -> None:
    v = np.concatenate([np.random.default_rng(7).uniform(-1.0, 6.0, 500),
                        [0.0, 5.0, np.nan, np.inf]])
    ohm, forced = divider_all(v, 1000.0, 5.0)
    with np.errstate(all="ignore"):
        formula = np.where((v > 0.0) & (v < 5.0), 1000.0 * (5.0 - v) / v, np.nan)
    np.testing.assert_array_equal(ohm, formula)
    expected = np.where(v <= 0.0, sc.OPEN_CIRCUIT, np.where(v >= 5.0, sc.SHORT_CIRCUIT, sc.GOOD))
    np.testing.assert_array_equal(forced, expected)
    for x, o, f in zip(v.tolist(), ohm.tolist(), forced.tolist(), strict=True):
        one, flag = divider_ohm(x, 1000.0, 5.0)
        assert flag == f and (one == o or (math.isnan(one) and math.isnan(o)))
