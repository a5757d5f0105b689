#!/usr/bin/env python3
"""Kernel throughput of the models that ``bench/bench_kernels.py`` (APL family, cubic) does
not cover: sinh_pl, rational (split mode), spike_decay, creep_pi.

    python bench/bench_models.py [--samples 1000000] [--reference-samples 5000]

For each model: samples/s of the batch path ``run`` (numba kernel, one core, after a
warm-up call that compiles it), best of 3, against the slow pure-Python reference of the
same equations that the model's own tests check the kernel against
(``test/models/test_{sinh_pl,rational,spike_decay}.py``), timed in the same run on
``--reference-samples`` samples, and the largest difference between the two there.
Parameters and inputs are those of the tests: sinh_pl with 2 cells on a modulated sine,
rat22 split into loading / unloading fits on a random walk, spike_decay on a staircase,
creep_pi with its default 8 play operators and 4 time constants on a noisy 1 kHz sine.
creep_pi's goal is 5 M samples/s for one sensor; its ``run`` and ``step`` are also given as
a ratio to the cubic's ``run`` (``strain_comp.models.cubic``, numpy, no state) timed in the
same run on the same samples. Then one tick of 256 sensors: ``CreepPIArray.step`` against
``APLArray.step`` (N = 11, M = 9, ``bench/_common.py``), the kernel of the engine's fused
array tick, median per tick over 5000 ticks at 1 kHz.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test" / "models"))
import test_creep_pi
import test_rational
import test_sinh_pl
import test_spike_decay
from _common import best_time, calibration, resistance, row

from strain_comp.base.compensator import Normalisation
from strain_comp.models.apl import APLArray
from strain_comp.models.creep_pi import TAUS, CreepPIArray
from strain_comp.models.cubic import Cubic
from strain_comp.models.rational import Rational


def sinh_pl(n: int):
    m = test_sinh_pl.model(2)
    t, s = test_sinh_pl.excitation(n)
    r = test_sinh_pl.resistance(m, t, s)

    def slow(k: int) -> np.ndarray:
        xi = m.normalisation.xi(r[:k])
        args = (m.w0, m.vb, list(m.w), list(m.i_s), list(m.v_t))
        return m.normalisation.strain(test_sinh_pl.inverse_slow(t[:k], xi, *args))

    return "sinh_pl (2 cells)", m, t, r, slow


def rational(n: int):
    rng = np.random.default_rng(0)
    t = np.arange(n) * 1e-3
    r = 3.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t) + np.cumsum(rng.normal(0, 3e-4, n))
    norm = Normalisation.from_ranges(float(r.min()), float(r.max()), 0.0, 1.0)
    coef = {"combined": [1.0, 2.0, 3.0, 0.5, 4.0], "loading": [0.5, 2.5, 3.0, 0.1, 5.0],
            "unloading": [1.5, 1.0, 2.0, 0.0, 3.0]}
    direction = test_rational.DIRECTION
    m = Rational(coef, "split", norm, direction)
    rows = [coef[k] for k in ("combined", "loading", "unloading")]

    def slow(k: int) -> np.ndarray:
        return np.array(test_rational.rational_slow(t[:k], norm.xi(r[:k]), rows, True,
                                                    direction.deadzone / norm.r0,
                                                    direction.tau))

    return "rational (rat22, split)", m, t, r, slow


def spike_decay(n: int):
    m = test_spike_decay.truth_model()
    t, s = test_spike_decay.staircase(2.0, dt=0.02, hold=2.0, step=3.0, top=12.0)
    r = m.predict_resistance(t, s)  # one staircase (from rest to rest), repeated
    reps = -(-n // t.size)
    t = (np.arange(reps)[:, None] * (t[-1] + 0.02) + t[None, :]).reshape(-1)[:n]
    r = np.tile(r, reps)[:n] + np.random.default_rng(0).normal(0, 0.3, n)
    d = test_spike_decay.DIRECTION

    def slow(k: int) -> np.ndarray:
        return np.array(test_spike_decay.kernel_slow(m, t[:k], r[:k], d.deadzone, d.tau))

    return "spike_decay", m, t, r, slow


def creep_pi(n: int):
    m = test_creep_pi.random_model(n_play=8, taus=TAUS)
    t = np.arange(n) * 1e-3
    r = 12.0 + 1.5 * np.sin(2 * np.pi * 0.3 * t) + np.random.default_rng(0).normal(0, 0.01, n)

    def slow(k: int) -> np.ndarray:
        return np.array(test_creep_pi.reference(m, t[:k], r[:k]))

    return "creep_pi (8 play, 4 tau)", m, t, r, slow


def against_cubic(n: int) -> None:
    """creep_pi's run and step against the cubic's run on the same samples."""
    _, m, t, r, _ = creep_pi(n)
    cubic = Cubic([0.0, 1.0, 0.1, 0.01], m.normalisation)
    m.run(t[:100], r[:100])
    cubic.run(t[:100], r[:100])

    def go() -> None:
        m.reset()
        m.run(t, r)

    k = min(n, 200_000)

    def steps() -> None:
        m.reset()
        for a, b in zip(t[:k].tolist(), r[:k].tolist(), strict=True):
            m.step(a, b)

    fast = n / best_time(go, 3)
    base = n / best_time(lambda: cubic.run(t, r), 3)
    stepped = k / best_time(steps, 1)
    print(f"creep_pi run {fast / 1e6:.1f} M samples/s = {fast / base:.2f} x the cubic's run "
          f"({base / 1e6:.1f} M/s); step {stepped / 1e3:.0f} k samples/s "
          f"(goal: run >= 5 M/s)")
    row("creep_pi kernel `run` against the cubic's (`bench_models.py`)",
        f"{fast / 1e6:.1f} M samples/s", f"cubic: {base / 1e6:.1f} M/s",
        f"{fast / base:.2f}x")


def array_tick(k: int = 256, ticks: int = 5000) -> None:
    """Median time of one tick of k sensors: CreepPIArray.step against APLArray.step."""
    t = np.arange(ticks) * 1e-3
    r = resistance(t, k, seed=4)
    apl = APLArray([c.build_model() for c in
                                calibration([f"x{i}" for i in range(k)], ["apl"]).sensors.values()])
    creep = CreepPIArray([test_creep_pi.random_model(seed, n_play=8, taus=TAUS)
                          for seed in range(k)])
    out = np.empty(k)
    medians = []
    for kernel in (creep, apl):
        kernel.step(t[0], r[0], out)
        kernel.reset()
        cost = np.empty(ticks)
        for i in range(ticks):
            start = time.perf_counter()
            kernel.step(t[i], r[i], out)
            cost[i] = time.perf_counter() - start
        medians.append(float(np.median(cost)) * 1e6)
    print(f"{k} sensors, one tick: CreepPIArray.step median {medians[0]:.1f} us, "
          f"APLArray.step {medians[1]:.1f} us ({medians[0] / medians[1]:.2f}x); "
          f"{k / medians[0]:.1f} M sensor-samples/s")
    row(f"`CreepPIArray.step`, {k} creep_pi sensors, one tick (`bench_models.py`)",
        f"median {medians[0]:.1f} us", f"`APLArray.step` {medians[1]:.1f} us",
        f"{medians[0] / medians[1]:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--reference-samples", type=int, default=5000)
    args = parser.parse_args()
    n, k = args.samples, args.reference_samples
    print(f"kernel throughput, run() on {n:,} samples, one core; pure-Python reference of "
          f"the same equations (from the model's tests) on {k:,} samples:")
    print(f"{'model':<26}{'samples/s':>14}{'reference':>12}{'ratio':>9}{'max |diff| %':>14}")
    for build in (sinh_pl, rational, spike_decay, creep_pi):
        name, model, t, r, slow = build(n)
        model.reset()
        model.run(t[:100], r[:100])  # compile / load the kernel

        def go(model=model, t=t, r=r) -> None:
            model.reset()
            model.run(t, r)

        fast = n / best_time(go, 3)
        ref_out: list[np.ndarray] = []
        ref = k / best_time(lambda slow=slow, out=ref_out: out.append(slow(k)), 1)
        model.reset()
        diff = float(np.max(np.abs(model.run(t[:k], r[:k]) - ref_out[-1])))
        print(f"{name:<26}{fast:>14,.0f}{ref:>12,.0f}{fast / ref:>8.0f}x{diff:>14.1e}")
        row(f"{name} kernel `run`, one core (`bench_models.py`)",
            f"{fast / 1e6:.1f} M samples/s", f"pure-Python reference: {ref / 1e3:.0f} k/s",
            f"{fast / ref:.0f}x")
    against_cubic(n)
    array_tick()


if __name__ == "__main__":
    main()
