"""Property tests: every model, any finite positive input, through the engine.

Each model of ``MODEL_NAMES`` is fitted once (``fitted``) on a short simulated rig run
(random ramps and holds) by the same ``strain_comp.offline.fit.fit_sensor`` the command line uses,
so the calibrations carry a real valid range and direction settings. Hypothesis then
draws irregular but increasing times and positive resistances, and checks:

* the engine's strain is finite and inside the calibration's strain range widened by
  ``MARGIN`` (NaN only before the first sample the engine uses);
* the bare compensator is finite for every resistance the engine may feed it
  (between the short and open-circuit limits, ``SHORT_FACTOR`` / ``OPEN_FACTOR``);
* batch equals streaming, for the models (``run`` vs ``step``) and the engine, to 1e-9;
* ``reset`` restores the initial state (the same output as a fresh object);
* the direction detector stays at 0 when |dR/dt| stays below its dead zone.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from conftest import calibration_of, fitted, strain_bounds
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from strain_comp.base.direction import DirectionDetector, DirectionSettings
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR
from strain_comp.models import MODEL_NAMES

GAP_RESET = 5.0
EXPLORE = int(os.environ.get("STRAIN_COMP_EXPLORE", "0"))
"""Set to a number of examples to search further, with random seeds (not for CI)."""
PROPERTY = settings(max_examples=EXPLORE or 25, deadline=None, derandomize=not EXPLORE,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


@st.composite
def increasing_times(draw: st.DrawFn, n: int, *, max_dt: float) -> np.ndarray:
    """Irregular, strictly increasing times from an arbitrary start."""
    t0 = draw(st.sampled_from([0.0, 3.25, 1.7e9]))
    dts = draw(st.lists(st.floats(1e-3, max_dt), min_size=n, max_size=n))
    return t0 + np.cumsum(dts)


@st.composite
def model_input(draw: st.DrawFn, *, wide: bool) -> tuple[str, np.ndarray, np.ndarray]:
    """(model, t, r): r within the valid resistance range (and some way out of it), or with
    ``wide`` anywhere in (0, 1e12] ohm, log-uniform."""
    model = draw(st.sampled_from(MODEL_NAMES))
    n = draw(st.integers(1, 60))
    t = draw(increasing_times(n, max_dt=GAP_RESET if not wide else 3 * GAP_RESET))
    vr = fitted(model).valid_range
    if wide:
        exponents = draw(st.lists(st.floats(-6.0, 12.0), min_size=n, max_size=n))
        r = 10.0 ** np.array(exponents)
    else:
        u = draw(st.lists(st.floats(-0.5, 1.5), min_size=n, max_size=n))
        r = vr.r_lo + np.array(u) * (vr.r_hi - vr.r_lo)
        r = np.maximum(r, SHORT_FACTOR * vr.r_lo)
    return model, t, r


@pytest.fixture(scope="module", autouse=True)
def _fit_every_model() -> None:
    for model in MODEL_NAMES:
        fitted(model)


@PROPERTY
@given(data=st.one_of(model_input(wide=False), model_input(wide=True)))
def test_engine_strain_is_finite_and_inside_the_declared_range(data: tuple) -> None:
    model, t, r = data
    cal = fitted(model)
    lo, hi = strain_bounds(cal)
    out = Engine(calibration_of(model), gap_reset=GAP_RESET).run("s1", t, r)
    used = np.flatnonzero((out.status == 0) | (out.status >= 6))
    first = used[0] if used.size else t.size
    assert np.isnan(out.strain[:first]).all()
    held = out.strain[first:]
    assert np.isfinite(held).all(), (model, t, r, held)
    assert ((held >= lo) & (held <= hi)).all(), (model, held, lo, hi)
    assert set(np.unique(out.direction)) <= {-1, 0, 1}


@st.composite
def fed_input(draw: st.DrawFn) -> tuple[str, np.ndarray, np.ndarray]:
    """(model, t, r) with r anywhere the engine lets reach a model: between the short and
    open-circuit limits, log-uniform; steps no longer than the engine's gap reset."""
    model = draw(st.sampled_from(MODEL_NAMES))
    n = draw(st.integers(1, 60))
    t = draw(increasing_times(n, max_dt=GAP_RESET))
    vr = fitted(model).valid_range
    lo, hi = math.log10(SHORT_FACTOR * vr.r_lo), math.log10(OPEN_FACTOR * vr.r_hi)
    exponents = draw(st.lists(st.floats(lo, hi), min_size=n, max_size=n))
    return model, t, 10.0 ** np.array(exponents)


@PROPERTY
@given(data=fed_input())
def test_bare_compensator_is_finite_and_batch_equals_streaming(data: tuple) -> None:
    model, t, r = data
    batch = fitted(model).build_model().run(t, r)
    streaming_model = fitted(model).build_model()
    streaming = np.array([streaming_model.step(ti, ri) for ti, ri in zip(t, r, strict=True)])
    assert np.isfinite(batch).all(), (model, t, r, batch)
    np.testing.assert_allclose(batch, streaming, rtol=1e-9, atol=1e-9)


@PROPERTY
@given(first=fed_input(), second=st.data())
def test_model_reset_restores_the_initial_state(first: tuple, second: st.DataObject) -> None:
    model, t, r = first
    t2 = second.draw(increasing_times(30, max_dt=GAP_RESET))
    r2 = second.draw(st.lists(st.floats(0.0, 1.0), min_size=30, max_size=30))
    vr = fitted(model).valid_range
    r2 = vr.r_lo + np.array(r2) * (vr.r_hi - vr.r_lo)
    used = fitted(model).build_model()
    used.run(t, r)
    used.reset()
    after_reset = used.run(t2, r2)
    fresh = fitted(model).build_model().run(t2, r2)
    np.testing.assert_array_equal(after_reset, fresh)


@st.composite
def engine_stream(draw: st.DrawFn) -> tuple[str, np.ndarray, np.ndarray]:
    """(model, t, r) of any kind: good, out of range, NaN, inf, <= 0, open, short, repeated
    and backward times, long gaps and clock resets."""
    model, t, r = draw(model_input(wide=False))
    n = t.size
    vr = fitted(model).valid_range
    kinds = draw(st.lists(st.integers(0, 12), min_size=n, max_size=n))
    bad = {0: math.nan, 1: math.inf, 2: -math.inf, 3: 0.0, 4: -5.0,
           5: 1e3 * OPEN_FACTOR * vr.r_hi, 6: 0.1 * SHORT_FACTOR * vr.r_lo}
    r, t = r.copy(), t.copy()
    for i, kind in enumerate(kinds):
        if kind in bad:
            r[i] = bad[kind]
        elif kind == 7 and i > 0:
            t[i] = t[i - 1]  # repeated time stamp
        elif kind == 8 and i > 0:
            t[i:] -= draw(st.floats(0.0, 2.0 * GAP_RESET))  # back in time (bag loop)
        elif kind == 9 and i > 0:
            t[i:] += 2.0 * GAP_RESET  # long gap
    return model, t, r


@PROPERTY
@given(data=engine_stream(), cut=st.floats(0.0, 1.0))
def test_engine_batch_equals_streaming_and_reset(data: tuple, cut: float) -> None:
    model, t, r = data
    engine = Engine(calibration_of(model), gap_reset=GAP_RESET)
    steps = [engine.step("s1", ti, ri) for ti, ri in zip(t, r, strict=True)]
    streaming = np.array([o.strain for o in steps])
    batch_engine = Engine(calibration_of(model), gap_reset=GAP_RESET)
    k = int(cut * t.size)  # batch in two pieces continues where the first stopped
    parts = [batch_engine.run("s1", t[:k], r[:k]), batch_engine.run("s1", t[k:], r[k:])]
    batch = np.concatenate([p.strain for p in parts])
    np.testing.assert_allclose(batch, streaming, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(np.concatenate([p.status for p in parts]),
                                  [o.status for o in steps])
    np.testing.assert_array_equal(np.concatenate([p.direction for p in parts]),
                                  [o.direction for o in steps])
    assert batch_engine.health() == engine.health()
    engine.reset()
    again = engine.run("s1", t, r)
    fresh_engine = Engine(calibration_of(model), gap_reset=GAP_RESET)
    fresh = fresh_engine.run("s1", t, r)
    np.testing.assert_array_equal(again.strain, fresh.strain)
    np.testing.assert_array_equal(again.status, fresh.status)
    assert engine.health() == fresh_engine.health()


@PROPERTY
@given(deadzone=st.floats(1e-3, 1e3), tau=st.sampled_from([0.0, 0.01, 0.2, 1.0]),
       r0=st.floats(1.0, 1e4), dts=st.lists(st.floats(1e-3, 2.0), min_size=2, max_size=200),
       data=st.data())
def test_detector_never_leaves_hold_below_its_deadzone(deadzone: float, tau: float, r0: float,
                                                       dts: list, data: st.DataObject) -> None:
    rates = data.draw(st.lists(st.floats(-0.99, 0.99), min_size=len(dts), max_size=len(dts)))
    dt = np.array(dts)
    t = 10.0 + np.cumsum(dt)
    r = r0 + np.concatenate(([0.0], np.cumsum(np.array(rates[1:]) * deadzone * dt[1:])))
    detector = DirectionDetector(DirectionSettings(deadzone=deadzone, tau=tau))
    assert not detector.run(t, r).any()
