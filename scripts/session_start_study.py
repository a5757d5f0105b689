#!/usr/bin/env python3
"""How the session start on a run's second cycle is made, leave one run out.

    python scripts/session_start_study.py --sensors nylon fiber --models creep_pi cubic

The leave-one-run-out calibrations of ``scripts/generalisation.py`` (``fit A C D ...``,
pooled in one input space; its fit cache in ``OUT/cache``) used on the left-out run B after
a session start on B's second cycle (``second_cycle``: one unreferenced warm-up cycle
first), made each of these ways, and scored on all of B (``evaluate``'s RMSE):

* ``io``: ``recalibrate --input`` then ``recalibrate`` (output gain and offset), the
  benchmark's ``warmup``;
* ``i``: ``recalibrate --input`` only; ``o``: the output gain and offset only;
* ``line``: B's cycle put into the pooled input space as each training run was put there
  by its own zero and sensitivity: the cycle's least-squares line of resistance on strain
  mapped onto the line through the mapped training runs (``pool.run_line``; the maps of the
  calibration's ``pooled_runs``), no output step; ``lineo``: ``line``, then the output
  gain and offset.

Prints per run and the median / worst per sensor, model and variant.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import generalisation as g  # noqa: E402

VARIANTS = ("io", "i", "o", "line", "lineo")


def recalibrated(rec: Any, cal: Any, span: tuple[float, float], forms: tuple[str, ...]) -> Any:
    """``cal`` after ``recalibrate [--input] --from B --window START:END`` per form (a step
    that cannot be made is skipped, as in the benchmark)."""
    from strain_comp.errors import StrainCompError
    from strain_comp.offline.recalibrate import recalibrate_recordings

    for form in forms:
        try:
            cal = recalibrate_recordings(
                cal, {rec.name: rec}, form=form, span=None if span[0] == 0.0 else span,
                first=span[1] if span[0] == 0.0 else None,
                tare="calibration" if form == "output" else "auto")[0]
        except StrainCompError:
            continue
    return cal


def spanned_by_line(bench: g.Bench, sensor: g.Sensor, others: list[g.Run], rec: Any,
                    cal: Any, span: tuple[float, float]) -> Any:
    """``cal`` reading B through the map that puts its cycle's line onto the pooled space's."""
    from strain_comp.core.calibration import Calibration
    from strain_comp.offline.pool import run_line
    from strain_comp.offline.recalibrate import apply_span, cut

    name = rec.name
    maps = cal.sensors[name].provenance.get("pooled_runs") or []
    r_all, s_all = [], []
    for i, run in enumerate(others):
        train = bench.recording(sensor, run)
        r_all.append(train.r if not maps else maps[i]["rest_calibrated"]
                     + maps[i]["span_gain"] * (train.r - maps[i]["rest"]))
        s_all.append(train.s)
    r = np.concatenate(r_all)
    space = run_line(replace(rec, t=np.arange(r.size, dtype=np.float64), r=r,
                             s=np.concatenate(s_all)))
    own = run_line(cut(rec, *span))
    if space is None or own is None:
        return cal
    zero_span = (own[0], space[0], space[1] / own[1])
    return Calibration({name: apply_span(cal.sensors[name], zero_span, {"study": "line"})})


def started_by(variant: str, bench: g.Bench, sensor: g.Sensor, others: list[g.Run],
               rec: Any, cal: Any, span: tuple[float, float]) -> Any:
    """``cal`` after the session start ``variant`` (module docstring) on ``span`` of B."""
    if variant.startswith("line"):
        cal = spanned_by_line(bench, sensor, others, rec, cal, span)
    forms = {"io": ("input", "output"), "i": ("input",), "o": ("output",), "line": (),
             "lineo": ("output",)}[variant]
    return recalibrated(rec, cal, span, forms)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=g.DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=REPO / "out" / "generalisation")
    parser.add_argument("--sensors", nargs="+", default=["nylon", "fiber"])
    parser.add_argument("--models", nargs="+", default=list(g.DEFAULT_MODELS))
    parser.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    args = parser.parse_args()
    bench = g.Bench(args.data, args.out, log=lambda line: print(line, file=sys.stderr))
    sensors = g.sensors_of(args.data)
    for sensor in (sensors[name] for name in args.sensors):
        for model in args.models:
            found: dict[str, list[float]] = {v: [] for v in args.variants}
            for test in sensor.runs:
                others = [r for r in sensor.runs if r != test]
                cal = bench.fit(sensor, tuple(others), model)
                rec = bench.recording(sensor, test)
                second = g.second_cycle(rec.t, rec.s) or (0.0, g.first_cycle(rec.t, rec.s))
                for variant in args.variants:
                    started = started_by(variant, bench, sensor, others, rec, cal, second)
                    found[variant].append(g.rmse(rec, started))
                print(f"{sensor.name} {model} {test.label}: " + ", ".join(
                    f"{v} {found[v][-1]:.2f}" for v in args.variants), flush=True)
            for variant, values in found.items():
                print(f"## {sensor.name} {model} {variant}: median {np.median(values):.2f} "
                      f"worst {np.max(values):.2f} {sensor.unit}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
