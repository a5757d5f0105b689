"""sinh_pl ([ReducedPL] eq. (1)-(3)) against a slow pure-Python reference."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy.optimize import brentq

from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.errors import ParameterError
from strain_comp.models.sinh_pl import SinhPL

NORM = Normalisation(r0=50.0, alpha=-3.0, s0=10.0, beta=-1.0)
DIRECTION = DirectionSettings(deadzone=1.0)


def cell_slow(u: float, e: float, dt: float, i_s: float, v_t: float) -> float:
    v = e - u
    g = i_s * (math.exp(v / v_t) - math.exp(-v / v_t))
    gp = 2 * i_s / v_t * math.cosh(v / v_t)
    return u + dt * g / (1 + dt * gp)


def forward_slow(t, psi, w0, vb, w, i_s, v_t):
    u = [psi[0]] * len(w)
    out = []
    for n in range(len(t)):
        if n:
            u = [cell_slow(u[k], psi[n], t[n] - t[n - 1], i_s[k], v_t[k]) for k in range(len(w))]
        out.append(w0 * psi[n] + sum(wk * uk for wk, uk in zip(w, u, strict=True)) - vb)
    return out


def resistance(m: SinhPL, t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """R [ohm] of the forward model eq. (2) (``forward_slow``) for strain s [%], from rest."""
    xi = forward_slow(t, m.normalisation.psi(s), m.w0, m.vb, m.w, m.i_s, m.v_t)
    return (np.asarray(xi) - m.normalisation.alpha) * m.normalisation.r0


def inverse_slow(t, xi, w0, vb, w, i_s, v_t):
    """Solve the discrete forward step for e with brentq (independent of Newton)."""
    e = (xi[0] + vb) / (w0 + sum(w))
    u = [e] * len(w)
    out = [e]
    for n in range(1, len(t)):
        dt = t[n] - t[n - 1]

        def h(e, u=u, dt=dt, n=n):
            return w0 * e + sum(w[k] * cell_slow(u[k], e, dt, i_s[k], v_t[k])
                                for k in range(len(w))) - vb - xi[n]

        e = brentq(h, -50, 50, xtol=1e-14, rtol=1e-15)
        u = [cell_slow(u[k], e, dt, i_s[k], v_t[k]) for k in range(len(w))]
        out.append(e)
    return out


def model(n_cells: int = 1) -> SinhPL:
    if n_cells == 1:
        return SinhPL(1.0, -0.2, [0.5], [0.05], [0.2], NORM)
    return SinhPL(1.0, -0.2, [0.4, 0.3], [0.05, 0.5], [0.2, 0.5], NORM)


def excitation(n: int = 20000, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * dt
    s = 10 + 9 * np.sin(2 * np.pi * 0.2 * t) * np.sin(2 * np.pi * 0.013 * t + 0.3)
    return t, s


@pytest.mark.parametrize("n_cells", [1, 2])
def test_kernels_match_reference(n_cells: int) -> None:
    m = model(n_cells)
    rng = np.random.default_rng(n_cells)
    t = np.cumsum(rng.uniform(0.001, 0.2, 200))
    psi = rng.uniform(-1, 1, 200)
    args = (m.w0, m.vb, list(m.w), list(m.i_s), list(m.v_t))
    s = NORM.strain(psi)
    r = resistance(m, t, s)
    xi = NORM.xi(r)
    np.testing.assert_allclose(NORM.psi(m.run(t, r)), inverse_slow(t, xi, *args), atol=1e-10)
    # the compensator is the exact inverse of the discrete forward model
    m.reset()
    np.testing.assert_allclose(m.run(t, r), s, atol=1e-9)


def test_step_equals_run_and_reset() -> None:
    m = model(2)
    t, s = excitation(2000)
    r = resistance(m, t, s) + np.random.default_rng(0).normal(0, 0.01, t.size)
    batch = m.run(t, r)
    m.reset()
    steps = np.array([m.step(a, b) for a, b in zip(t, r, strict=True)])
    np.testing.assert_allclose(steps, batch, rtol=0, atol=1e-9)
    m.reset()
    np.testing.assert_allclose(m.run(t, r), batch, rtol=0, atol=0)


@pytest.mark.parametrize("n_cells", [1, 2])
def test_fit_recovers_forward_model(n_cells: int) -> None:
    truth = model(n_cells)
    t, s = excitation(20000 if n_cells == 1 else 8000)
    r = resistance(truth, t, s)
    start = time.perf_counter()
    fitted = SinhPL.fit([Segment(t, r, s)], NORM, direction=DIRECTION, n_cells=n_cells)
    elapsed = time.perf_counter() - start
    t2 = np.arange(8000) * 0.01
    s2 = 10 + 8 * np.sin(2 * np.pi * 0.35 * t2)  # held out: another rate and pattern
    r2 = resistance(truth, t2, s2)
    rmse = float(np.sqrt(np.mean((fitted.run(t2, r2) - s2) ** 2)))
    print(f"sinh_pl N={n_cells}: fit {elapsed:.2f} s on {t.size} samples, held-out RMSE "
          f"{rmse:.2e} %")
    assert rmse < 0.01
    if n_cells == 1:
        got = fitted.to_params()
        for key, want in truth.to_params().items():
            np.testing.assert_allclose(got[key], want, rtol=1e-3)


def test_params_round_trip_and_errors() -> None:
    m = model(2)
    back = SinhPL.from_params(m.to_params(), NORM, direction=DIRECTION)
    assert back.to_params() == m.to_params()
    bad = dict(m.to_params(), v_t=[0.2, -1.0])
    with pytest.raises(ParameterError, match=r"v_t\.1"):
        SinhPL.from_params(bad, NORM, direction=DIRECTION)
    with pytest.raises(ParameterError, match="i_s"):
        SinhPL.from_params(dict(m.to_params(), i_s=[0.1]), NORM, direction=DIRECTION)
    with pytest.raises(ParameterError, match="w0"):
        SinhPL.from_params(dict(m.to_params(), w0=0.0), NORM, direction=DIRECTION)
