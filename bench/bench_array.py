#!/usr/bin/env python3
"""An array of 256 APL sensors (N = 11, M = 9) stepped by the engine at 1 kHz in real time.

    python bench/bench_array.py [--sensors 256] [--seconds 60] [--baseline-ticks 1000] [--no-gc]
                                [--model apl|creep_pi]

``--model creep_pi``: the same with creep_pi sensors (``bench/_common.py``: 8 play
operators, the default time constants), stepped by the engine's fused tick bound to the
creep_pi kernel (``strain_comp.core.array.family_tick``); the bare kernel compared is then
``CreepPIArray.step``.

``Engine(calibration, arrays={"arr": names}).step_array`` is called once per tick for
``--seconds`` of 1 kHz data (60 000 ticks by default), each call timed on its own
(Python call, screening, the model kernel, the direction kernel and the output arrays
included). Printed: per-tick cost median / p99 / max and the share of the 1 ms budget,
and the median of the bare model array's ``step`` alone (``APLArray`` or
``CreepPIArray``: one kernel call per tick, no screening) in the same run for comparison.

Baseline in the same run: the same ticks fed through a Python loop over the sensors,
``Engine.step(sensor, t, r)`` per sensor (an engine without the array registered), on
the first ``--baseline-ticks`` ticks; both paths' strain must agree there to 1e-9.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import calibration, resistance, row

from strain_comp.core.engine import Engine
from strain_comp.models.apl import APLArray
from strain_comp.models.creep_pi import CreepPIArray


def run_fixed_cost(cal: object, name: str, model: str, t: np.ndarray, r: np.ndarray,
                   calls: int = 3000) -> None:
    """``Engine.run`` on one sample at a time (its fixed cost) against ``Engine.step``."""
    engine = Engine(cal)
    engine.warm_up()
    n = min(calls, t.size)
    cost_run, cost_step = np.empty(n), np.empty(n)
    for i in range(n):
        start = time.perf_counter()
        engine.run(name, t[i:i + 1], r[i:i + 1])
        cost_run[i] = time.perf_counter() - start
    engine.reset()
    for i in range(n):
        start = time.perf_counter()
        engine.step(name, t[i], r[i])
        cost_step[i] = time.perf_counter() - start
    med_run, med_step = np.median(cost_run) * 1e6, np.median(cost_step) * 1e6
    print(f"Engine.run on one sample (fixed cost), {n} calls: median {med_run:.1f} us; "
          f"Engine.step median {med_step:.1f} us; goal '< 20 us': "
          f"{'holds' if med_run < 20 else 'does NOT hold'}")
    row(f"`Engine.run` fixed cost: one {model} sample per call (`bench_array.py`)",
        f"median {med_run:.1f} us", f"`Engine.step` on one sample: {med_step:.1f} us",
        f"{med_run / med_step:.1f}x step")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--baseline-ticks", type=int, default=1000)
    parser.add_argument("--model", choices=("apl", "creep_pi"), default="apl")
    parser.add_argument("--band", action="store_true",
                        help="every sensor with an uncertainty (the standard deviation of "
                             "each estimate computed too)")
    parser.add_argument("--no-gc", action="store_true",
                        help="disable Python's garbage collector during the timed ticks")
    args = parser.parse_args()
    k, ticks = args.sensors, round(args.seconds * 1000)
    names = [f"x{i:03d}" for i in range(k)]
    cal = calibration(names, [args.model], seed=3, band=args.band)
    t = np.arange(ticks) * 1e-3
    r = resistance(t, k, seed=4)

    engine = Engine(cal, arrays={"arr": names})
    group = engine._arrays["arr"]
    path = (f"fused tick: {', '.join(type(kern).__name__ for _, kern in group.kernels)} "
            f"kernel for all {k} sensors" if group.fused
            else "FALLBACK: Python loop of Engine.step")
    engine.warm_up()
    gc.collect()
    if args.no_gc:
        gc.disable()
    cost = np.empty(ticks)
    strain_array = np.empty((min(args.baseline_ticks, ticks), k))
    for i in range(ticks):
        start = time.perf_counter()
        out = engine.step_array("arr", t[i], r[i])
        cost[i] = time.perf_counter() - start
        if i < strain_array.shape[0]:
            strain_array[i] = out.strain
    gc.enable()

    models = [c.build_model() for c in cal.sensors.values()]
    kernel: APLArray | CreepPIArray = (APLArray(models) if args.model == "apl"
                                       else CreepPIArray(models))  # type: ignore[arg-type]
    kernel_cost = np.empty(min(ticks, 10_000))
    for i in range(kernel_cost.size):
        start = time.perf_counter()
        kernel.step(t[i], r[i])
        kernel_cost[i] = time.perf_counter() - start

    loop = Engine(cal)
    loop.warm_up()
    n_base = strain_array.shape[0]
    base_cost = np.empty(n_base)
    strain_loop = np.empty((n_base, k))
    gc.collect()
    for i in range(n_base):
        start = time.perf_counter()
        ti, ri = t[i], r[i]
        for j, name in enumerate(names):
            strain_loop[i, j] = loop.step(name, ti, ri[j]).strain
        base_cost[i] = time.perf_counter() - start
    diff = float(np.max(np.abs(strain_array - strain_loop)))

    us = cost * 1e6
    med, p99, worst = np.median(us), np.percentile(us, 99), us.max()
    base_med = np.median(base_cost) * 1e6
    label = "APL sensors (N=11, M=9)" if args.model == "apl" else "creep_pi sensors"
    kname = type(kernel).__name__
    print(f"Engine.step_array, {k} {label}{', with the band' if args.band else ''}, "
          f"{ticks:,} ticks at 1 kHz ({args.seconds:g} s of data)"
          f"{', gc off' if args.no_gc else ''}; {path}")
    print(f"  per tick: median {med:.1f} us, p99 {p99:.1f} us, max {worst:.0f} us; "
          f"median uses {med / 10:.1f} % of the 1 ms budget (p99 {p99 / 10:.1f} %); "
          f"{int((us > 1000).sum())} ticks over budget")
    print(f"  bare {kname}.step ({kernel_cost.size:,} ticks): median "
          f"{np.median(kernel_cost) * 1e6:.1f} us; the rest is screening, the direction "
          f"kernel and the output arrays")
    print(f"  {k / np.median(cost):,.0f} sensor-samples/s; total {cost.sum():.2f} s for "
          f"{args.seconds:g} s of data ({args.seconds / cost.sum():.0f}x real time)")
    print(f"baseline, Python loop of Engine.step over the {k} sensors ({n_base} ticks): "
          f"median {base_med:.0f} us per tick ({base_med / 10:.0f} % of the budget)")
    print(f"ratio loop / array (median per tick): {base_med / med:.0f}x; "
          f"max |strain difference| {diff:.1e} %")
    if not diff <= 1e-9:
        raise SystemExit("array path and per-sensor loop disagree")
    k_med = np.median(kernel_cost) * 1e6
    goal = "<= 2x the bare kernel" if k >= 256 else "<= 20 us"
    held = med <= 2 * k_med if k >= 256 else med <= 20.0
    print(f"goal 'step_array {goal}': {'holds' if held else 'does NOT hold'} "
          f"({med:.1f} us, {med / k_med:.2f}x the kernel)")
    run_fixed_cost(cal, names[0], args.model, t, r[:, 0])
    flags = f"--sensors {k}" + ("" if args.model == "apl" else f" --model {args.model}")
    row(f"`Engine.step_array`, {k} {label} at 1 kHz, {'fused tick' if group.fused else 'loop'} "
        f"(`bench_array.py {flags}`)", f"median {med:.1f} us/tick, p99 {p99:.0f} us",
        f"bare kernel (`{kname}.step`) {k_med:.1f} us; loop of `Engine.step` "
        f"{base_med:.0f} us", f"{med / k_med:.2f}x the kernel; {base_med / med:.0f}x faster "
        f"than the loop")


if __name__ == "__main__":
    main()
