"""Cubic baseline ([Electrolycra] eq. (4)) against the equation computed directly."""

from __future__ import annotations

import numpy as np
import pytest

from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.errors import ParameterError
from strain_comp.models.cubic import Cubic

DIRECTION = DirectionSettings(deadzone=0.0)
PAPER_C = [-69.5, 7.816, -0.2112, 0.003512]  # c0..c3 of the paper, ohm units
NORM = Normalisation(r0=7.16, alpha=-2.61, s0=25.0, beta=-1.0)


def eq4(r, c):
    c0, c1, c2, c3 = c
    return [c3 * v ** 3 + c2 * v ** 2 + c1 * v + c0 for v in r]


def test_run_and_step_are_eq4():
    r = np.linspace(10.0, 30.0, 101)
    model = Cubic(PAPER_C, NORM)
    np.testing.assert_allclose(model.run(np.arange(r.size), r), eq4(r, PAPER_C), rtol=1e-12)
    np.testing.assert_allclose([model.step(0.0, v) for v in r], eq4(r, PAPER_C), rtol=1e-12)


def test_fit_recovers_known_coefficients():
    rng = np.random.default_rng(0)
    r = rng.uniform(11.0, 26.0, 500)
    s = np.array(eq4(r, PAPER_C))
    norm = Normalisation.fit(r, s)
    half = r.size // 2
    segments = [Segment(np.arange(half), r[:half], s[:half]),
                Segment(np.arange(r.size - half), r[half:], s[half:])]
    model = Cubic.fit(segments, norm, direction=DIRECTION)
    np.testing.assert_allclose(model.c, PAPER_C, rtol=1e-6)


def test_params_round_trip_and_errors():
    model = Cubic(PAPER_C, NORM)
    again = Cubic.from_params(model.to_params(), NORM, direction=DIRECTION)
    assert again.to_params() == model.to_params() == {"c": PAPER_C}
    for bad in ({}, {"c": [1.0, 2.0]}, {"c": [1.0, "x", 2.0, 3.0]}, {"c": [1, 2, 3, np.nan]}):
        with pytest.raises(ParameterError):
            Cubic.from_params(bad, NORM, direction=DIRECTION)
