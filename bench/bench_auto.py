#!/usr/bin/env python3
"""Wall time of ``fit --model auto`` (``model_choice.fit_auto``) on rig runs, against the
same choice followed by a fit that learns its band by fitting the chosen model's folds again.

    python bench/bench_auto.py [--seconds 240] [--candidates cubic,mpi,apl,creep_pi]

Training runs: four rig scenarios (``rates``, ``triangle``, ``patterns``, ``random``,
seed 0, ``--seconds`` each), sensor s1. ``fit_auto`` learns the band from the chosen
model's folds as the choice started them; the baseline is what it ran before:
``choose_model`` then ``fit_auto`` of the chosen model on one group (every fold of the
chosen model fitted and started again). Every model is fitted once first (numba
compiled), both variants run alternately, best of ``--repeat``; the two bands are
compared weight for weight.
"""

from __future__ import annotations

import argparse
import math
import os
import time

from _common import row

from strain_comp.io.recording import Recording
from strain_comp.offline import rig
from strain_comp.offline.fit import choose_model, fit_auto, fit_sensor, options_of

SCENARIOS = ("rates", "triangle", "patterns", "random")


def runs(seconds: float) -> list[Recording]:
    """The training runs, sensor s1."""
    out = []
    for scenario in SCENARIOS:
        out.append(rig.simulate(scenario, seed=0, duration=seconds)["s1"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=240.0)
    parser.add_argument("--candidates", default="cubic,mpi,apl,creep_pi")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    candidates = tuple(args.candidates.split(","))
    recordings = runs(args.seconds)
    for model in candidates:  # compile
        fit_sensor(recordings[:1], model, name="s1", options=options_of(model, {}))

    def before() -> object:
        model, _, _ = choose_model(recordings, "s1", candidates=candidates)
        return fit_auto(recordings, name="s1", candidates=(model,),
                        groups=["1"] * len(recordings)).uncertainty

    def after() -> object:
        return fit_auto(recordings, name="s1", candidates=candidates).uncertainty

    best = {"before": math.inf, "after": math.inf}
    bands = {}
    for _ in range(args.repeat):
        for name, fn in (("before", before), ("after", after)):
            start = time.perf_counter()
            bands[name] = fn()
            best[name] = min(best[name], time.perf_counter() - start)
    same = bands["before"] == bands["after"]
    print(f"{len(recordings)} runs x {args.seconds:g} s, candidates {','.join(candidates)}; "
          f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; bands identical: {same}")
    row(f"fit --model auto, {len(recordings)} rig runs x {args.seconds:g} s, "
        f"{len(candidates)} candidates (`bench_auto.py`)", f"{best['after']:.1f} s",
        f"{best['before']:.1f} s (choice, then the band's folds fitted again)",
        f"{best['before'] / best['after']:.2f}x")


if __name__ == "__main__":
    main()
