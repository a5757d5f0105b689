#!/usr/bin/env python3
"""What creep memory buys: creep_pi against the cubic, MPI and APL on the measured data.

    python scripts/creep_study.py --out out/creep [--models creep_pi,cubic,mpi,apl]

Two tables (RMSE in % strain, mm for the fibre), every number through the code of the
command line (``strain-comp import-csv``, ``fit``, ``evaluate``, ``recalibrate``; bags, fits
and sensors as ``scripts/generalisation.py`` makes them, fits cached in ``OUT/cache``):

1. **In-run**: each model fitted on one run and scored on that run (``evaluate
   --in-run-bound``), every run of the carbon-black strip, the conductive fibre and the
   silver-nylon thread.
2. **Leave-one-run-out on the thread's 7 runs**: fitted on the 6 others (``strain-comp fit
   A B C D E F``), scored on the one left out, in three workflows:

   * ``plain``: the calibration as it is (``evaluate --tare calibration``);
   * ``session start``: ``recalibrate --input --from B --first S`` then ``recalibrate
     --from B --first S``, S the run's first cycle (``generalisation.first_cycle``), scored
     on all of B;
   * ``warm-up + session start``: the same on the run cut after its first cycle (one
     unreferenced warm-up cycle, then the calibration cycle), scored on what follows the
     warm-up.

``--quick``: the thread only, creep_pi and cubic.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generalisation as gen

MODELS = ("creep_pi", "cubic", "mpi", "apl")
TARGET_MEDIAN, TARGET_WORST = 5.0, 7.5
"""Thread, leave-one-run-out, warm-up + session start [% strain]."""


def in_run(bench: gen.Bench, sensors: Sequence[gen.Sensor], models: Sequence[str]) -> str:
    """Table 1: per run, each model's in-run RMSE and creep_pi's ratio to the cubic's."""
    lines = ["| sensor | run | " + " | ".join(models) + " |",
             "|---|---|" + "---:|" * len(models)]
    for sensor in sensors:
        for run in sensor.runs:
            rec = bench.recording(sensor, run)
            cells = [f"{gen.rmse(rec, bench.fit(sensor, run, m)):.2f}" for m in models]
            lines.append(f"| {sensor.name} ({sensor.unit}) | {run.label} | "
                         + " | ".join(cells) + " |")
            print(lines[-1], file=sys.stderr, flush=True)
    return "\n".join(lines)


def loo_fit(bench: gen.Bench, sensor: gen.Sensor, left_out: gen.Run, model: str) -> Any:
    """``strain-comp fit`` on every run of ``sensor`` but ``left_out``, cached."""
    from strain_comp.core.calibration import load_calibration, save_calibration
    from strain_comp.offline.fit import fit_bags

    path = bench.out / "cache" / f"{sensor.name}_loo_{left_out.label}_{model}_{bench.key}.yaml"
    if path.is_file() and not bench.refit:
        return load_calibration(path)
    bags = [bench.bag(sensor, run) for run in sensor.runs if run != left_out]
    with contextlib.redirect_stdout(sys.stderr):
        cal = fit_bags(bags, model, [sensor.name])
    cal.sensors[sensor.name].strain_unit = sensor.unit
    path.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(cal, path)
    return cal


def after_warm_up(rec: Any) -> Any:
    """The run cut after its first cycle (the warm-up)."""
    from strain_comp.io.recording import Recording

    keep = rec.t >= rec.t[0] + gen.first_cycle(rec.t, rec.s)
    return Recording(rec.name, rec.t[keep], rec.r[keep], rec.s[keep])


def loo(bench: gen.Bench, sensor: gen.Sensor, models: Sequence[str]
        ) -> tuple[str, dict[str, dict[str, list[float]]]]:
    """Table 2 and its numbers {model: {workflow: [RMSE per left-out run]}}."""
    workflows = ("plain", "session start", "warm-up + session start")
    both = ("input", "output")
    scores: dict[str, dict[str, list[float]]] = {m: {w: [] for w in workflows} for m in models}
    lines = ["| left out | " + " | ".join(f"{m} {w}" for m in models for w in workflows) + " |",
             "|---|" + "---:|" * (len(models) * len(workflows))]
    for run in sensor.runs:
        rec = bench.recording(sensor, run)
        cut = after_warm_up(rec)
        cells = []
        for model in models:
            cal = loo_fit(bench, sensor, run, model)
            values = (gen.rmse(rec, cal),
                      gen.rmse(rec, gen.chain(rec, cal, gen.first_cycle(rec.t, rec.s), both)),
                      gen.rmse(cut, gen.chain(cut, cal, gen.first_cycle(cut.t, cut.s), both)))
            for w, v in zip(workflows, values, strict=True):
                scores[model][w].append(v)
            cells += [f"{v:.2f}" for v in values]
        lines.append(f"| {run.label} | " + " | ".join(cells) + " |")
        print(lines[-1], file=sys.stderr, flush=True)
    for stat, fn in (("median", np.median), ("worst", np.max)):
        lines.append(f"| **{stat}** | " + " | ".join(
            f"**{float(fn(scores[m][w])):.2f}**" for m in models for w in workflows) + " |")
    return "\n".join(lines), scores


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=gen.DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=Path("out/creep"))
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--refit", action="store_true")
    args = parser.parse_args(argv)
    models = ["creep_pi", "cubic"] if args.quick else args.models.split(",")
    sensors = gen.sensors_of(args.data)
    if "nylon" not in sensors:
        raise SystemExit(f"no silver-nylon thread runs under {args.data}")
    measured = [sensors[k] for k in (("nylon",) if args.quick else ("cb", "fiber", "nylon"))
                if k in sensors]
    bench = gen.Bench(args.data, args.out, refit=args.refit,
                      log=lambda line: print(line, file=sys.stderr))
    print("## In-run RMSE (fitted and scored on the same run)\n")
    print(in_run(bench, measured, models))
    table, scores = loo(bench, sensors["nylon"], models)
    print("\n## Thread, leave-one-run-out (fitted on the 6 other runs) [% strain]\n")
    print(table)
    print()
    for model in models:
        warm = scores[model]["warm-up + session start"]
        median, worst = float(np.median(warm)), float(np.max(warm))
        met = median <= TARGET_MEDIAN and worst <= TARGET_WORST
        print(f"{model}: warm-up + session start median {median:.2f} (target <= "
              f"{TARGET_MEDIAN}), worst {worst:.2f} (target <= {TARGET_WORST}): "
              f"{'met' if met else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
