#!/usr/bin/env python3
"""Replay of an array bag by today's path against the node's.

    python bench/bench_array_replay.py [--model apl|creep_pi] [--sensors 8] [--ticks 50000]

One Float64MultiArray topic ``/arr/resistance`` of ``--sensors`` sensors (``bench/_common.py``
calibration) at 1 kHz, replayed (``replay_bag``, read + compensate + write) twice, best of
``--repeat`` each, kernels warm: as replay runs an array today (``Engine.run_array``: each
sensor's own batch path, cross-talk read per tick) and through the node's path
(``Engine.run_ticks`` of the array registered in the engine: the family kernel), the latter
by an engine whose ``run_array`` is ``run_ticks``. Printed: both times, their ratio and the
largest difference of the strain written.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import calibration, resistance

import strain_comp.offline.replay as replay
from strain_comp.core.engine import Engine
from strain_comp.core.outputs import BatchOutput
from strain_comp.io.bag import BagWriter, read_bag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", choices=("apl", "creep_pi"), default="apl")
    parser.add_argument("--sensors", type=int, default=8)
    parser.add_argument("--ticks", type=int, default=50_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    names = [f"s{i}" for i in range(args.sensors)]
    cal = calibration(names, [args.model])
    t = np.arange(args.ticks) * 1e-3
    r = resistance(t, args.sensors, seed=1)

    class TickEngine(Engine):
        """The node's path: the array registered, ``run_array`` is ``run_ticks``."""

        def __init__(self, calibration: Any, **kw: Any) -> None:
            super().__init__(calibration, arrays={"arr": names}, **kw)

        def run_array(self, sensors: Sequence[str], t: npt.ArrayLike, r: npt.ArrayLike,
                      temperature: Mapping[str, npt.ArrayLike | None] | None = None
                      ) -> dict[str, BatchOutput]:
            values = np.asarray(r, dtype=np.float64)
            out = self.run_ticks("arr", t, values)
            return {s: BatchOutput(out.strain[:, j], out.direction[:, j], out.status[:, j],
                                   out.out_of_range[:, j], values[:, j],
                                   std=None if out.std is None else out.std[:, j])
                    for j, s in enumerate(sensors)}

    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "array.mcap"
        with BagWriter(bag) as writer:
            writer.write_float64_array("/arr/resistance", t, r, names)
        best: dict[str, float] = {}
        strain: dict[str, np.ndarray] = {}
        for engine in (Engine, TickEngine) * (args.repeat + 1):  # the first round compiles
            replay.Engine = engine  # type: ignore[misc]
            out = Path(tmp) / f"{engine.__name__}.mcap"
            start = time.perf_counter()
            replay.replay_bag(bag, cal, out)
            took = time.perf_counter() - start
            if engine.__name__ in strain:
                best[engine.__name__] = min(best.get(engine.__name__, took), took)
            strain[engine.__name__] = read_bag(out).series["/arr/strain"].values
    diff = float(np.nanmax(np.abs(strain["Engine"] - strain["TickEngine"])))
    print(f"{args.model}, {args.sensors} sensors, {args.ticks} ticks: run_array "
          f"{best['Engine']:.3f} s, run_ticks {best['TickEngine']:.3f} s, ratio "
          f"{best['TickEngine'] / best['Engine']:.2f}x, largest strain difference {diff:.1e}")


if __name__ == "__main__":
    main()
