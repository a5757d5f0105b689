"""rat22 ([EGaIn] eq. (10)) combined and split by the direction detector."""

from __future__ import annotations

import time

import numpy as np
import pytest

from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import STATE_SIZE, DirectionSettings
from strain_comp.errors import FitError, ParameterError
from strain_comp.models.rational import Rational, fit_rat22, rational_kernel

DIRECTION = DirectionSettings(deadzone=0.05, tau=0.05)


def rational_slow(t, xi, coef, split, deadzone, tau):
    """Per-sample reference: detector on xi, branch = last moving direction."""
    out, filt, row = [], 0.0, 0
    for n in range(len(t)):
        if split and n:
            dt = t[n] - t[n - 1]
            d = (xi[n] - xi[n - 1]) / dt
            filt = filt + (1 - np.exp(-dt / tau)) * (d - filt) if tau > 0 else d
            if filt > deadzone:
                row = 1
            elif filt < -deadzone:
                row = 2
        p1, p2, p3, q1, q2 = coef[row]
        x = xi[n]
        out.append((p1 * x * x + p2 * x + p3) / (x * x + q1 * x + q2))
    return out


def hysteretic_data(n: int = 20000, seed: int = 0, freq: float = 0.05):
    """Loading and unloading branches that differ (R in ohm, S in %)."""
    t = np.arange(n) * 0.01
    s = 50 + 45 * np.sin(2 * np.pi * freq * t)
    rising = np.gradient(s, t) > 0
    r = 2.0 + 0.03 * s + 2e-4 * s**2 + np.where(rising, -0.05, 0.05) * np.sin(np.pi * s / 100)
    return t, r + np.random.default_rng(seed).normal(0, 1e-4, n), s


def test_kernel_matches_reference_and_step() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.02, 400))
    r = 3.0 + np.cumsum(rng.normal(0, 0.003, 400))
    norm = Normalisation.from_ranges(float(r.min()), float(r.max()), 0.0, 1.0)
    coef = {"combined": [1.0, 2.0, 3.0, 0.5, 4.0], "loading": [0.5, 2.5, 3.0, 0.1, 5.0],
            "unloading": [1.5, 1.0, 2.0, 0.0, 3.0]}
    for mode in ("combined", "split"):
        m = Rational(coef, mode, norm, DIRECTION)
        batch = m.run(t, r)
        rows = [coef[k] for k in ("combined", "loading", "unloading")]
        slow = rational_slow(t, norm.xi(r), rows, mode == "split", DIRECTION.deadzone / norm.r0,
                             DIRECTION.tau)
        np.testing.assert_allclose(batch, slow, rtol=1e-12)
        m.reset()
        steps = [m.step(a, b) for a, b in zip(t, r, strict=True)]
        np.testing.assert_allclose(steps, batch, rtol=0, atol=1e-9)


def test_fit_recovers_exact_rat22() -> None:
    xi = np.linspace(-1, 1, 500)
    coef = np.array([2.0, -1.0, 3.0, 0.5, 4.0])
    s = (coef[0] * xi**2 + coef[1] * xi + coef[2]) / (xi**2 + coef[3] * xi + coef[4])
    np.testing.assert_allclose(fit_rat22(xi, s, guard=(-1.1, 1.1)), coef, rtol=1e-6)


def test_pole_guard_rejects_a_pole_in_range() -> None:
    xi = np.linspace(-1, 1, 400)
    xi = xi[np.abs(xi - 0.3) > 0.05]
    s = (xi**2 + 1) / ((xi - 0.3) * (xi + 2))  # the best rat22 has a pole at 0.3
    lin, *_ = np.linalg.lstsq(np.column_stack([xi**2, xi, np.ones_like(xi), -s * xi, -s]),
                              s * xi**2, rcond=None)
    assert np.min(np.abs(np.roots([1.0, lin[3], lin[4]]) - 0.3)) < 1e-6
    coef = fit_rat22(xi, s, guard=(-1.1, 1.1))
    roots = np.roots([1.0, coef[3], coef[4]])
    real = roots[np.abs(roots.imag) < 1e-12].real
    assert np.all((real < -1.1) | (real > 1.1))
    assert np.all(np.isfinite(Rational({"combined": coef}, "combined",
                                       Normalisation(1.0, 0.0, 1.0, 0.0), DIRECTION).run(xi, xi)))


def test_split_beats_combined_on_hysteresis() -> None:
    t, r, s = hysteretic_data()
    norm = Normalisation.fit(r, s)
    seg = [Segment(t, r, s)]
    results = {}
    for mode in ("combined", "split"):
        start = time.perf_counter()
        m = Rational.fit(seg, norm, direction=DIRECTION, mode=mode)
        elapsed = time.perf_counter() - start
        t2, r2, s2 = hysteretic_data(8000, seed=1, freq=0.07)  # held out
        results[mode] = float(np.sqrt(np.mean((m.run(t2, r2) - s2) ** 2)))
        print(f"rational {mode}: fit {elapsed:.2f} s on {t.size} samples, held-out RMSE "
              f"{results[mode]:.3f} %")
    assert results["split"] < 0.5 * results["combined"]


def test_params_round_trip_and_errors() -> None:
    t, r, s = hysteretic_data(6000)
    norm = Normalisation.fit(r, s)
    m = Rational.fit([Segment(t, r, s)], norm, direction=DIRECTION, mode="split")
    back = Rational.from_params(m.to_params(), norm, direction=DIRECTION)
    assert back.to_params() == m.to_params()
    m.reset()
    np.testing.assert_array_equal(back.run(t, r), m.run(t, r))
    params = m.to_params()
    params["unloading"] = {"p": [1.0, 2.0], "q": [0.0, 1.0]}
    with pytest.raises(ParameterError, match=r"unloading\.p"):
        Rational.from_params(params, norm, direction=DIRECTION)
    with pytest.raises(ParameterError, match="mode"):
        Rational.from_params({"mode": "both"}, norm, direction=DIRECTION)
    with pytest.raises(FitError, match="falling"):
        up = slice(0, 500)  # only a rising quarter wave
        Rational.fit([Segment(t[up], r[up], s[up])], norm, direction=DIRECTION, mode="split")


def test_analytic_jacobians_match_finite_differences() -> None:
    from strain_comp.models.rational import _eval, _free, _jac, _jac_free

    def approx_derivative(f, v: np.ndarray, h: float = 1e-6) -> np.ndarray:
        steps = np.eye(v.size) * h
        return np.column_stack([(f(v + e) - f(v - e)) / (2 * h) for e in steps])

    x = np.linspace(0.3, 2.0, 50)
    coef = np.array([0.7, -1.2, 3.0, 0.4, 2.5])
    np.testing.assert_allclose(_jac(coef, x), approx_derivative(lambda c: _eval(c, x), coef),
                               rtol=1e-6, atol=1e-9)
    z = np.array([0.7, -1.2, 3.0, -0.8, 0.3])
    np.testing.assert_allclose(_jac_free(z, x),
                               approx_derivative(lambda v: _eval(_free(v), x), z),
                               rtol=1e-6, atol=1e-9)


def test_a_sample_on_a_pole_reads_nan_instead_of_raising() -> None:
    """Found by scripts/fuzz.py: a mutated calibration whose denominator q2 is 0 put a pole
    at xi = 0; the engine's range probe hit it exactly and numba raised ZeroDivisionError
    through the loader. On a pole the kernel now gives NaN (screened like any non-finite
    strain); next to it the strain is the rational's own value."""
    coef = np.tile([1.0, 2.0, 3.0, 1.0, 0.0], (3, 1))  # den = (xi + 1) xi
    xi = np.array([0.0, 0.5])
    out = rational_kernel(np.zeros(STATE_SIZE + 1), np.array([0.0, 0.1]), xi, coef,
                          False, 0.0, 0.1)
    assert np.isnan(out[0])
    assert out[1] == pytest.approx((0.25 + 1.0 + 3.0) / (1.5 * 0.5))
