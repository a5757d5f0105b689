"""Voltage-divider input conversion ([Electrolycra] section II.A)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from strain_comp.base.conversion import divider_to_resistance, resistance_to_divider


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
