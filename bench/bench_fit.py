#!/usr/bin/env python3
"""Wall time of fitting every model on a 20k-sample training recording from the virtual rig.

    python bench/bench_fit.py [--samples 20000] [--naive-seconds S] [--models apl,pl,...]

Training data: ``strain_comp.offline.rig.simulate("rates", duration=samples / 25 Hz)`` (0-20 %
triangles at 20-100 mm/min, repeated), cut to ``--samples`` samples; spike_decay, which
fits from step-and-hold data, gets ``simulate("steps")`` at 50 Hz cut to the same count.
Each model is fitted with ``strain_comp.offline.fit.fit_sensor`` (what ``strain-comp fit`` runs
after reading the bag: normalisation, direction settings, the model's ``fit`` with its
defaults -- for APL/PL the 13 x 9 sigma/p grid plus a Nelder-Mead refinement -- and the
training error through the engine). Printed: wall time, the model fit's own time, and
the training RMSE. Every model is fitted once on a short recording first, so no figure
includes numba compilation. Target: APL under 30 s on this 2-core machine.

Baselines in the same run:

* the default APL fit with BLAS held to one thread (as ``APL.fit`` runs) against the same
  fit with BLAS's own threads;
* the APL sigma/p grid alone (13 x 9 points scored by their QP) in one thread per available
  core against the same grid serially (``workers=1``), alternately, best of
  ``--grid-repeats``: the speed-up (or not) of the threaded grid, printed with
  ``os.cpu_count()`` and the load average (a shared machine's other work takes cores);
* a naive, unguided ``scipy.optimize.minimize`` (Nelder-Mead, scipy defaults) of the same
  APL model's training RMSE over all 24 parameters (log sigma, p, w_0..w_12, mu_1..mu_9)
  from a neutral start (sigma = 0.02 /s, p = 1, w = [1, 0...], f = identity), given equal
  work: as many model runs over the training data as the guided fit made (its
  ``fit_report["evaluations"]``, or ``--naive-evaluations``). Printed: the RMSE each
  reached (the ratio does not depend on the machine's speed);
* the rational rat22 fit (``fit_rat22``) at ``--rational-sizes`` samples with the analytic
  Jacobian against scipy's finite-difference Jacobian: time per sample (flat = linear).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import time

import numpy as np
from _common import row
from scipy.optimize import minimize

from strain_comp.base.compensator import Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.errors import StrainCompError
from strain_comp.io.recording import Recording
from strain_comp.models import Normalisation
from strain_comp.models.apl import APL
from strain_comp.models.apl_fit import available_cores
from strain_comp.offline import rig
from strain_comp.offline.fit import fit_sensor, split_segments

MODELS = ("apl", "pl", "mpi", "cubic", "sinh_pl", "rational", "spike_decay")


def training_recording(scenario: str, n: int) -> Recording:
    """``n`` samples of a rig scenario (repeated as needed), sensor s1."""
    fs = {"rates": 25.0, "steps": 50.0}[scenario]
    run = rig.simulate(scenario, seed=0, duration=(n + 1) / fs)
    s1 = run["s1"]
    return Recording("s1", s1.t[:n], s1.r[:n], s1.s[:n])


class _Stop(Exception):
    pass


def naive_apl(rec: Recording, evaluations: int, target: float
              ) -> tuple[float, float | None, int, float]:
    """(best RMSE, time it first reached ``target`` or None, evaluations, seconds) of
    Nelder-Mead stopped after ``evaluations`` model runs."""
    segments = split_segments(rec.t, rec.r, rec.s)
    norm = Normalisation.fit(rec.r, rec.s)
    ref = np.concatenate([seg.s for seg in segments])
    state = {"best": math.inf, "reached": None, "n": 0}
    start = time.perf_counter()

    def rmse(v: np.ndarray) -> float:
        elapsed = time.perf_counter() - start
        if state["n"] >= evaluations:
            raise _Stop
        state["n"] += 1
        try:
            model = APL(n=11, m=9, sigma=10.0 ** v[0], p=float(v[1]), w=v[2:15],
                        mu=v[15:24], normalisation=norm)
        except StrainCompError:
            return 1e3  # outside the model's domain (f not increasing, p out of range)
        est = []
        for seg in segments:
            model.reset()
            est.append(model.run(seg.t, seg.r))
        err = float(np.sqrt(np.mean((np.concatenate(est) - ref) ** 2)))
        err = err if math.isfinite(err) else 1e3
        if err < state["best"]:
            state["best"] = err
            if err <= target and state["reached"] is None:
                state["reached"] = elapsed
        return err

    v0 = np.concatenate(([math.log10(0.02), 1.0], [1.0], np.zeros(12), [1.0], np.zeros(8)))
    try:
        minimize(rmse, v0, method="Nelder-Mead",
                 options={"maxfev": 10**9, "maxiter": 10**9, "adaptive": True})
    except _Stop:
        pass
    return state["best"], state["reached"], state["n"], time.perf_counter() - start


def grid_speedup(rec: Recording, direction: DirectionSettings, repeats: int) -> None:
    """The default 13 x 9 sigma/p grid alone (``APL.fit`` with no search refinement, no
    Nelder-Mead, no output-error step: the grid points scored by their QP), serially
    (``workers=1``) and in one thread per available core, alternately, best of
    ``repeats`` each: equal work, same run. Prints the cores and the load average (other
    processes on the machine take cores from the threads), and checks both gave one model."""
    segments = split_segments(rec.t, rec.r, rec.s)
    norm = Normalisation.fit(rec.r, rec.s)
    cores = available_cores()
    only_grid = {"search_nfev": 0, "refine": False, "output_nfev": 0, "progress": False}
    load_before = os.getloadavg()
    best = {1: math.inf, cores: math.inf}
    cpu = {1: math.inf, cores: math.inf}
    models = {}
    for _ in range(repeats):
        for workers in best:
            start, start_cpu = time.perf_counter(), time.process_time()
            models[workers] = APL.fit(segments, norm, direction=direction, workers=workers,
                                      **only_grid)
            wall = time.perf_counter() - start
            if wall < best[workers]:
                best[workers], cpu[workers] = wall, time.process_time() - start_cpu
    load_after = os.getloadavg()
    same = all(np.array_equal(m.w, models[1].w) and m.sigma == models[1].sigma
               for m in models.values())
    points = int(models[1].fit_report["evaluations"])
    ratio = best[1] / best[cores]
    load = f"load average {load_before[0]:.2f} before, {load_after[0]:.2f} after"
    print(f"APL sigma/p grid alone ({points} points, {rec.t.size:,} samples): serial "
          f"{best[1]:.2f} s, {cores} threads {best[cores]:.2f} s: {ratio:.2f}x; "
          f"os.cpu_count() = {os.cpu_count()}, {cores} cores available; {load}; "
          f"same model: {same}")
    print(f"  CPU time: serial {cpu[1]:.2f} s, threaded {cpu[cores]:.2f} s (cores kept busy "
          f"on average: {cpu[cores] / best[cores]:.2f} of {cores}; the rest went to the "
          f"machine's other work or waiting for the GIL)")
    gil_free = _gil_free_share(segments, norm, best[1])
    print(f"  the cell-state kernel (GIL released) takes {100 * gil_free:.0f} % of the serial "
          f"grid: were it the only part to run in parallel, {cores} idle cores would give "
          f"{1 / (1 - gil_free + gil_free / cores):.2f}x (Amdahl); BLAS and numpy's array "
          f"copies also release the GIL, the bounded least-squares solver (scipy's bvls) "
          f"does not")
    if not same:
        raise SystemExit("threaded and serial grids gave different models")
    row(f"APL sigma/p grid ({points} points) in {cores} threads, {rec.t.size:,} samples "
        f"(`bench_fit.py`)", f"{best[cores]:.2f} s ({os.cpu_count()} cores, {load})",
        f"the same grid serially: {best[1]:.2f} s", f"{ratio:.2f}x")


def blas_threads(rec: Recording, direction: DirectionSettings) -> int:
    """The default APL fit as ``APL.fit`` runs it (BLAS held to one thread) against the
    same fit with BLAS's threads left as numpy starts them, one after the other; returns
    the fit's model runs (the naive baseline's budget)."""
    from threadpoolctl import threadpool_info

    segments = split_segments(rec.t, rec.r, rec.s)
    norm = Normalisation.fit(rec.r, rec.s)
    unlimited = APL.fit.__func__.__wrapped__  # type: ignore[attr-defined]
    threads = max((pool["num_threads"] for pool in threadpool_info()
                   if pool["user_api"] == "blas"), default=1)
    load = os.getloadavg()[0]
    start = time.perf_counter()
    model = APL.fit(segments, norm, direction=direction, progress=False)
    one = time.perf_counter() - start
    start = time.perf_counter()
    other = unlimited(APL, segments, norm, direction=direction, progress=False)
    free = time.perf_counter() - start
    print(f"APL fit ({rec.t.size:,} samples), BLAS held to one thread: {one:.2f} s; with "
          f"BLAS's {threads} threads: {free:.2f} s ({free / one:.1f}x; load average "
          f"{load:.2f}); same RMSE: {model.fit_report['rmse'] == other.fit_report['rmse']}")
    row(f"APL fit, BLAS held to one thread, {rec.t.size:,} samples (`bench_fit.py`)",
        f"{one:.2f} s (load average {load:.2f})",
        f"the same fit with BLAS's {threads} threads: {free:.2f} s", f"{free / one:.1f}x")
    return int(model.fit_report["evaluations"])


def _gil_free_share(segments: list[Segment], norm: Normalisation, serial: float) -> float:
    """Share of the serial default grid's wall time ``serial`` that its cell-state kernel
    (nogil) takes, timed alone over the same points."""
    from strain_comp.models import apl_kernels as kern
    from strain_comp.models.apl_fit import P_GRID, _FitProblem

    problem = _FitProblem(APL.name, APL.kind, segments, norm, n=11, m=9, eps=1e-3, ridge=1e-6,
                          cell_weights="signed", search_nfev=0)
    start = time.perf_counter()
    for sigma in problem.default_sigma_grid():
        for p in P_GRID:
            kern.states_kernel(problem.t, problem.xi, problem.starts, kern.KIND_APL,
                               float(sigma), float(p), problem.rho, problem.inv_width)
    return min(1.0, (time.perf_counter() - start) / serial)


def rational_scaling(sizes: list[int]) -> None:
    """fit_rat22 time per sample, analytic vs finite-difference Jacobian."""
    from scipy import optimize

    from strain_comp.models import rational

    rng = np.random.default_rng(0)
    print("rational rat22 fit (fit_rat22), analytic Jacobian vs scipy finite differences:")
    print(f"{'samples':>10}{'analytic s':>12}{'us/sample':>11}{'FD s':>9}{'us/sample':>11}"
          f"{'FD/analytic':>13}")
    real = optimize.least_squares
    for n in sizes:
        xi = np.sort(rng.uniform(0.2, 1.8, n))
        s = (3.0 * xi * xi - xi + 0.5) / (xi * xi + 0.3 * xi + 1.2) + rng.normal(0, 1e-3, n)
        guard = (0.1, 1.9)
        rational.fit_rat22(xi[:100], s[:100], guard=guard)
        start = time.perf_counter()
        rational.fit_rat22(xi, s, guard=guard)
        t_an = time.perf_counter() - start

        def no_jac(*a: object, **k: object) -> object:
            k.pop("jac", None)
            return real(*a, **k)

        rational.least_squares = no_jac
        try:
            start = time.perf_counter()
            rational.fit_rat22(xi, s, guard=guard)
            t_fd = time.perf_counter() - start
        finally:
            rational.least_squares = real
        print(f"{n:>10,}{t_an:>12.3f}{1e6 * t_an / n:>11.2f}{t_fd:>9.3f}{1e6 * t_fd / n:>11.2f}"
              f"{t_fd / t_an:>12.1f}x")
        row(f"rational rat22 fit, {n:,} samples (`bench_fit.py`)",
            f"{t_an:.2f} s, {1e6 * t_an / n:.1f} us/sample (analytic Jacobian)",
            f"finite-difference Jacobian: {t_fd:.2f} s", f"{t_fd / t_an:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--naive-evaluations", type=int, default=None,
                        help="model runs of the naive baseline (default: the APL fit's)")
    parser.add_argument("--rational-sizes", default="20000,200000,1000000")
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--grid-repeats", type=int, default=3,
                        help="timed runs of the APL grid alone, serial and threaded each")
    args = parser.parse_args()
    rates = training_recording("rates", args.samples)
    steps = training_recording("steps", args.samples)
    # compile every kernel once so the times below are fit times, not numba start-up
    for model in args.models.split(","):
        src = steps if model == "spike_decay" else rates
        warm = Recording("s1", src.t[:1000], src.r[:1000], src.s[:1000])
        with contextlib.suppress(StrainCompError):
            fit_sensor([warm], model, name="s1", options={
                "sigma_grid": [0.1], "p_grid": [1.0], "refine": False, "progress": False}
                if model in ("apl", "pl") else None)
    print(f"fit_sensor wall time, {args.samples:,} training samples "
          f"(rig 'rates' at 25 Hz; spike_decay: rig 'steps' at 50 Hz), defaults:")
    print(f"{'model':<12}{'wall s':>9}{'fit s':>9}{'train RMSE %':>14}")
    results = {}
    cals = {}
    for model in args.models.split(","):
        rec = steps if model == "spike_decay" else rates
        start = time.perf_counter()
        try:
            cal = fit_sensor([rec], model, name="s1", options={"progress": False}
                             if model in ("apl", "pl") else None)
        except StrainCompError as exc:
            print(f"{model:<12} failed: {exc}")
            continue
        wall = time.perf_counter() - start
        results[model] = (wall, cal.provenance["fit_rmse"])
        cals[model] = cal
        print(f"{model:<12}{wall:>9.2f}{cal.provenance['fit_seconds']:>9.2f}"
              f"{cal.provenance['fit_rmse']:>14.3f}")
    if "apl" in results:
        wall, target = results["apl"]
        verdict = "holds" if wall < 30.0 else "does NOT hold"
        print(f"target 'APL fit (with sigma/p search) under 30 s': {verdict} ({wall:.1f} s)")
        direction = cals["apl"].direction
        grid_speedup(rates, direction, args.grid_repeats)
        budget = args.naive_evaluations or blas_threads(rates, direction)
        best, reached, n, sec = naive_apl(rates, budget, target)
        when = (f"reached the guided RMSE after {reached:.1f} s" if reached is not None else
                f"never reached the guided fit's {target:.3f} %")
        print(f"baseline: naive Nelder-Mead over all 24 APL parameters, equal work "
              f"({n} model runs, {sec:.1f} s): best RMSE {best:.3f} % ({best / target:.1f}x "
              f"the guided fit's); {when}")
        row(f"APL fit training RMSE, {args.samples:,} samples (`bench_fit.py`)",
            f"{target:.3f} % in {wall:.1f} s",
            f"naive Nelder-Mead over all 24 parameters, equal work ({n} model runs): "
            f"{best:.3f} %", f"{best / target:.1f}x lower error")
    if args.rational_sizes:
        rational_scaling([int(x) for x in args.rational_sizes.split(",")])


if __name__ == "__main__":
    main()
