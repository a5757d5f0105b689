"""Kernel throughput of the APL family and the cubic baseline.

Run on demand (not part of the test suite)::

    python bench/bench_kernels.py [--samples 1000000] [--no-fit]

For apl, pl, mpi (N = 11, M = 9) and cubic it prints the samples/s of ``run`` on one
core (after a warm-up call that compiles the kernel) and the ratio against a pure-Python
loop of the same equations timed in the same run (on fewer samples, scaled; both as the
best of 15 short runs taking turns, ``best_times``, so that on a shared machine neither
side is timed only in a busy moment); then the roofline of the APL kernel, then the
per-tick cost of ``APLArray.step`` for 256 APL sensors at 1 kHz (median, p99, share of
the 1 ms budget), and the wall time of ``fit`` on a 20k-sample training set.

The input is 1 kHz resistance through triangle waves of periods 2 to 60 s over the full
normalised range plus a random walk; the APL parameters are the paper's (sigma =
2.15e-2 /s, p = 0.73, w from Table I) with a mildly nonlinear f.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np
from _common import row

from strain_comp._numba import njit
from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.models.apl import APL, MPI, PL, APLArray
from strain_comp.models.apl_kernels import FASTMATH, LANES, pow01
from strain_comp.models.cubic import Cubic
from strain_comp.models.pwa import slope_tables, slopes_from_mu

NORM = Normalisation(r0=7.16, alpha=-2.61, s0=25.0, beta=-1.0)
CHUNK = 100_000
"""Samples per timed kernel run (short runs, many of them: see ``best_times``)."""
PY_SAMPLES = 2_000
"""Samples per timed run of the pure-Python loops."""
W_PAPER = [2.523, 0.843, 1.522, 0.522, 0.513, 0.002, 0.022, 0.041, 0.106, 0.276, 0.457, 0.695,
           0.0]
MU = [1.0, 0.05, -0.03, 0.08, 0.02, 0.1, -0.05, 0.04, 0.06]


def make_input(n: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """1 kHz time and resistance: triangles of periods 2..60 s, then a random walk."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    half = n // 2
    period = np.repeat([2.0, 5.0, 20.0, 60.0], -(-half // 4))[:half]
    phase = np.cumsum(1e-3 / period) % 1.0
    xi = np.empty(n)
    xi[:half] = 1.0 - 2.0 * np.abs(1.0 - 2.0 * phase)
    xi[half:] = np.sin(np.cumsum(rng.normal(0.0, 3e-3, n - half)))
    return t, (xi - NORM.alpha) * NORM.r0


def python_cells(kind: str, t, r, n_cells: int, sigma: float, p: float, w, mu) -> list[float]:
    """The same equations (eq. (1)/(6), (2), (3)) as a plain Python loop."""
    if kind == "apl":
        rho = [2.0 * k / (n_cells + 1) - 1.0 for k in range(1, n_cells + 1)]
    else:
        rho = [k / (n_cells + 1) for k in range(1, n_cells + 1)]
    b, f_at_b, inv_slopes = (a.tolist() for a in slope_tables(slopes_from_mu(mu)))
    x: list[float] = []
    t_prev = 0.0
    out = []
    for ti, ri in zip(t.tolist(), r.tolist(), strict=True):
        xi = ri / NORM.r0 + NORM.alpha
        if not x:
            x = [xi + 1.0 if kind == "apl" else xi] * n_cells
        else:
            sdt = sigma * max(ti - t_prev, 0.0)
            for k in range(n_cells):
                if kind == "apl":
                    xk = min(max(x[k], xi - rho[k]), xi + 1.0)
                    if sdt > 0.0:
                        xk = min(xk + sdt * ((xi + 1.0 - xk) / (rho[k] + 1.0)) ** p, xi + 1.0)
                else:
                    xk = min(max(x[k], xi - rho[k]), xi + rho[k])
                    if sdt > 0.0:
                        d = xi - xk
                        step = sdt * (abs(d) / rho[k]) ** p
                        xk = min(xk + step, xi) if d > 0 else max(xk - step, xi)
                x[k] = xk
        t_prev = ti
        y = w[0] * xi + w[-1]
        for k in range(n_cells):
            y += w[k + 1] * x[k]
        j = 0
        while j < len(b) and f_at_b[j] < y:
            j += 1
        psi = (b[0] + (y - f_at_b[0]) * inv_slopes[0] if j == 0
               else b[j - 1] + (y - f_at_b[j - 1]) * inv_slopes[j])
        out.append((psi - NORM.beta) * NORM.s0)
    return out


def python_cubic(t, r, c) -> list[float]:
    c0, c1, c2, c3 = c
    return [((c3 * v + c2) * v + c1) * v + c0 for v in r.tolist()]


def best_times(fns: dict[str, Callable[[], object]], rounds: int = 15) -> dict[str, float]:
    """Smallest wall time [s] of each function over ``rounds`` rounds, the functions taking
    turns within each round: on a shared machine each then gets its share of the quiet
    moments, so ratios between them hold better than with one block of repeats each."""
    best = dict.fromkeys(fns, math.inf)
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def bench_models(n: int) -> None:
    t, r = make_input(n)
    n = min(n, CHUNK)
    n_py = min(n, PY_SAMPLES)
    models = {
        "apl": (APL(n=11, m=9, sigma=2.15e-2, p=0.73, w=W_PAPER, mu=MU, normalisation=NORM),
                "apl"),
        "pl": (PL(n=11, m=9, sigma=2.15e-2, p=0.73, w=W_PAPER, mu=MU, normalisation=NORM), "pl"),
        "mpi": (MPI(n=11, m=9, sigma=0.0, p=1.0, w=W_PAPER, mu=MU, normalisation=NORM), "pl"),
        "cubic": (Cubic([-69.5, 7.816, -0.2112, 0.003512], NORM), None),
    }
    print(f"kernel throughput, run() on {n:,} samples, one core (N=11, M=9), against the "
          f"pure-Python loop on {n_py:,}; best of 15 interleaved runs each:")
    print(f"{'model':<7}{'samples/s':>14}{'pure Python':>14}{'ratio':>9}")
    for name, (model, kind) in models.items():
        model.run(t[:100], r[:100])  # compile / warm up

        def go(model=model):
            model.reset()
            model.run(t[:n], r[:n])

        def py(model=model, kind=kind):
            if kind is None:
                python_cubic(t[:n_py], r[:n_py], model.c)
            else:
                python_cells(kind, t[:n_py], r[:n_py], model.N, model.sigma, model.p,
                             model.w.tolist(), model.mu)

        best = best_times({"kernel": go, "python": py})
        fast, slow = n / best["kernel"], n_py / best["python"]
        print(f"{name:<7}{fast:>14,.0f}{slow:>14,.0f}{fast / slow:>8.0f}x")
        row(f"{name} kernel `run`, N=11, M=9, one core (`bench_kernels.py`)",
            f"{fast / 1e6:.1f} M samples/s", f"pure-Python loop: {slow / 1e3:.0f} k/s",
            f"{fast / slow:.0f}x")
    apl = models["apl"][0]
    apl.reset()
    n_check = min(n, 20_000)
    check = np.abs(apl.run(t[:n_check], r[:n_check]) - python_cells(
        "apl", t[:n_check], r[:n_check], 11, apl.sigma, apl.p, apl.w.tolist(), apl.mu)).max()
    print(f"(apl kernel vs pure Python on {n_check} samples: max |difference| {check:.1e} %)")


def bench_array(n_sensors: int = 256, ticks: int = 20_000) -> None:
    rng = np.random.default_rng(1)
    models = [APL(n=11, m=9, sigma=2.15e-2 * rng.uniform(0.5, 2), p=rng.uniform(0.5, 1.5),
                  w=np.array(W_PAPER) * rng.uniform(0.8, 1.2, 13), mu=MU, normalisation=NORM)
              for _ in range(n_sensors)]
    array = APLArray(models)
    t, r = make_input(ticks, seed=2)
    rs = r[:, None] * rng.uniform(0.98, 1.02, n_sensors)[None, :]
    out = np.empty(n_sensors)
    array.step(t[0], rs[0], out)
    cost = np.empty(ticks)
    for i in range(ticks):
        start = time.perf_counter()
        array.step(t[i], rs[i], out)
        cost[i] = time.perf_counter() - start
    med, p99 = np.median(cost) * 1e6, np.percentile(cost, 99) * 1e6
    print(f"\nAPLArray.step, {n_sensors} APL sensors (N=11, M=9), {ticks} ticks at 1 kHz "
          f"(one kernel call per tick, Python call included):")
    print(f"  median {med:.1f} us, p99 {p99:.1f} us, max {cost.max() * 1e6:.0f} us; "
          f"median uses {med / 10:.1f} % of the 1 ms budget "
          f"({n_sensors / np.median(cost):,.0f} sensor-samples/s)")


def simulated_training_set(n: int = 20_000, fs: float = 50.0) -> list[Segment]:
    """A rate-dependent sensor (play hysteresis + viscoelastic creep on loading) driven by
    triangles of several periods; R in ohm, S in %."""
    segments = []
    per = n // 4
    for period in (6.0, 15.0, 40.0, 100.0):
        t = np.arange(per) / fs
        s = 50.0 * (1.0 - np.abs(1.0 - 2.0 * ((t / period) % 1.0)))
        x = s / 50.0
        u = v = x[0]
        r = np.empty(per)
        for i in range(per):
            if i:
                tau = 4.0 if x[i] > v else 0.2
                v += (x[i] - v) * (1.0 - math.exp(-(t[i] - t[i - 1]) / tau))
            u = min(max(u, x[i] - 0.06), x[i] + 0.06)
            r[i] = 10 + 8 * x[i] + 3 * x[i] ** 2 + 3.0 * (x[i] - u) + 2.0 * (x[i] - v)
        segments.append(Segment(t, r, s))
    return segments


def bench_fit() -> None:
    segments = simulated_training_set()
    n = sum(seg.t.size for seg in segments)
    norm = Normalisation.fit(np.concatenate([s.r for s in segments]),
                             np.concatenate([s.s for s in segments]))
    direction = DirectionSettings(deadzone=0.0)
    print(f"\nfit wall time on {n} training samples (N=11, M=9, default grids + refine):")
    for cls in (APL, PL, MPI, Cubic):
        start = time.perf_counter()
        model = cls.fit(segments, norm, direction=direction)
        seconds = time.perf_counter() - start
        report = getattr(model, "fit_report", None) or {}
        extra = (f", {report['evaluations']} QP solves, training rmse {report['rmse']:.3f} %"
                 if report else "")
        print(f"  {cls.name:<6}{seconds:7.2f} s{extra}")


@njit(fastmath=FASTMATH, error_model="numpy")
def _pow_only(z: np.ndarray, p: float) -> float:
    """Sum of pow01 over every cell and sample (independent: vectorisable)."""
    acc = 0.0
    for i in range(z.shape[0]):
        for k in range(z.shape[1]):
            acc += pow01(z[i, k], p)
    return acc


@njit(fastmath=FASTMATH, error_model="numpy")
def _libm_only(z: np.ndarray, p: float) -> float:
    """The same with libm's pow (a scalar call per cell)."""
    acc = 0.0
    for i in range(z.shape[0]):
        for k in range(z.shape[1]):
            acc += z[i, k] ** p
    return acc


def roofline(n: int = CHUNK, n_cells: int = 11) -> None:
    """What bounds the APL kernel: its ns/sample against the N powers z^p it must evaluate.

    Per sample the kernel evaluates N = 11 powers (pow01: ~20 flops of log polynomial and
    ~30 of exp polynomial; 12 with the cells padded to whole SIMD vectors, the figure timed
    here) plus ~10 flops of band clip and creep per cell, then the output
    (N + 2 multiply-adds and an M-segment search): about 11 x 60 + 40 = 700 flops and 24
    bytes of input/output per sample. At 24 bytes per ~700 flops memory is never the bound;
    the powers are. The samples form a recursion (each state needs the previous), so only
    the N cells of one sample can run in SIMD lanes, and a sample cannot start before the
    previous one's powers are done: the kernel with one vector of cells (``LANES``) shows
    that latency alone, the floor of the time per sample whatever the SIMD width.
    """
    t, r = make_input(n)

    def kernel_run(cells: int) -> Callable[[], object]:
        w = np.r_[W_PAPER[0], np.resize(W_PAPER[1:-1], cells), W_PAPER[-1]]
        model = APL(n=cells, m=9, sigma=2.15e-2, p=0.73, w=w, mu=MU, normalisation=NORM)
        model.run(t[:100], r[:100])

        def go() -> None:
            model.reset()
            model.run(t, r)

        return go

    lanes = -(-n_cells // LANES) * LANES  # the kernel pads the cells to whole vectors
    z = np.random.default_rng(0).uniform(1e-3, 1.0, (n, lanes))
    _pow_only(z[:10], 0.73)
    _libm_only(z[:10], 0.73)
    n_py = min(n, PY_SAMPLES)
    best = best_times({
        "kernel": kernel_run(n_cells), "one vector": kernel_run(LANES),
        "pow01": lambda: _pow_only(z, 0.73), "libm": lambda: _libm_only(z, 0.73),
        "python": lambda: python_cells("apl", t[:n_py], r[:n_py], n_cells, 2.15e-2, 0.73,
                                       W_PAPER, np.array(MU))})
    ns_kernel, ns_one_vector, ns_pow, ns_libm = (
        1e9 * best[k] / n for k in ("kernel", "one vector", "pow01", "libm"))
    ns_py = 1e9 * best["python"] / n_py
    flops = n_cells * 60 + 40
    print(f"\nroofline of the APL kernel (N={n_cells}, {n:.0e} samples, one core):")
    print(f"  kernel:                        {ns_kernel:7.1f} ns/sample "
          f"({flops / ns_kernel:.2f} Gflop/s at ~{flops} flops/sample, 24 B/sample)")
    print(f"  the {lanes} powers it evaluates ({n_cells} cells padded to whole vectors), "
          f"alone (pow01, SIMD, no recursion):{ns_pow:7.1f} ns/sample "
          f"({100 * ns_pow / ns_kernel:.0f} % of the kernel)")
    print(f"  the same powers with libm pow: {ns_libm:7.1f} ns/sample")
    print(f"  the kernel with {LANES} cells (one SIMD vector): {ns_one_vector:7.1f} ns/sample: "
          f"the latency of one sample's dependency chain (state -> power -> state), which "
          f"SIMD cannot shorten; {n_cells} cells ({-(-n_cells // LANES)} vectors) cost "
          f"{ns_kernel / ns_one_vector:.2f}x that")
    print(f"  pure-Python loop (baseline):   {ns_py:7.0f} ns/sample "
          f"(kernel is {ns_py / ns_kernel:.0f}x faster; 100x would need "
          f"{ns_py / 100:.0f} ns/sample)")
    row(f"APL kernel roofline: ns per sample vs its {lanes} powers alone (`bench_kernels.py`)",
        f"{ns_kernel:.0f} ns/sample, {flops / ns_kernel:.1f} Gflop/s; {LANES} cells (one "
        f"vector, the recursion's latency): {ns_one_vector:.0f} ns",
        f"the powers alone (pow01): {ns_pow:.0f} ns; libm pow: {ns_libm:.0f} ns; "
        f"pure Python: {ns_py:.0f} ns", f"powers {100 * ns_pow / ns_kernel:.0f} % of the "
        f"kernel; kernel {ns_py / ns_kernel:.0f}x pure Python")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--no-fit", action="store_true")
    args = parser.parse_args()
    bench_models(args.samples)
    roofline(min(args.samples, CHUNK))
    bench_array()
    if not args.no_fit:
        bench_fit()


if __name__ == "__main__":
    main()
