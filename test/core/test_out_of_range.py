"""Beyond the calibrated range: ``Engine(out_of_range="extend")`` against the truth.

Truth is the strain of a synthetic sensor whose resistance law is known (linear, power
law, a carbon-black-like law whose resistance peaks and falls), calibrated on part of its
stroke with ``strain-comp fit``'s code and used beyond it; and, for the bounds, the
definition of the extension (``core.range_policy.bounded_slopes``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from conftest import R_HI, R_LO, S_HI, S_LO, calibration_of, cubic_cal, engine_of

from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import DEFAULT_OUT_OF_RANGE, EXTEND_REACH, EXTEND_SLOPE, MARGIN
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import fit_sensor


def triangles(peak: float, cycles: int = 3, rate: float = 10.0, fs: float = 50.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """Time [s] and strain [%] of ``cycles`` triangles from 0 to ``peak`` at ``rate`` %/s."""
    period = 2.0 * peak / rate
    t = np.arange(0.0, cycles * period, 1.0 / fs)
    return t, peak * (1.0 - np.abs(2.0 * (t % period) / period - 1.0))


def calibrated(law: Callable[[np.ndarray], np.ndarray], peak: float, model: str
               ) -> SensorCalibration:
    t, s = triangles(peak)
    r = law(s) + np.random.default_rng(0).normal(0.0, 0.02, s.size)
    return fit_sensor([Recording("s1", t, r, s)], model, name="s1")


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


@pytest.mark.parametrize(("law", "model", "tol"), [
    (lambda e: 100.0 * (1.0 + 0.02 * e), "cubic", 0.1),
    (lambda e: 100.0 * (1.0 + 0.02 * e), "mpi", 0.1),
    (lambda e: 100.0 * (1.0 + 0.01 * e ** 1.3), "cubic", 3.0),
    (lambda e: 100.0 * (1.0 + 0.01 * e ** 1.3), "mpi", 1.5),
])
def test_a_sensor_calibrated_to_20_percent_is_read_to_40(
        law: Callable[[np.ndarray], np.ndarray], model: str, tol: float) -> None:
    """Calibrated on 0-20 %, used on 0-40 %: a linear sensor is read to within 0.1 %
    (strain), a power-law one (its slope grows, the map's end slope falls short) to within
    ``tol`` RMSE, where the clamp is off by up to 18 %; flagged as in clamp mode."""
    cal = calibrated(law, 20.0, model)
    t, s = triangles(40.0)
    r = law(s)
    clamped = engine_of(cal, out_of_range="clamp").run("s1", t, r)
    extended = engine_of(cal, out_of_range="extend").run("s1", t, r)
    assert rmse(clamped.strain, s) > 6.0
    assert rmse(extended.strain, s) < tol
    np.testing.assert_array_equal(extended.out_of_range, clamped.out_of_range)
    assert extended.out_of_range[s > 25.0].all()


def test_past_a_resistance_peak_the_extension_does_not_run_away() -> None:
    """A carbon-black-like strip (R peaks at 20 % and falls), calibrated on 0-30 %, is
    used when it has become 15 % more sensitive: R passes the calibrated top while the
    strain does not. The cubic's map turns back at that end, so ``extend`` adds nothing
    there and its model reads the range's end: no worse than the clamp; the end slope
    (``extrapolate``) reads worse."""
    def law(e: np.ndarray) -> np.ndarray:
        return 100.0 * (1.0 + 0.04 * e - 0.001 * e ** 2)

    cal = calibrated(law, 30.0, "cubic")
    t, s = triangles(30.0)
    r = 100.0 + 1.15 * (law(s) - 100.0)
    errors = {mode: rmse(engine_of(cal, out_of_range=mode).run("s1", t, r).strain, s)
              for mode in ("clamp", "extrapolate", "extend")}
    assert errors["extend"] <= errors["clamp"] + 1e-9
    assert errors["extend"] < errors["extrapolate"]


def test_a_steep_end_is_held_to_twice_the_secant_and_the_reach() -> None:
    """A map whose end slope is far steeper than its secant (the end-slope runaway):
    the extension beyond the top uses ``EXTEND_SLOPE[1]`` x the secant and stops at
    ``EXTEND_REACH`` strain spans above the range, where ``extrapolate`` keeps going."""
    # S = -12 + 0.56 (R - 100) + k (R - 100)^2 (R - 200), written as a cubic in R
    k = 2e-4
    c = np.polynomial.polynomial.polyadd(
        np.polynomial.polynomial.polyfromroots([100.0, 100.0, 200.0]) * k,
        [-12.0 - 56.0, 0.56])
    cal = cubic_cal(params={"c": c.tolist()}, valid_range=ValidRange(R_LO, R_HI, -12.0, 44.0))
    engine = engine_of(cal, out_of_range="extend")
    span = R_HI - R_LO
    r_top, r_bottom = R_HI + MARGIN * span, R_LO - MARGIN * span  # the flag's edges
    cubic = np.polynomial.polynomial.Polynomial(c)
    secant = (cubic(r_top) - cubic(r_bottom)) / (r_top - r_bottom)
    end = cubic.deriv()(r_top)
    out = engine.run("s1", [0.0, 0.1, 0.2], [r_top, r_top + 10.0, r_top + 1000.0]).strain
    slope = (out[1] - out[0]) / 10.0
    assert end > 2.0 * EXTEND_SLOPE[1] * secant
    assert slope == pytest.approx(EXTEND_SLOPE[1] * secant)
    assert out[0] == pytest.approx(min(cubic(r_top), 44.0 + MARGIN * 56.0))
    assert out[2] == pytest.approx(44.0 + EXTEND_REACH * 56.0)
    runaway = engine_of(cal, out_of_range="extrapolate").run("s1", [0.0], [r_top + 1000.0])
    assert runaway.strain[0] > 10.0 * out[2]


def test_below_the_range_the_estimate_extends_to_zero_strain_at_most() -> None:
    """A resistance under the calibrated range: a calibration that starts at rest (its
    strain range reaches 0) reads its floor as the clamp does (a moved rest level is not
    read as compression); one fitted on 10-50 % extends down, but not past 0 %."""
    at_rest = engine_of(cubic_cal(), out_of_range="extend").run("s1", [0.0], [R_LO * 0.8])
    clamped = engine_of(cubic_cal(), out_of_range="clamp").run("s1", [0.0], [R_LO * 0.8])
    assert at_rest.strain[0] == pytest.approx(clamped.strain[0])
    assert S_LO <= 0.0
    pre = cubic_cal(valid_range=ValidRange(R_LO, R_HI, 10.0, S_HI))
    near = engine_of(pre, out_of_range="extend").run("s1", [0.0], [R_LO - 10.0]).strain[0]
    far = engine_of(pre, out_of_range="extend").run("s1", [0.0], [R_LO - 90.0]).strain[0]
    floor = engine_of(pre, out_of_range="clamp").run("s1", [0.0], [R_LO - 10.0]).strain[0]
    assert 0.0 < near < floor
    assert far == pytest.approx(0.0)


def test_an_array_on_the_fused_kernel_extends_as_each_sensor_alone() -> None:
    """APL sensors of an array keep the fused kernel with ``extend`` (the default) and
    give, in and out of range, what each sensor gives through ``step``."""
    apl = calibration_of("apl").sensors["s1"]
    cal = Calibration({n: SensorCalibration(**{**vars(apl), "name": n}) for n in ("a", "b")})
    vr = apl.valid_range
    fused = Engine(cal, arrays={"arr": ["a", "b"]})
    alone = Engine(cal)
    assert DEFAULT_OUT_OF_RANGE == "extend" and fused._arrays["arr"].fused
    t = np.arange(60) * 0.02
    r = vr.r_lo + (vr.r_hi - vr.r_lo) * np.stack([1.6 * np.sin(t) ** 2 - 0.3,
                                                  np.linspace(1.4, -0.4, t.size)], axis=1)
    for ti, row in zip(t, r, strict=True):
        out = fused.step_array("arr", ti, row)
        one = [alone.step(n, ti, v) for n, v in zip(("a", "b"), row, strict=True)]
        np.testing.assert_allclose(out.strain, [o.strain for o in one], rtol=1e-9, atol=1e-9)
        assert list(out.out_of_range) == [o.out_of_range for o in one]
    assert fused.health()["a"].n_out_of_range > 5


def test_the_margin_and_reach_set_the_limits(monkeypatch: pytest.MonkeyPatch) -> None:
    """``SensorRange.build`` with another margin and reach (read when called, as
    studies/policy_ablation.py sets them): the flag's edges widened by that share of the
    span, the extension reaching that many strain spans above the calibrated strain (the
    definitions, docs/design.md "Out of range")."""
    from strain_comp.core import range_policy

    cal = cubic_cal()
    vr = cal.valid_range
    default_reach = range_policy.SensorRange.build(cal, "extend", cal.build_model()).reach[1]
    assert default_reach == pytest.approx(vr.s_hi + EXTEND_REACH * (vr.s_hi - vr.s_lo))
    monkeypatch.setattr(range_policy, "MARGIN", 0.1)
    monkeypatch.setattr(range_policy, "EXTEND_REACH", 0.5)
    limits = range_policy.SensorRange.build(cal, "extend", cal.build_model())
    assert limits.r_hi == pytest.approx(vr.r_hi + 0.1 * (vr.r_hi - vr.r_lo))
    assert limits.s_lo == pytest.approx(vr.s_lo - 0.1 * (vr.s_hi - vr.s_lo))
    assert limits.reach[1] == pytest.approx(vr.s_hi + 0.5 * (vr.s_hi - vr.s_lo))
