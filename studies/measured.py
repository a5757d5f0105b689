#!/usr/bin/env python3
# Study: Every model's held-out errors on the lab recordings? (docs/results.md)
"""Held-out errors of every model on the real lab recordings (../shared/data/measured).

    python studies/measured.py --data ../shared/data/measured --out out/measured

Steps: each CSV is imported into a bag with ``strain-comp import-csv`` (the importer repairs
and counts reference glitches), each model is fitted on the training files with the same
code as ``strain-comp fit`` and scored on the held-out files with the same code as
``strain-comp evaluate`` (the engine's batch path). The split is by file, fixed in advance:

* carbon-black/PDMS strip (``cb_pdms_7p5wt``): fit on v16 (continuous triangles at 40, 80,
  120 mm/min, R 34.7-45.8 kohm); held out: v19 (triangles again, 34.1-48.5 kohm), v10
  (30 % ramps with 150 s holds, 35.7-58.4 kohm), the random sawtooth (49.1-73.3 kohm) and
  v9 (velocity profile with 300 s holds, 16.3-23.9 kohm). The runs' resistance levels
  differ by up to 3x (contact resistance, ageing between runs), so v9 is *not* in the
  training set: fitted together with v16, no model in ohm can serve both levels (tried:
  training RMSE of MPI 25.6 %, cubic 4.9 %). The files at other levels are held out to
  show, not hide, that a calibration in ohm does not carry over to them.
* conductive fibre (``conductive_fiber``): fit on run 1, held out: runs 3 and 4. The gauge
  length is not stated, so its "strain" is the crosshead extension in mm unless
  ``--fiber-gauge-mm`` is given; its errors are then in mm, not %.

A second table splits each run in time instead (fit on the first 60 %, score on the rest),
to separate model error from the run-to-run shift of the resistance level. The fitted
calibration runs through the whole run, as it would online, and is scored on the rest: a
model with memory enters the held-out part in the state the run left it in, not reset
in the middle of a hold. A third table adds the residual loop to it: each calibration
fitted on the first 60 % goes through ``diagnose_conditions`` (the code behind
``strain-comp diagnose``, default options) on that same first 60 % alone, with its own
held-out time blocks, and the calibration it returns (the model plus the terms the loop
added) is scored on the last 40 % in the same way.

Prints a Markdown table (model x held-out file, RMSE) with the wall time of every fit
(``fit_bags``: bag read, model fit incl. numba compilation on first use, training error),
writes ``results.json``, and one plot (the time series of the best model on the first
held-out carbon-black file). Models that fail to fit are listed with the reason.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
WITHIN_FIT = 0.6
"""Within-run split: fit on the first 60 % of a run's time, score on the last 40 %."""
MODELS = ("cubic", "rational", "sinh_pl", "mpi", "pl", "apl", "spike_decay")
MEMORY_MODELS = ("mpi", "pl", "apl", "spike_decay")
"""Models whose output depends on the loading history (the within-run target)."""
WITH_HOLDS = ("v9", "v10", "fiber_run1", "fiber_run3", "fiber_run4")
"""Files with holds or relaxation at constant strain (the within-run target)."""

DATASETS = {
    "cb": {
        "dir": "cb_pdms_7p5wt", "format": "cb_pdms",
        "train": ["2_7-5_E4pin_20mm_v16_0.3Strain.csv"],
        "test": ["2_7-5_E4pin_20mm_v19_0.3Strain.csv", "2_7-5_E4pin_20mm_v10_0.3Strain.csv",
                 "2_7-5_4Epin_rand_sawtooth.csv",
                 "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv"],
    },
    "fiber": {
        "dir": "conductive_fiber", "format": "fiber",
        "train": ["oldthread_sensorfiber_5x_1_synced.csv"],
        "test": ["oldthread_sensorfiber_5x_3_synced.csv", "oldthread_sensorfiber_5x_4_synced.csv"],
    },
}


def short(csv_name: str) -> str:
    """A short column label for a CSV file name."""
    for key in ("v19", "v10", "v16", "v9", "rand_sawtooth"):
        if key in csv_name:
            return key
    if "sensorfiber" in csv_name:
        return "fiber_run" + csv_name.split("_")[3]
    return Path(csv_name).stem


def import_all(data: Path, out: Path, fiber_gauge_mm: float | None) -> dict[str, Path]:
    """Import every CSV into ``out/bags``; bag path by CSV file name."""
    from strain_comp.cli import main as cli

    bags: dict[str, Path] = {}
    for sensor, spec in DATASETS.items():
        for csv_name in spec["train"] + spec["test"]:
            bag = out / "bags" / f"{Path(csv_name).stem}.mcap"
            argv = ["import-csv", str(data / spec["dir"] / csv_name), "--out", str(bag),
                    "--sensor", sensor, "--format", spec["format"]]
            if sensor == "fiber" and fiber_gauge_mm:
                argv += ["--gauge-length-mm", str(fiber_gauge_mm)]
            print(f"## import {csv_name}", file=sys.stderr)
            with contextlib.redirect_stdout(sys.stderr):  # the import reports
                code = cli(argv)
            if code != 0:
                raise SystemExit(f"import of {csv_name} failed")
            bags[csv_name] = bag
    return bags


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help=f"measured data directory (default {DEFAULT_DATA})")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "measured")
    parser.add_argument("--models", nargs="+", default=list(MODELS))
    parser.add_argument("--fiber-gauge-mm", type=float, default=None)
    parser.add_argument("--no-bound", action="store_true",
                        help="skip the in-run bound (a fit per model and held-out file)")
    args = parser.parse_args(argv)

    from strain_comp.core.calibration import Calibration
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.errors import StrainCompError
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import evaluate_recordings
    from strain_comp.offline.fit import fit_bags, in_run_bound
    from strain_comp.offline.plots import plot_time

    args.out.mkdir(parents=True, exist_ok=True)
    bags = import_all(args.data, args.out, args.fiber_gauge_mm)
    units = {"cb": "%", "fiber": "%" if args.fiber_gauge_mm else "mm"}
    recordings = {name: load_recordings(path)[0] for name, path in bags.items()}
    results: dict[str, dict] = {}
    failures: list[str] = []
    best: dict[str, tuple[float, str, Calibration]] = {}
    for sensor, spec in DATASETS.items():
        for model in args.models:
            key = f"{sensor}/{model}"
            start = time.perf_counter()
            try:
                cal = fit_bags([bags[c] for c in spec["train"]], model, [sensor])
                cal.sensors[sensor].strain_unit = units[sensor]
            except StrainCompError as err:
                failures.append(f"{key}: fit failed: {err}")
                continue
            seconds = time.perf_counter() - start
            save_calibration(cal, args.out / f"{sensor}_{model}.yaml")
            prov = cal.sensors[sensor].provenance
            row = {"fit_seconds": seconds, "fit_rmse": prov["fit_rmse"], "held_out": {},
                   "rest_resistance": cal.sensors[sensor].rest_resistance,
                   "measurement_chain": prov.get("measurement_chain")}
            for csv_name in spec["test"]:
                try:
                    result = evaluate_recordings(recordings[csv_name], cal)
                    if not args.no_bound:
                        in_run_bound(result, recordings[csv_name], cal)
                    ev = result.sensors[sensor]
                    tared = evaluate_recordings(recordings[csv_name], cal, tare="auto")
                except StrainCompError as err:
                    failures.append(f"{key} on {short(csv_name)}: {err}")
                    continue
                tev = tared.sensors[sensor]
                row["held_out"][short(csv_name)] = {
                    "rmse": ev.stats.rmse, "mae": ev.stats.mae, "max_abs": ev.stats.max_abs,
                    "r2": ev.stats.r2, "n": ev.stats.n, "n_out_of_range": ev.n_out_of_range,
                    "out_of_range_share": ev.n_out_of_range / max(ev.n_samples, 1),
                    "in_run_rmse": ev.in_run_rmse, "tare_rmse": tev.stats.rmse,
                    "tare_max_abs": tev.stats.max_abs,
                    "tare_out_of_range_share": tev.n_out_of_range / max(tev.n_samples, 1),
                    "tare_notes": [n for n in tared.notes if "tare" in n]}
            results[key] = row
            first = short(spec["test"][0])
            if first in row["held_out"]:
                score = row["held_out"][first]["rmse"]
                if sensor not in best or score < best[sensor][0]:
                    best[sensor] = (score, model, cal)
            print(f"## {key}: fit {seconds:.1f} s, training RMSE {prov['fit_rmse']:.3f}",
                  file=sys.stderr)

    print(markdown(results, args.fiber_gauge_mm))
    print(targets(results))
    within, looped = within_run(recordings, args.models, failures, units)
    print(within_markdown(within))
    print(loop_markdown(within, looped))
    if failures:
        print("\nFailures:")
        for line in failures:
            print(f"- {line}")
    (args.out / "results.json").write_text(json.dumps(
        {"results": results, "within_run": within, "within_run_loop": looped,
         "failures": failures}, indent=2) + "\n",
        encoding="utf-8")
    if "cb" in best:
        _, model, cal = best["cb"]
        first = DATASETS["cb"]["test"][0]
        ev = evaluate_recordings(recordings[first], cal).sensors["cb"]
        path = plot_time(ev, args.out / f"cb_{short(first)}_{model}.png")
        print(f"\nplot: {path}")
    return 0


def within_run(recordings: dict[str, dict], models: list[str], failures: list[str],
               units: dict[str, str] | None = None,
               ) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, dict]]]:
    """RMSE on the last ``1 - WITHIN_FIT`` of each run after fitting on its first part,
    without and with the residual loop run on that first part.

    This separates what a model can do on one run (stable contact resistance) from the
    run-to-run shift of the resistance level that the by-file split above runs into. The
    calibration runs over the whole run (its state carried into the held-out part, as
    online) and only the held-out part is scored. The loop (``diagnose_conditions`` with
    its defaults: ten time blocks, every third held out) sees the first part only; the
    scored part never chooses a term.
    """
    from strain_comp.core.calibration import Calibration
    from strain_comp.core.metrics import error_stats
    from strain_comp.diagnosis.conditions import diagnose_conditions
    from strain_comp.diagnosis.report import effect_reading
    from strain_comp.errors import StrainCompError
    from strain_comp.offline.evaluate import evaluate_recordings
    from strain_comp.offline.fit import fit_sensor

    table: dict[str, dict[str, float]] = {}
    looped: dict[str, dict[str, dict]] = {}
    for csv_name, by_sensor in recordings.items():
        (sensor, rec), = by_sensor.items()
        cut = rec.t[0] + WITHIN_FIT * (rec.t[-1] - rec.t[0])
        head, tail = rec.t <= cut, rec.t > cut
        part = {k: None if getattr(rec, k) is None else getattr(rec, k)[head]
                for k in ("t", "r", "s", "temperature")}
        training = dataclasses.replace(rec, **part)
        row = table.setdefault(short(csv_name), {})
        loop_row = looped.setdefault(short(csv_name), {})
        for model in models:
            try:
                fitted = fit_sensor([training], model, name=sensor)
                fitted.strain_unit = (units or {}).get(sensor, "%")
                cal = Calibration({sensor: fitted})
                ev = evaluate_recordings({sensor: rec}, cal)
            except StrainCompError as err:
                failures.append(f"within-run {short(csv_name)}/{model}: {err}")
                continue
            scored = ev.sensors[sensor]
            keep = scored.scored & tail
            row[model] = error_stats(scored.estimate[keep], scored.reference[keep]).rmse
            try:
                found = diagnose_conditions({sensor: training}, cal)
                ev = evaluate_recordings({sensor: rec}, found.calibration)
            except StrainCompError as err:
                failures.append(f"within-run loop {short(csv_name)}/{model}: {err}")
                continue
            scored = ev.sensors[sensor]
            keep = scored.scored & tail
            top = max((e for e in found.sensors[sensor].scores if e.kind != "baseline"),
                      key=lambda e: e.score)
            loop_row[model] = {
                "rmse": error_stats(scored.estimate[keep], scored.reference[keep]).rmse,
                "condition": next(c["name"] for c in found.conditions if c["chosen"]),
                "conditions": [{k: None if isinstance(v, float) and v != v else v
                                for k, v in c.items()} for c in found.conditions],
                "added": [{"name": a.name, "kind": a.kind, "coef": a.coef,
                           "reading": effect_reading(a.kind, a.params, a.coef or 0.0,
                                                     a.magnitude, unit=fitted.strain_unit)}
                          for a in found.added],
                "loop_before": found.before["rmse"], "loop_after": found.after["rmse"],
                "message": found.sensors[sensor].message,
                "top_score": {"name": top.name, "score": top.score},
                "offset_score": next((e.score for e in found.sensors[sensor].scores
                                      if e.kind == "offset"), None)}
        print(f"## within-run {short(csv_name)} done", file=sys.stderr)
    return table, looped


def within_markdown(table: dict[str, dict[str, float]]) -> str:
    """Within-run table: one row per file, one column per model."""
    models = list(dict.fromkeys(m for row in table.values() for m in row))
    lines = [f"\nwithin one run: fit on the first {100 * WITHIN_FIT:.0f} % of the time, "
             "RMSE on the rest (cb in % strain, fiber in the unit above)\n",
             "| file | " + " | ".join(models) + " |", "|---|" + "---:|" * len(models)]
    for name, row in table.items():
        cells = [f"{row[m]:.3f}" if m in row else "failed" for m in models]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def loop_markdown(within: dict[str, dict[str, float]], looped: dict[str, dict[str, dict]],
                  ) -> str:
    """Within-run table after the loop, the terms it added, and the within-run target
    (best memory model <= 0.8 x the cubic on the files with holds) without and with it."""
    models = list(dict.fromkeys(m for row in looped.values() for m in row))
    lines = ["\nwithin one run, after the loop on the training part (the first "
             f"{100 * WITHIN_FIT:.0f} %, its own held-out blocks); RMSE on the rest, "
             "* = the loop changed the calibration\n",
             "| file | " + " | ".join(models) + " |", "|---|" + "---:|" * len(models)]
    for name, row in looped.items():
        cells = ["failed" if m not in row else f"{row[m]['rmse']:.3f}"
                 + ("*" if row[m]["added"] or row[m]["condition"] != "as calibrated" else "")
                 for m in models]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("\nwhat the loop did (held-out blocks of the training part: before -> after)")
    for name, row in looped.items():
        for m, cell in row.items():
            what = "; ".join(f"{a['name']}: {a['reading']}" for a in cell["added"])
            if cell["condition"] != "as calibrated":
                what = f"condition {cell['condition']}" + (f"; {what}" if what else "")
            if not what:
                continue
            lines.append(f"- {name}/{m}: {what} ({cell['loop_before']:.3f} -> "
                         f"{cell['loop_after']:.3f})")
    untouched = [f"{name}/{m} ({c['top_score']['name']} {c['top_score']['score']:.2f}"
                 + (", vetoed on the held-out blocks" if "looked useful" in c["message"]
                    else "")
                 + ("" if c["offset_score"] is None else f"; offset {c['offset_score']:.2f}")
                 + ")"
                 for name, row in looped.items() for m, c in row.items()
                 if not c["added"] and c["condition"] == "as calibrated"]
    if untouched:
        lines.append("- nothing added (best candidate and the intercept alone, their "
                     "cross-validated scores): "
                     + ", ".join(untouched))
    lines += ["\nwithin-run target: best memory model "
              f"({', '.join(MEMORY_MODELS)}) <= 0.8 x the cubic\n",
              "| file | without the loop | with the loop, against the cubic without | "
              "with the loop, against the cubic with |", "|---|---|---|---|"]
    met = [0, 0, 0]
    files = [f for f in WITH_HOLDS if f in within and f in looped]
    for f in files:
        cells = []
        pairs = ((within[f], within[f]), (looped[f], within[f]), (looped[f], looped[f]))
        for k, (memory, static) in enumerate(pairs):
            rmse = {m: v if isinstance(v, float) else v["rmse"] for m, v in memory.items()}
            base = static.get("cubic")
            base = base if base is None or isinstance(base, float) else base["rmse"]
            have = [m for m in MEMORY_MODELS if m in rmse]
            if base is None or not have:
                cells.append("n/a")
                continue
            best = min(have, key=rmse.__getitem__)
            ratio = rmse[best] / base
            met[k] += ratio <= 0.8
            cells.append(f"{best} {rmse[best]:.3f} / cubic {base:.3f} = {ratio:.2f} "
                         + ("met" if ratio <= 0.8 else "not met"))
        lines.append(f"| {f} | " + " | ".join(cells) + " |")
    lines.append("\nmet on " + " / ".join(f"{n} of {len(files)}" for n in met) + " files")
    return "\n".join(lines)


def targets(results: dict[str, dict]) -> str:
    """Per held-out run: the best model without and with tare, and whether the best tared
    model is within 1.5 x its own in-run bound."""
    lines = ["\nper held-out run: best model without tare, with tare, and its in-run bound\n",
             "| run | best without tare | best with tare | in-run bound of that model | "
             "within 1.5 x bound |", "|---|---|---|---:|---|"]
    runs = dict.fromkeys(f for row in results.values() for f in row["held_out"])
    within = 0
    for f in runs:
        cells = {key: row["held_out"][f] for key, row in results.items()
                 if f in row["held_out"]}
        plain = min(cells, key=lambda k: cells[k]["rmse"])
        tared = min(cells, key=lambda k: cells[k]["tare_rmse"])
        bound = cells[tared].get("in_run_rmse")
        ok = bound is not None and cells[tared]["tare_rmse"] <= 1.5 * bound
        within += ok
        lines.append(f"| {f} | {plain.split('/')[1]} {cells[plain]['rmse']:.3f} | "
                     f"{tared.split('/')[1]} {cells[tared]['tare_rmse']:.3f} | "
                     + ("n/a" if bound is None else f"{bound:.3f}")
                     + f" | {'yes' if ok else 'no'} |")
    lines.append(f"\n{within} of {len(runs)} held-out runs within 1.5 x the in-run bound")
    return "\n".join(lines)


def markdown(results: dict[str, dict], fiber_gauge_mm: float | None) -> str:
    """Held-out RMSE table, one row per dataset and model, one column per held-out file."""
    lines = []
    for sensor, spec in DATASETS.items():
        unit = "mm" if sensor == "fiber" and not fiber_gauge_mm else "% strain"
        files = [short(c) for c in spec["test"]]
        trained = " + ".join(short(c) for c in spec["train"])
        lines.append(f"\n{sensor} (fit on {trained}; held-out RMSE [{unit}]: without tare / "
                     "with `--tare auto`, and in brackets the in-run bound, the same model "
                     "fitted on that run itself)\n")
        lines.append("| model | fit time [s] | train RMSE | " + " | ".join(files) + " |")
        lines.append("|---|---:|---:|" + "---:|" * len(files))
        for key, row in results.items():
            if not key.startswith(f"{sensor}/"):
                continue
            cells = []
            for f in files:
                h = row["held_out"].get(f)
                bound = h.get("in_run_rmse") if h else None
                cells.append("failed" if not h else
                             f"{h['rmse']:.3f} / {h['tare_rmse']:.3f}"
                             + (f" [{bound:.3f}]" if bound is not None else ""))
            lines.append(f"| {key.split('/')[1]} | {row['fit_seconds']:.1f} | "
                         f"{row['fit_rmse']:.3f} | " + " | ".join(cells) + " |")
        # the valid range comes from the training data alone: the same for every model
        shares = {f: h["out_of_range_share"] for key, row in results.items()
                  if key.startswith(f"{sensor}/") for f, h in row["held_out"].items()}
        tared = {f: h["tare_out_of_range_share"] for key, row in results.items()
                 if key.startswith(f"{sensor}/") for f, h in row["held_out"].items()}
        if shares:
            lines.append("\nheld-out samples outside the calibration's resistance range: "
                         + ", ".join(f"{f} {100 * v:.0f} %" for f, v in shares.items())
                         + "; with tare: "
                         + ", ".join(f"{f} {100 * v:.0f} %" for f, v in tared.items()))
        notes = {f: h["tare_notes"] for key, row in results.items()
                 if key.startswith(f"{sensor}/") for f, h in row["held_out"].items()}
        lines += [f"- {f}: " + "; ".join(n) for f, n in notes.items() if n]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
