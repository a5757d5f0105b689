"""APL / PL / MPI ([Electrolycra] eq. (1)-(3), (6)) against slow pure-Python references,
fitting, and the paper's qualitative claims on a simulated rate-dependent sensor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.errors import FitError, InputError, ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models import model_class, pwa
from strain_comp.models.apl import APL, MPI, PL, APLArray
from strain_comp.models.cubic import Cubic
from strain_comp.offline.fit import check_training_span
from strain_comp.offline.options import check_fit_options

DIRECTION = DirectionSettings(deadzone=0.0)
NORM = Normalisation(r0=7.16, alpha=-2.61, s0=25.0, beta=-1.0)


# ---------------------------------------------------------------- slow references


def ref_f(psi: float, mu: list[float]) -> float:
    """eq. (3) with the documented basis: psi plus one-sided dead zones at -1 + 2i/M."""
    m = len(mu)
    total = mu[0] * psi
    for i in range(1, m):
        b = -1.0 + 2.0 * i / m
        total += mu[i] * (max(psi - b, 0.0) if b > 0 else min(psi - b, 0.0))
    return total


def ref_finv(y: float, mu: list[float]) -> float:
    """f^-1 by bisection (f strictly increasing)."""
    lo, hi = -1e4, 1e4
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if ref_f(mid, mu) < y:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def ref_run(kind: str, t, r, n: int, sigma: float, p: float, w, mu, norm: Normalisation):
    """eq. (1) (kind 'apl') or eq. (6) ('pl'), projected explicit Euler, then eq. (2)."""
    if kind == "apl":
        rho = [2.0 * k / (n + 1) - 1.0 for k in range(1, n + 1)]
    else:
        rho = [k / (n + 1) for k in range(1, n + 1)]
    x = None
    t_prev = None
    out = []
    for ti, ri in zip(t, r, strict=True):
        if not (math.isfinite(ti) and math.isfinite(ri) and ri > 0):
            out.append(math.nan)
            continue
        xi = ri / norm.r0 + norm.alpha
        if x is None:
            x = [xi + 1.0 if kind == "apl" else xi] * n
        else:
            dt = max(ti - t_prev, 0.0)
            for k in range(n):
                if kind == "apl":
                    xk = min(max(x[k], xi - rho[k]), xi + 1.0)
                    rate = sigma * ((xi - xk + 1.0) / (rho[k] + 1.0)) ** p
                    x[k] = min(xk + dt * rate, xi + 1.0)
                else:
                    xk = min(max(x[k], xi - rho[k]), xi + rho[k])
                    d = xi - xk
                    rate = sigma * (abs(d) / rho[k]) ** p * (1.0 if d > 0 else -1.0)
                    xk += dt * rate
                    x[k] = min(xk, xi) if d > 0 else max(xk, xi)
        t_prev = ti
        y = w[0] * xi + sum(w[k + 1] * x[k] for k in range(n)) + w[n + 1]
        out.append((ref_finv(y, mu) - norm.beta) * norm.s0)
    return np.array(out)


def random_model(rng: np.random.Generator, cls: type):
    n = int(rng.integers(1, 14))
    m = int(rng.choice([1, 3, 5, 7, 9, 11]))
    sigma = 0.0 if cls is MPI else float(10 ** rng.uniform(-2, 1))
    p = float(rng.uniform(0.2, 3.0))
    w = rng.normal(size=n + 2)
    w[1:n + 1] = np.abs(w[1:n + 1])
    mu = np.r_[rng.uniform(0.5, 2.0), rng.normal(scale=0.2, size=m - 1)]
    from strain_comp.models.pwa import mu_from_slopes, slopes_from_mu
    mu = mu_from_slopes(np.maximum(slopes_from_mu(mu), 0.05))
    return cls(n=n, m=m, sigma=sigma, p=p, w=w, mu=mu, normalisation=NORM)


def random_walk(rng: np.random.Generator, size: int, *, bad: bool = True):
    t = np.cumsum(rng.exponential(0.05, size=size))
    t[rng.integers(1, size, 3)] = t[rng.integers(1, size, 3)]  # a few repeated/back times
    xi = np.cumsum(rng.normal(scale=0.08, size=size))
    xi = 1.2 * np.sin(xi)  # stays in [-1.2, 1.2], reverses often
    r = (xi - NORM.alpha) * NORM.r0
    if bad:
        r[rng.integers(0, size, 3)] = [np.nan, -1.0, np.inf]
    return t, r


# ---------------------------------------------------------------- kernels


@pytest.mark.parametrize("p", [0.05, 0.3, 0.73, 1.0, 3.0, 20.0])
def test_inline_power_matches_libm(p):
    """The kernels' z^p (log/exp polynomials) against libm's pow over the cells' range of z
    (0, 1]: relative error within a few hundred ulps (p log z carries the rounding)."""
    rng = np.random.default_rng(int(100 * p))
    z = np.concatenate([10.0 ** rng.uniform(-30.0, 0.0, 3000), rng.uniform(0.0, 1.0, 3000),
                        [1.0, 0.5, 2.0 ** -1000]])
    got = np.array([kern.pow01(v, p) for v in z])
    ref = np.array([math.pow(v, p) for v in z])
    np.testing.assert_allclose(got, ref, rtol=2e-13, atol=1e-300)


@pytest.mark.parametrize("cls", [APL, PL, MPI])
def test_kernel_matches_reference(cls):
    rng = np.random.default_rng({"apl": 1, "pl": 2, "mpi": 3}[cls.name])
    kind = "apl" if cls is APL else "pl"
    for _ in range(6):
        model = random_model(rng, cls)
        t, r = random_walk(rng, 300)
        got = model.run(t, r)
        ref = ref_run(kind, t, r, model.N, model.sigma, model.p, model.w.tolist(),
                      model.mu.tolist(), NORM)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        ok = ~np.isnan(ref)
        np.testing.assert_allclose(got[ok], ref[ok], rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("cls", [APL, PL, MPI])
def test_step_equals_run_and_reset(cls):
    rng = np.random.default_rng(7)
    model = random_model(rng, cls)
    t, r = random_walk(rng, 500)
    batch = model.run(t, r)
    x_end = model.x.copy()
    model.reset()
    stream = np.array([model.step(ti, ri) for ti, ri in zip(t, r, strict=True)])
    np.testing.assert_allclose(stream, batch, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(model.x, x_end, rtol=0, atol=1e-12)
    model.reset()
    np.testing.assert_array_equal(model.run(t, r), batch)
    # run continues from the state: two halves equal one call
    model.reset()
    halves = np.concatenate([model.run(t[:200], r[:200]), model.run(t[200:], r[200:])])
    np.testing.assert_array_equal(halves, batch)


def test_f_strictly_increasing_and_exact_inverse():
    rng = np.random.default_rng(3)
    for _ in range(10):
        model = random_model(rng, APL)
        psi = np.linspace(-3, 3, 2001)
        f = pwa.path_matrix(psi, model.M) @ pwa.slopes_from_mu(model.mu)
        assert np.all(np.diff(f) > 0)
        np.testing.assert_allclose([ref_f(v, model.mu.tolist()) for v in psi[::50]],
                                   f[::50], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(pwa.finv_array(f, model.b, model.f_at_b, model.inv_slopes),
                                   psi, atol=1e-12)


def test_array_kernel_matches_per_sensor_models():
    rng = np.random.default_rng(11)
    models = []
    for i in range(9):
        mdl = random_model(rng, (APL, PL, MPI)[i % 3])
        models.append(type(mdl)(n=5, m=7, sigma=mdl.sigma, p=mdl.p,
                                w=rng.uniform(0, 1, 7), mu=[1.0, 0.1, 0.2, 0, 0.1, -0.3, 0.2],
                                normalisation=Normalisation(7 + i, -2.5, 20 + i, -1)))
    array = APLArray(models)
    t = np.cumsum(rng.exponential(0.02, 400))
    rs = np.column_stack([m.normalisation.r0 * (1.2 * np.sin(np.cumsum(rng.normal(0, .1, 400)))
                                                - m.normalisation.alpha) for m in models])
    rs[50, 2] = np.nan
    rs[51:53, 4] = 0.0
    batch = np.array([array.step(ti, row) for ti, row in zip(t, rs, strict=True)])
    for s, model in enumerate(models):
        np.testing.assert_allclose(batch[:, s], model.run(t, rs[:, s]), rtol=1e-12, atol=1e-12)
    array.reset()
    np.testing.assert_allclose(array.step(t[0], rs[0]), batch[0], rtol=0, atol=0)
    with pytest.raises(ParameterError):
        APLArray([models[0], APL(n=4, m=7, sigma=1, p=1, w=np.ones(6),
                                             mu=np.r_[1.0, np.zeros(6)], normalisation=NORM)])


# ---------------------------------------------------------------- parameters


@pytest.mark.parametrize("name", ["apl", "pl", "mpi"])
def test_params_round_trip_and_validation(name):
    cls = model_class(name)
    model = random_model(np.random.default_rng(5), cls)
    params = model.to_params()
    again = cls.from_params(params, NORM, direction=DIRECTION)
    assert again.to_params() == params
    t, r = random_walk(np.random.default_rng(6), 200)
    np.testing.assert_array_equal(again.run(t, r), model.run(t, r))
    bad_cases = [("N", 0), ("M", 4), ("p", 0.0), ("w", [1.0]), ("mu", [-1.0] * model.M),
                 ("sigma", -1.0), ("N", True)]
    for field, value in bad_cases:
        with pytest.raises(ParameterError) as info:
            cls.from_params({**params, field: value}, NORM, direction=DIRECTION)
        assert info.value.field.split(".")[0] in (field, "w", "mu"), info.value
    if cls is MPI:
        with pytest.raises(ParameterError):
            cls.from_params({**params, "sigma": 0.5}, NORM, direction=DIRECTION)
    with pytest.raises(ParameterError, match="w"):
        cls.from_params({k: v for k, v in params.items() if k != "w"}, NORM,
                        direction=DIRECTION)


# ---------------------------------------------------------------- fitting


def triangle_segments(periods, *, fs=20.0, cycles=2, lo=-1.0, hi=1.0):
    out = []
    for period in periods:
        t = np.arange(0, period * cycles, 1 / fs)
        phase = (t / period) % 1.0
        out.append((t, lo + (hi - lo) * (1 - np.abs(1 - 2 * phase))))
    return out


def test_fit_recovers_known_forward_models():
    rng = np.random.default_rng(21)
    n, m = 6, 5
    w = np.r_[0.8, rng.uniform(0.05, 0.4, n), 0.1]
    mu = [1.0, 0.2, 0.1, 0.3, -0.2]
    for cls, sigma, p in ((MPI, 0.0, 1.0), (APL, 0.3, 1.0)):
        truth = cls(n=n, m=m, sigma=sigma, p=p, w=w, mu=mu, normalisation=NORM)
        segs = []
        for t, xi in triangle_segments([4, 13, 40], lo=-1.0, hi=1.1):
            r = (xi - NORM.alpha) * NORM.r0
            truth.reset()
            segs.append(Segment(t, r, truth.run(t, r)))
        grid = {} if cls is MPI else {"sigma_grid": [0.03, 0.1, 0.3, 1.0, 3.0],
                                      "p_grid": [0.5, 1.0, 2.0]}
        fitted = cls.fit(segs, NORM, direction=DIRECTION, N=n, M=m, progress=False, **grid)
        err = 0.0
        for seg in segs:
            fitted.reset()
            err = max(err, float(np.abs(fitted.run(seg.t, seg.r) - seg.s).max()))
        print(f"\n{cls.name}: max training error {err:.2e} %, sigma {fitted.sigma:.4g}, "
              f"p {fitted.p:.4g}")
        assert err < 0.05
        if cls is APL:
            assert fitted.sigma == pytest.approx(sigma, rel=0.1)
            assert fitted.p == pytest.approx(p, rel=0.1)


def noisy_input_segments(truth, periods, noise, rng):
    """Triangles through ``truth``; the fit sees the resistance with white noise of
    ``noise`` (normalised units) added, the strain is the truth's noise-free output."""
    noisy, clean = [], []
    for t, xi in triangle_segments(periods, lo=-1.0, hi=1.1):
        r = (xi - NORM.alpha) * NORM.r0
        truth.reset()
        s = truth.run(t, r)
        noisy.append(Segment(t, r + rng.normal(scale=noise * NORM.r0, size=r.size), s))
        clean.append(Segment(t, r, s))
    return noisy, clean


def rmse_on(model, segments):
    errors = []
    for seg in segments:
        model.reset()
        errors.append(model.run(seg.t, seg.r) - seg.s)
    return float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))


@pytest.mark.parametrize("cls", [APL, PL, MPI])
def test_output_error_refinement_never_worse_than_qp(cls):
    """The output-error refinement starts at the QP solution and only accepts lower RMSE."""
    rng = np.random.default_rng({"apl": 31, "pl": 32, "mpi": 33}[cls.name])
    n, m = 5, 7
    for noise in (0.0, 0.03, 0.2):
        truth = random_model(rng, cls)
        segs, _ = noisy_input_segments(truth, [5, 17], noise, rng)
        grid = {} if cls is MPI else {"sigma_grid": [0.5], "p_grid": [1.3], "refine": False}
        qp, refined = (cls.fit(segs, NORM, direction=DIRECTION, N=n, M=m, progress=False,
                               output_nfev=nfev, search_nfev=0, **grid) for nfev in (0, 60))
        assert rmse_on(refined, segs) <= rmse_on(qp, segs) + 1e-9
        assert refined.fit_report["rmse"] == pytest.approx(rmse_on(refined, segs), rel=1e-9)


def test_output_error_recovers_model_from_noisy_input_better_than_qp():
    """Errors in the input: the QP (equation error) degrades; the output-error refinement
    recovers the known model clearly better, judged on noise-free held-out input."""
    rng = np.random.default_rng(4)
    n, m = 6, 5
    w = np.r_[0.8, rng.uniform(0.05, 0.4, n), 0.1]
    mu = [1.0, 0.2, 0.1, 0.3, -0.2]
    for cls, sigma, p in ((MPI, 0.0, 1.0), (APL, 0.3, 1.0)):
        truth = cls(n=n, m=m, sigma=sigma, p=p, w=w, mu=mu, normalisation=NORM)
        train, _ = noisy_input_segments(truth, [4, 13, 40], 0.05, rng)
        _, held_out = noisy_input_segments(truth, [7, 25], 0.0, rng)
        grid = {} if cls is MPI else {"sigma_grid": [sigma], "p_grid": [p], "refine": False}
        qp, refined = (cls.fit(train, NORM, direction=DIRECTION, N=n, M=m, progress=False,
                               output_nfev=nfev, search_nfev=0, **grid) for nfev in (0, 100))
        errors = rmse_on(qp, held_out), rmse_on(refined, held_out)
        print(f"\n{cls.name}: held-out RMSE vs truth, QP {errors[0]:.3f} %, "
              f"refined {errors[1]:.3f} %")
        assert errors[1] < 0.8 * errors[0]


def test_fit_errors():
    t = np.arange(30.0)
    with pytest.raises(FitError, match="at least"):
        APL.fit([Segment(t, 10 + np.sin(t), np.sin(t))], NORM, direction=DIRECTION)
    t = np.arange(2000.0)  # no excitation: refused before any model's fit, by the sensor's name
    with pytest.raises(FitError, match="span no range of resistance"):
        check_training_span([Segment(t, np.full(t.size, 10.0), np.sin(t))], "s")
    for bad in ({"M": 4}, {"output_nfev": -1}, {"search_nfev": 1.5}, {"search_top": True}):
        with pytest.raises(InputError, match="integer"):
            check_fit_options("apl", bad)


# ---------------------------------------------------------------- paper's claims


def sensor_resistance(t, s, *, h=0.06, tau_up=4.0, tau_down=0.2, k_play=3.0, c_visc=2.0):
    """A simulated rate-dependent textile sensor, strain s [%] (0..50) -> R [ohm].

    Nonlinear elastic response + a play hysteresis (rate independent) + a viscoelastic
    element that creeps slowly on loading (tau_up) and follows fast on unloading
    (tau_down): the S-R loop is clockwise and rotates counterclockwise about its
    lower-left corner as the strain rate grows, relaxation shows after loading steps.
    """
    x = s / 50.0
    u = v = x[0]
    out = np.empty_like(x)
    for i in range(x.size):
        if i:
            sub_dt = (t[i] - t[i - 1]) / 10
            for j in range(10):
                xs = x[i - 1] + (x[i] - x[i - 1]) * (j + 1) / 10
                v += (xs - v) * (1 - math.exp(-sub_dt / (tau_up if xs > v else tau_down)))
        u = min(max(u, x[i] - h), x[i] + h)
        out[i] = 10 + 8 * x[i] + 3 * x[i] ** 2 + k_play * (x[i] - u) + c_visc * (x[i] - v)
    return out


def strain_triangles(periods):
    return [(t, 25.0 * (lo_hi + 1)) for t, lo_hi in triangle_segments(periods)]


def test_apl_loop_rotates_with_rate_about_lower_left_corner():
    model = APL(n=11, m=1, sigma=0.5, p=0.8, w=np.r_[0.5, np.full(11, 0.05), 0.0], mu=[1.0],
                normalisation=NORM)
    corners = {}
    periods = [2, 20, 200]
    for period, (t, xi) in zip(periods, triangle_segments(periods, fs=50.0, cycles=3), strict=True):
        model.reset()
        psi = NORM.psi(model.run(t, (xi - NORM.alpha) * NORM.r0))
        last = t >= 2 * period  # the last cycle
        corners[period] = (round(float(psi[last][np.argmin(xi[last])]), 4),
                           round(float(psi[last][np.argmax(xi[last])]), 4))
    print("\nAPL loop corners (period: psi at xi=-1, psi at xi=1):", corners)
    lows = [c[0] for c in corners.values()]
    highs = [c[1] for c in corners.values()]
    assert max(lows) - min(lows) < 0.02  # hinged at the lower-left corner
    assert highs[0] < highs[1] < highs[2]  # faster input: the upper end lower (clockwise)


def test_rate_sweep_apl_beats_mpi_beats_cubic():
    train = [Segment(t, sensor_resistance(t, s), s) for t, s in strain_triangles([8, 30, 100])]
    norm = Normalisation.fit(np.concatenate([g.r for g in train]),
                             np.concatenate([g.s for g in train]))
    models = {cls.name: cls.fit(train, norm, direction=DIRECTION, **kw)
              for cls, kw in ((APL, {"progress": False}), (MPI, {}), (Cubic, {}))}
    errors = {name: [] for name in models}
    print("\nheld-out RMSE [% strain] by triangle period (trained on 8, 30, 100 s):")
    for (t, s), period in zip(strain_triangles([5, 15, 50, 150]), [5, 15, 50, 150], strict=True):
        r = sensor_resistance(t, s)
        row = {}
        for name, model in models.items():
            model.reset()
            e = model.run(t, r) - s
            errors[name].append(e)
            row[name] = float(np.sqrt(np.mean(e ** 2)))
        print(f"  period {period:>4} s: " + "  ".join(f"{k} {v:.3f}" for k, v in row.items()))
        assert row["apl"] < row["mpi"] < row["cubic"]
    total = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in errors.items()}
    print(f"  all: {total}; mpi/apl = {total['mpi'] / total['apl']:.2f}, "
          f"cubic/mpi = {total['cubic'] / total['mpi']:.2f}")
    assert total["apl"] < 0.5 * total["mpi"] and total["mpi"] < total["cubic"]


def test_grid_search_in_threads_gives_the_serial_result() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(600) * 0.01
    r = 100.0 + 20.0 * np.sin(t) + 5.0 * np.sin(3.1 * t) + rng.normal(0, 0.05, t.size)
    s = 0.4 * (r - 100.0) + 0.5 * np.sin(t - 0.2)
    seg = [Segment(t, r, s)]
    norm = Normalisation.fit(r, s)
    kw = dict(direction=DirectionSettings(deadzone=0.1), N=3, M=3,
              sigma_grid=[0.05, 0.5, 5.0], p_grid=[0.5, 1.0], refine=False, output_nfev=0,
              search_nfev=0, progress=False)
    serial = APL.fit(seg, norm, workers=1, **kw)
    threaded = APL.fit(seg, norm, workers=3, **kw)
    assert (threaded.sigma, threaded.p) == (serial.sigma, serial.p)
    np.testing.assert_array_equal(threaded.w, serial.w)


def test_grid_threads_follow_cores_and_problem_size(monkeypatch):
    from strain_comp.models import apl_fit as apl

    monkeypatch.setattr(apl, "available_cores", lambda: 4)
    assert apl.grid_workers(None, 117, 20_000) == 4
    assert apl.grid_workers(None, 6, 20_000) == 3  # two or more points per thread
    assert apl.grid_workers(None, 117, apl.MIN_THREADED_SAMPLES - 1) == 1  # tiny: serial
    assert apl.grid_workers(3, 117, 100) == 3  # asked for: given
    assert apl.grid_workers(8, 2, 20_000) == 2  # never more threads than points
    monkeypatch.setattr(apl, "available_cores", lambda: 1)
    assert apl.grid_workers(None, 117, 20_000) == 1


def test_falling_resistance_sensor_fits_as_well_as_its_rising_mirror():
    """A sensor whose resistance falls with strain (R' = 40 ohm - R of the rising sensor
    above) carries the same information: APL must creep after strain loading steps, so it
    drives its cells by -xi (orientation -1) and fits as well as on the rising sensor."""
    grid = {"sigma_grid": [0.03, 0.1, 0.3, 1.0], "p_grid": [0.5, 1.0, 2.0], "progress": False}
    errors = {}
    for sign in (1, -1):
        def resistance(t, s, sign=sign):
            r = sensor_resistance(t, s)
            return r if sign > 0 else 40.0 - r
        train = [Segment(t, resistance(t, s), s) for t, s in strain_triangles([8, 30, 100])]
        norm = Normalisation.fit(np.concatenate([g.r for g in train]),
                                 np.concatenate([g.s for g in train]))
        model = APL.fit(train, norm, direction=DIRECTION, N=6, M=5, **grid)
        assert model.orientation == sign
        again = APL.from_params(model.to_params(), norm, direction=DIRECTION)
        t, s = strain_triangles([15])[0]
        model.reset()
        errors[sign] = float(np.sqrt(np.mean((model.run(t, resistance(t, s)) - s) ** 2)))
        np.testing.assert_array_equal(again.run(t, resistance(t, s)),
                                      (model.reset(), model.run(t, resistance(t, s)))[1])
        array = APLArray([model])
        model.reset()
        step = [array.step(ti, [ri])[0] for ti, ri in zip(t[:200], resistance(t, s)[:200],
                                                          strict=True)]
        np.testing.assert_allclose(step, model.run(t[:200], resistance(t, s)[:200]),
                                   rtol=0, atol=1e-9)
    print(f"\nheld-out RMSE, rising {errors[1]:.4f} %, falling {errors[-1]:.4f} %")
    assert errors[-1] < 1.05 * errors[1]
    with pytest.raises(ParameterError, match="orientation"):
        APL.from_params({**model.to_params(), "orientation": 0}, NORM, direction=DIRECTION)
