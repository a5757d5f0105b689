#!/usr/bin/env python3
# Study: Does creep_pi beat the cubic, MPI and APL on the measured data? (docs/results.md)
"""What creep memory buys: creep_pi against the cubic, MPI and APL on the measured data.

    python studies/creep_study.py --out out/creep [--models creep_pi,cubic,mpi,apl]

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

``--quick``: the thread only, creep_pi and cubic. ``--option K=V`` (repeatable): a fit
option of creep_pi (``strain-comp fit --option``), e.g. ``--option taus=[0.3,3]``.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import generalisation as gen

MODELS = ("creep_pi", "cubic", "mpi", "apl")
TARGET_MEDIAN, TARGET_WORST = 5.0, 7.5
"""Thread, leave-one-run-out, warm-up + session start [% strain]."""


def fit_one(bench: gen.Bench, sensor: gen.Sensor, run: gen.Run, model: str,
            options: Mapping[str, Any]) -> Any:
    """``strain-comp fit RUN --model MODEL`` (``options`` for creep_pi), cached."""
    if model != "creep_pi" or not options:
        return bench.fit(sensor, run, model)
    return fitted(bench, sensor, [r for r in sensor.runs if r == run], model, options,
                  f"{sensor.name}_{run.label}_{model}")


def fitted(bench: gen.Bench, sensor: gen.Sensor, runs: Sequence[gen.Run], model: str,
           options: Mapping[str, Any], stem: str) -> Any:
    """``strain-comp fit RUNS... --model MODEL --option ...``, cached under ``stem``."""
    from strain_comp.core.calibration_file import load_calibration, save_calibration
    from strain_comp.offline.fit import fit_bags

    tag = hashlib.sha256(json.dumps(dict(options), sort_keys=True).encode()).hexdigest()[:8]
    path = bench.out / "cache" / f"{stem}_{tag}_{bench.key}.yaml"
    if path.is_file() and not bench.refit:
        return load_calibration(path)
    with contextlib.redirect_stdout(sys.stderr):
        cal = fit_bags([bench.bag(sensor, run) for run in runs], model, [sensor.name],
                       dict(options))
    cal.sensors[sensor.name].strain_unit = sensor.unit
    path.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(cal, path)
    return cal


def in_run(bench: gen.Bench, sensors: Sequence[gen.Sensor], models: Sequence[str],
           options: Mapping[str, Any]) -> str:
    """Table 1: per run, each model's in-run RMSE."""
    lines = ["| sensor | run | " + " | ".join(models) + " |",
             "|---|---|" + "---:|" * len(models)]
    for sensor in sensors:
        for run in sensor.runs:
            rec = bench.recording(sensor, run)
            cells = [f"{gen.rmse(rec, fit_one(bench, sensor, run, m, options)):.2f}"
                     for m in models]
            lines.append(f"| {sensor.name} ({sensor.unit}) | {run.label} | "
                         + " | ".join(cells) + " |")
            print(lines[-1], file=sys.stderr, flush=True)
    return "\n".join(lines)


def loo_fit(bench: gen.Bench, sensor: gen.Sensor, left_out: gen.Run, model: str,
            options: Mapping[str, Any]) -> Any:
    """``strain-comp fit`` on every run of ``sensor`` but ``left_out``, cached."""
    return fitted(bench, sensor, [run for run in sensor.runs if run != left_out], model,
                  options if model == "creep_pi" else {},
                  f"{sensor.name}_loo_{left_out.label}_{model}")


def after_warm_up(rec: Any) -> Any:
    """The run cut after its first cycle (the warm-up)."""
    from strain_comp.io.recording import Recording

    keep = rec.t >= rec.t[0] + gen.first_cycle(rec.t, rec.s)
    return Recording(rec.name, rec.t[keep], rec.r[keep], rec.s[keep])


def loo(bench: gen.Bench, sensor: gen.Sensor, models: Sequence[str],
        options: Mapping[str, Any]) -> tuple[str, dict[str, dict[str, list[float]]]]:
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
            cal = loo_fit(bench, sensor, run, model, options)
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
    parser.add_argument("--option", action="append", default=[], metavar="K=V",
                        help="a fit option of creep_pi (as strain-comp fit --option)")
    args = parser.parse_args(argv)
    from strain_comp.offline.fit import parse_options
    from strain_comp.offline.options import check_fit_options

    options = parse_options(args.option)
    check_fit_options("creep_pi", options)
    models = ["creep_pi", "cubic"] if args.quick else args.models.split(",")
    sensors = gen.sensors_of(args.data)
    if "nylon" not in sensors:
        raise SystemExit(f"no silver-nylon thread runs under {args.data}")
    measured = [sensors[k] for k in (("nylon",) if args.quick else ("cb", "fiber", "nylon"))
                if k in sensors]
    bench = gen.Bench(args.data, args.out, refit=args.refit,
                      log=lambda line: print(line, file=sys.stderr))
    print("## In-run RMSE (fitted and scored on the same run)\n")
    if options:
        print(f"creep_pi fitted with {options}\n")
    print(in_run(bench, measured, models, options))
    table, scores = loo(bench, sensors["nylon"], models, options)
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
