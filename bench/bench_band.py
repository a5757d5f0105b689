"""The cost of the standard deviation of every estimate: the engine with and without an
uncertainty in its calibration, in one run, blocks interleaved.

    python bench/bench_band.py [--blocks 20] [--ticks 200]

For one APL sensor (``Engine.step``, the node's single-topic path) and 256- and 1024-sensor
APL arrays (``Engine.step_array``, the fused tick), the median time per call of each
variant over interleaved blocks of ``--ticks`` calls (so both see the same machine load),
and their ratio (with / without).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import calibration, resistance

from strain_comp.core.engine import Engine


def engines(k: int) -> tuple[Engine, Engine]:
    """(without, with) the band: one sensor, or an array of ``k``."""
    names = ["s1"] if k == 1 else [f"x{i:04d}" for i in range(k)]
    pair = []
    for band in (False, True):
        cal = calibration(names, ["apl"], seed=3, band=band)
        engine = Engine(cal, arrays=None if k == 1 else {"arr": names})
        engine.warm_up()
        pair.append(engine)
    return pair[0], pair[1]


def block(engine: Engine, k: int, t: np.ndarray, r: np.ndarray) -> float:
    """Seconds per call over one block."""
    start = time.perf_counter()
    if k == 1:
        for ti, ri in zip(t.tolist(), r[:, 0].tolist(), strict=True):
            engine.step("s1", ti, ri)
    else:
        for i in range(t.size):
            engine.step_array("arr", t[i], r[i])
    return (time.perf_counter() - start) / t.size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=20)
    parser.add_argument("--ticks", type=int, default=200)
    args = parser.parse_args()
    for k in (1, 256, 1024):
        plain, banded = engines(k)
        n = args.blocks * args.ticks
        t = np.arange(n) * 1e-3
        r = resistance(t, k, seed=4)
        cost: dict[bool, list[float]] = {False: [], True: []}
        for b in range(args.blocks):
            part = slice(b * args.ticks, (b + 1) * args.ticks)
            for band, engine in ((False, plain), (True, banded)):
                cost[band].append(block(engine, k, t[part], r[part]))
        without, with_band = (float(np.median(cost[b])) * 1e6 for b in (False, True))
        print(f"{'1 sensor, Engine.step' if k == 1 else f'{k} sensors, step_array':28s}: "
              f"without {without:8.1f} us, with the band {with_band:8.1f} us per call; "
              f"ratio {with_band / without:.2f}")


if __name__ == "__main__":
    main()
