"""spike_decay ([Nanocomposite] eq. (3)/(4), Tables 2, 4, 5)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy.optimize import brentq

import strain_comp as sc
from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.errors import ParameterError
from strain_comp.models.spike_decay import SpikeDecay

NORM = Normalisation(1.0, 0.0, 1.0, 0.0)  # unused by this model
DIRECTION = DirectionSettings(deadzone=4.0, tau=0.05)


def truth_model(direction: DirectionSettings = DIRECTION) -> SpikeDecay:
    """f = 1000 + 80 eps + 2 eps^2 ohm on [0, 15] %; tables over 2 rates x 2 strains."""
    return SpikeDecay(knots=[0.0], c=[[1000.0, 80.0, 2.0, 0.0]], eps_range=(0.0, 15.0),
                      rates=[0.5, 5.0], strains=[2.5, 15.0],
                      s_table=[[[0.05, 0.1], [0.1, 0.2]], [[-0.03, -0.05], [-0.06, -0.1]]],
                      lam_table=[[[1.0, 1.5], [2.0, 3.0]], [[1.0, 1.5], [2.0, 3.0]]],
                      min_step=0.5, normalisation=NORM, direction=direction)


def staircase(rate: float, *, dt: float = 0.01, hold: float = 5.0, step: float = 2.5,
              top: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """Steps of ``step`` % at ``rate`` %/s up to ``top`` and back, ``hold`` s after each."""
    levels = np.arange(0.0, top + 1e-9, step)
    seq = [*levels[1:], *levels[::-1][1:]]
    knots_t, knots_s, now, cur = [0.0, hold], [0.0, 0.0], hold, 0.0
    for level in seq:
        now += abs(level - cur) / rate
        knots_t += [now, now + hold]
        knots_s += [level, level]
        now, cur = now + hold, level
    t = np.arange(0.0, now, dt)
    return t, np.interp(t, knots_t, knots_s)


def kernel_slow(m: SpikeDecay, t, r, deadzone, tau):
    """Pure-Python reading of the documented online inversion."""
    def f(e):
        i = max(k for k in range(m.knots.size) if k == 0 or e >= m.knots[k])
        d = e - m.knots[i]
        return sum(m.c[i, p] * d**p for p in range(4))

    def finv(rv):
        lo_v, hi_v = f(m.lo), f(m.hi)
        rising = hi_v > lo_v
        if (rv <= lo_v) == rising:
            return m.lo
        if (rv >= hi_v) == rising:
            return m.hi
        return brentq(lambda e: f(e) - rv, m.lo, m.hi, xtol=1e-13)

    def lookup(k, rate, eps):
        ax_r = np.log10(m.rates)
        x = math.log10(rate) if rate > 0 else -1e300
        vals = [np.interp(x, ax_r, m.s_table[k][:, j]) for j in range(m.strains.size)]
        lams = [np.interp(x, ax_r, m.lam_table[k][:, j]) for j in range(m.strains.size)]
        return np.interp(eps, m.strains, vals), np.interp(eps, m.strains, lams)

    out = []
    filt, prev_t, prev_rc = 0.0, None, None
    spike, lam, ts = 0.0, 1.0, 0.0
    moving, t_move, eps_move, t_ext, r_ext, rc_ext = 0, 0.0, 0.0, 0.0, 0.0, 0.0
    eps_last, t_last = 0.0, 0.0
    for tn, rn in zip(t, r, strict=True):
        if prev_t is None:
            prev_t, prev_rc = tn, rn
            eps = finv(rn)
        else:
            rc = rn / (1 + spike * math.exp(-lam * max(tn - ts, 0.0))) if spike else rn
            dt = tn - prev_t
            der = (rc - prev_rc) / dt
            filt = filt + (1 - math.exp(-dt / tau)) * (der - filt) if tau > 0 else der
            prev_t, prev_rc = tn, rc
            d = 1 if filt > deadzone else (-1 if filt < -deadzone else 0)
            if moving == 0 and d != 0:
                moving, t_move, eps_move = d, t_last, eps_last
                t_ext, r_ext, rc_ext = tn, rn, rc
            elif moving != 0 and (rc - rc_ext) * moving > 0:
                t_ext, r_ext, rc_ext = tn, rn, rc
            eps = finv(rc)
            if moving != 0 and d != moving:
                eps_end = finv(rc_ext)
                if abs(eps_end - eps_move) >= m.min_step:
                    for _ in range(3):
                        change = eps_end - eps_move
                        s_new, lam_new = lookup(0 if change >= 0 else 1,
                                                abs(change) / max(t_ext - t_move, 1e-9), eps_end)
                        eps_end = finv(r_ext / (1 + s_new))
                    spike, lam, ts = s_new, lam_new, t_ext
                    rc = rn / (1 + spike * math.exp(-lam * (tn - ts)))
                    eps = finv(rc)
                moving, filt, prev_rc = 0, 0.0, rc
        eps_last, t_last = eps, tn
        out.append(eps)
    return out


def test_kernel_matches_reference_and_step() -> None:
    m = truth_model()
    t, s = staircase(2.0, dt=0.02, hold=2.0, step=3.0, top=12.0)
    rng = np.random.default_rng(0)
    r = m.predict_resistance(t, s) + rng.normal(0, 0.3, t.size)
    batch = m.run(t, r)
    np.testing.assert_allclose(batch, kernel_slow(m, t, r, DIRECTION.deadzone, DIRECTION.tau),
                               atol=1e-9)
    m.reset()
    steps = np.array([m.step(a, b) for a, b in zip(t, r, strict=True)])
    np.testing.assert_allclose(steps, batch, rtol=0, atol=1e-9)
    m.reset()
    np.testing.assert_array_equal(m.run(t, r), batch)


def test_step_response_shape() -> None:
    m = truth_model()
    t = np.arange(0.0, 10.0, 0.001)
    s = np.interp(t, [0, 1, 2, 10], [0, 0, 5, 5])  # 5 % at 5 %/s, end at t = 2 s
    r = m.predict_resistance(t, s)
    spike, lam = m.spike(5.0, 5.0, loading=True)
    f_end = m.f(5.0)
    after = t >= 2.0
    rel = r[after] / f_end - 1.0
    assert r[after].max() == pytest.approx(f_end * (1 + spike))  # spike at the end of the move
    assert np.all(np.diff(rel) < 0) and rel[-1] < 1e-6 * spike  # decays toward f
    k = np.searchsorted(t, 2.0 + 1.0 / lam)
    assert rel[k - np.searchsorted(t, 2.0)] == pytest.approx(spike / math.e, rel=1e-2)
    # and the online inversion follows the step and removes the decay
    est = m.run(t, r)
    hold = t > 2.5
    assert np.max(np.abs(est[hold] - 5.0)) < 0.01


def test_fit_from_step_and_hold_then_held_out_rate() -> None:
    truth = truth_model()
    rng = np.random.default_rng(1)
    segs = []
    for rate in (0.5, 5.0):
        t, s = staircase(rate)
        segs.append(Segment(t, truth.predict_resistance(t, s) + rng.normal(0, 0.05, t.size), s))
    n = sum(seg.t.size for seg in segs)
    start = time.perf_counter()
    m = SpikeDecay.fit(segs, NORM, direction=DIRECTION)
    elapsed = time.perf_counter() - start
    grid = np.linspace(0, 15, 61)
    np.testing.assert_allclose(m.f(grid), truth.f(grid), rtol=2e-3)
    for rate in (0.5, 5.0):
        for eps in (2.5, 12.5):  # step ends present for both directions
            for loading in (True, False):
                got, want = m.spike(rate, eps, loading=loading), truth.spike(rate, eps,
                                                                            loading=loading)
                np.testing.assert_allclose(got, want, rtol=0.05, atol=2e-3)
    # held out: rate 1.5 %/s (between the table rows), 3 % steps
    t2, s2 = staircase(1.5, step=3.0)
    r2 = truth.predict_resistance(t2, s2) + rng.normal(0, 0.05, t2.size)
    rmse = float(np.sqrt(np.mean((m.run(t2, r2) - s2) ** 2)))
    f_only = np.interp(r2, m.f(np.linspace(0, 15, 1501)), np.linspace(0, 15, 1501))
    rmse_static = float(np.sqrt(np.mean((f_only - s2) ** 2)))
    print(f"spike_decay: fit {elapsed:.2f} s on {n} samples; held-out RMSE {rmse:.3f} % "
          f"(quasi-static f only: {rmse_static:.3f} %)")
    assert rmse < 0.7 * rmse_static


def test_fit_without_holds_is_quasi_static() -> None:
    t = np.arange(0, 60, 0.01)
    s = 7.5 + 7.5 * np.sin(2 * np.pi * 0.1 * t)
    truth = truth_model()
    r = truth.f(s)
    m = SpikeDecay.fit([Segment(t, r, s)], NORM, direction=DIRECTION)
    assert not np.any(m.s_table)
    assert float(np.sqrt(np.mean((m.run(t, r) - s) ** 2))) < 0.1


def test_non_monotone_f_is_inverted_on_its_monotone_branch() -> None:
    # carbon-black like: R falls to 2 % strain, then rises (a shoulder)
    eps = np.array([0.0, 1.0, 2.0, 4.0, 6.0, 8.0, 10.0])
    r = np.array([1000.0, 980.0, 975.0, 1000.0, 1040.0, 1090.0, 1150.0])
    segs = []
    t_all, s_all = [], []
    now = 0.0
    for e in eps:
        t_all.append(now + np.arange(0, 3, 0.01))
        s_all.append(np.full(300, e))
        now += 3.0
    t = np.concatenate(t_all)
    s = np.concatenate(s_all)
    segs.append(Segment(t, np.interp(s, eps, r), s))
    m = SpikeDecay.fit(segs, NORM, direction=DIRECTION)
    assert (m.lo, m.hi) == (2.0, 10.0)
    est = m.run(np.arange(3) * 0.1, [1090.0, 1090.0, 900.0])
    assert est[0] == pytest.approx(8.0, abs=1e-6) and est[2] == 2.0  # below f(lo): clamped


def test_two_point_recalibration_maps_a_scaled_sensor_back() -> None:
    # the paper's recalibration of another sensor of the same make (f_new = a f + b) at 0 %
    # and 15 %: two points through the calibration's input correction
    m = truth_model()
    new_f = lambda e: 1.3 * m.f(e) - 250.0  # noqa: E731  another sensor of the same make
    cal = Calibration({"s1": SensorCalibration(
        name="s1", model="spike_decay", params=m.to_params(), normalisation=NORM,
        valid_range=ValidRange(1000.0, 2650.0, 0.0, 15.0), direction=DIRECTION)})
    points = [(float(new_f(0.0)), 0.0), (float(new_f(15.0)), 15.0)]
    new = sc.recalibrate(cal, points=points, form="input").calibration
    grid = np.linspace(0, 15, 31)
    est = sc.estimate(new, np.arange(grid.size) * 10.0, new_f(grid))  # 10 s apart: holds
    np.testing.assert_allclose(est.strain, grid, atol=1e-9)


def test_params_round_trip_and_errors() -> None:
    m = truth_model()
    back = SpikeDecay.from_params(m.to_params(), NORM, direction=DIRECTION)
    assert back.to_params() == m.to_params()
    for key, value, field in (("lambda_unloading", [[1.0, 1.0], [1.0, -2.0]], "lambda_unloading"),
                              ("S_loading", [[0.1, 0.1]], "S_loading"),
                              ("c", [[1000.0, -80.0, 8.0, 0.0]], "c"),
                              ("rates", [5.0, 0.5], "rates"),
                              ("min_step", -1.0, "min_step")):
        params = dict(m.to_params(), **{key: value})
        with pytest.raises(ParameterError, match=field):
            SpikeDecay.from_params(params, NORM, direction=DIRECTION)
    params = m.to_params()
    del params["knots"]
    with pytest.raises(ParameterError, match="knots"):
        SpikeDecay.from_params(params, NORM, direction=DIRECTION)
