#!/usr/bin/env python3
# Study: What does the residual loop change on the real lab recordings? (docs/results.md)
"""The residual loop on the real lab recordings (../shared/data/measured): before/after table.

    python studies/measured_diagnose.py --data ../shared/data/measured --out out/diagnose

Per data set, fixed in advance (by file, never by sample):

* carbon-black/PDMS strip (``cb_pdms_7p5wt``, strain in %): fit on v16, diagnose on v19,
  validate on v10;
* the same strip across resistance levels and the alternating excitation: fit on v16,
  diagnose on the random sawtooth, validate on v9 (the run whose excitation alternates);
* conductive fibre (``conductive_fiber``, "strain" = crosshead extension in mm, since the
  gauge length is not stated): fit on run 1, diagnose on run 3, validate on run 4.

The loop runs under each condition of ``strain_comp.diagnosis.conditions`` (as
calibrated; ``--tare auto``; the alternation, spike and baseline-step corrections when the
data show them) and keeps the one with the lowest validation RMSE (``strain-comp diagnose
--tare auto``).

Each CSV is imported with ``strain_comp.io.csv_import.import_csv`` (the importer behind
``strain-comp import-csv``), the calibration is fitted with ``strain_comp.offline.fit.fit_sensor``
(``strain-comp fit``) and ``strain_comp.diagnosis.loop.diagnose`` (``strain-comp diagnose
--validate``) adds what lowers the error on the validation run. "before" and "after" are
the RMSE on the validation run without and with the added terms, after the session-start
recalibration after its warm-up stretch (``--session-start on``, the default, as ``diagnose``;
``off``: through the engine as calibrated). With it on, the last column but one gives the
chosen result's figures without that recalibration as well.

``--carry`` (``CARRY``) judges the loop where the condition changes between runs, as the
product is used: per sensor (carbon black, fibre, silver-nylon thread, the virtual rig) the
model is fitted on one run, ``diagnose`` (``--tare auto``) works on that run and validates on
two others after their session start (the fibre has one other), and the calibration as fitted
and as diagnosed is then used on each later run after that run's own session start
(``strain-comp start CAL RUN``: its second load and unload after a warm-up one, or the first
where the run has no second or a step is refused there; ``strain_comp.offline.session_start``,
as the loop and the benchmark). Prints a table (later run: before -> after the loop, the
change, what the loop found or why it added nothing) and writes ``carry.json`` into ``--out``:

    python studies/measured_diagnose.py --carry --models cubic mpi --out out/carry

Prints a Markdown table (data set x model: before, after, effects added), writes
``results.json``, the diagnosed calibrations (``<set>_<model>_diagnosed.yaml``) and the
residual plots (``plots/``) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
DEFAULT_MODELS = ("cubic", "rational", "mpi")
DATASETS = {
    "cb_pdms": {"dir": "cb_pdms_7p5wt", "format": "cb_pdms", "unit": "%",
                "fit": "2_7-5_E4pin_20mm_v16_0.3Strain.csv",
                "diagnose": "2_7-5_E4pin_20mm_v19_0.3Strain.csv",
                "validate": "2_7-5_E4pin_20mm_v10_0.3Strain.csv"},
    "cb_levels": {"dir": "cb_pdms_7p5wt", "format": "cb_pdms", "unit": "%",
                  "fit": "2_7-5_E4pin_20mm_v16_0.3Strain.csv",
                  "diagnose": "2_7-5_4Epin_rand_sawtooth.csv",
                  "validate": "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv"},
    "fiber": {"dir": "conductive_fiber", "format": "fiber", "unit": "mm",
              "fit": "oldthread_sensorfiber_5x_1_synced.csv",
              "diagnose": "oldthread_sensorfiber_5x_3_synced.csv",
              "validate": "oldthread_sensorfiber_5x_4_synced.csv"},
}


NYLON = {"dir": "nylon_silver/session1_100Hz", "format": "generic", "unit": "%",
         "columns": {"time": "time_s", "resistance": "r_over_r0", "strain": "position"},
         "scales": {"strain": 100.0}}
CARRY = {
    "cb": {"dir": "cb_pdms_7p5wt", "format": "cb_pdms", "unit": "%",
           "diagnose": "2_7-5_E4pin_20mm_v16_0.3Strain.csv",
           "validate": ["2_7-5_E4pin_20mm_v19_0.3Strain.csv", "2_7-5_4Epin_rand_sawtooth.csv"],
           "evaluate": ["2_7-5_E4pin_20mm_v10_0.3Strain.csv",
                        "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv"]},
    "fiber": {"dir": "conductive_fiber", "format": "fiber", "unit": "mm",
              "diagnose": "oldthread_sensorfiber_5x_1_synced.csv",
              "validate": ["oldthread_sensorfiber_5x_3_synced.csv"],
              "evaluate": ["oldthread_sensorfiber_5x_4_synced.csv"]},
    "nylon": {**NYLON, "diagnose": "sin_20.csv", "validate": ["tri_50.csv", "mixed_10_20.csv"],
              "evaluate": ["sin_30.csv", "sin_40.csv", "mixed_15_25.csv", "mixed_20_30.csv"]},
    "rig": {"dir": "rig:", "format": "rig", "unit": "%", "diagnose": "random",
            "validate": ["steps", "patterns"], "evaluate": ["triangle", "rates"]},
}
"""``--carry``: per sensor, the run a calibration is fitted on and diagnosed, the runs the
loop validates on (two where the data have them; the fibre has three runs in all), and the
later runs it is judged on, fixed in advance by file."""


def carry_recording(spec: dict, run: str, name: str) -> Any:
    """One run of ``CARRY`` as a Recording named ``name`` (the rig: ``simulate``, seed 1,
    its default effects)."""
    from strain_comp.io.csv_import import import_csv
    from strain_comp.io.recording import Recording
    from strain_comp.offline.rig import simulate

    if spec["format"] == "rig":
        sim = simulate(run, seed=1).sensors["s1"]
        return Recording(name, sim.t, sim.resistance, sim.strain)
    return import_csv(Path(spec["data"]) / spec["dir"] / run, fmt=spec["format"], sensor=name,
                      columns=spec.get("columns"), scales=spec.get("scales")).recording


def policy_of(changes: list[str]) -> Any:
    """``LOOP_POLICY`` with the fields ``FIELD=VALUE`` of ``changes`` changed."""
    import dataclasses

    from strain_comp.diagnosis.policy import LOOP_POLICY

    fields = {f.name: f.type for f in dataclasses.fields(LOOP_POLICY)}
    values: dict[str, Any] = {}
    for change in changes:
        key, _, value = change.partition("=")
        if key not in fields:
            raise SystemExit(f"--policy: no field {key!r} (fields: {', '.join(fields)})")
        values[key] = int(value) if fields[key] in (int, "int") else float(value)
    return dataclasses.replace(LOOP_POLICY, **values)


def carry(args: argparse.Namespace) -> int:
    """The loop judged on later runs after their session start (module docstring)."""
    import numpy as np

    from strain_comp.core.calibration import Calibration
    from strain_comp.diagnosis.conditions import diagnose_conditions
    from strain_comp.diagnosis.session import session_errors
    from strain_comp.offline.fit import fit_sensor

    def used(cal: Calibration, name: str, rec: Any) -> float:
        errors = session_errors(cal, {name: rec}, name)
        return float(np.sqrt(np.mean(errors ** 2)))

    policy = policy_of(args.policy)
    rows = []
    for name, spec in CARRY.items():
        if args.sensors and name not in args.sensors:
            continue
        spec = {**spec, "data": args.data}
        recs = {run: carry_recording(spec, run, name)
                for run in [spec["diagnose"], *spec["validate"], *spec["evaluate"]]}
        for model in args.models:
            start = time.perf_counter()
            fitted = fit_sensor([recs[spec["diagnose"]]], model, name=name,
                                options={"progress": False} if model in ("apl", "pl", "mpi")
                                else {})
            fitted.strain_unit = spec["unit"]
            cal = Calibration({name: fitted})
            result = diagnose_conditions({name: recs[spec["diagnose"]]}, cal,
                                         validate_recordings=[{name: recs[v]}
                                                              for v in spec["validate"]],
                                         tare="auto", policy=policy)
            d = result.sensors[name]
            found = "; ".join(f"{a.name}: {a.reading()}" for a in result.added) or d.message
            chosen = next(c for c in result.conditions if c.get("chosen"))
            if chosen["name"] != "as calibrated":
                found = f"condition {chosen['name']} chosen; {found}"
            for run in spec["evaluate"]:
                before, after = used(cal, name, recs[run]), used(result.calibration, name,
                                                                 recs[run])
                rows.append({"sensor": name, "model": model, "unit": spec["unit"],
                             "diagnose": spec["diagnose"], "validate": spec["validate"],
                             "evaluate": run, "before": before, "after": after,
                             "added": [a.name for a in result.added], "found": found,
                             "seconds": round(time.perf_counter() - start, 1)})
            print(f"## {name}/{model}: {d.message} ({time.perf_counter() - start:.1f} s)",
                  file=sys.stderr)
    print("| sensor | model | fit + diagnose | validate | later run | RMSE after its session "
          "start: before -> after the loop | change | what the loop found |")
    print("|---|---|---|---|---|---|---:|---|")
    for row in rows:
        change = 100.0 * (row["after"] / row["before"] - 1.0) if row["before"] > 0 else 0.0
        print(f"| {row['sensor']} | {row['model']} | {short(row['diagnose'])} | "
              f"{', '.join(short(v) for v in row['validate'])} | {short(row['evaluate'])} | "
              f"{row['before']:.3f} -> {row['after']:.3f} {row['unit']} | {change:+.0f} % | "
              f"{row['found']} |")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "carry.json").write_text(json.dumps({"rows": rows}, indent=2) + "\n",
                                         encoding="utf-8")
    return 0


def short(run: str) -> str:
    """A run's short label: v16, run 1, sin_20, rig:random."""
    stem = run.removesuffix(".csv")
    for prefix, label in (("2_7-5_E4pin_20mm_", ""), ("2_7-5_4Epin_", ""),
                          ("oldthread_sensorfiber_5x_", "run ")):
        if stem.startswith(prefix):
            stem = label + stem.removeprefix(prefix).split("_")[0].removesuffix("_synced")
    return stem if stem != "rand" else "sawtooth"


def without(row: dict) -> str:
    """The chosen result's before -> after without the session start ("-": none made)."""
    if not row["as_calibrated"]:
        return "-"
    return (f"{row['as_calibrated']['before']:.3f} -> {row['as_calibrated']['after']:.3f} "
            f"{row['unit']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help=f"measured data directory (default {DEFAULT_DATA})")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "diagnose")
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS),
                        help=f"models to fit (default {' '.join(DEFAULT_MODELS)})")
    parser.add_argument("--session-start", choices=("on", "off"), default="on",
                        help="diagnose --session-start (default on)")
    parser.add_argument("--carry", action="store_true",
                        help="the loop judged on later runs after their session start (CARRY)")
    parser.add_argument("--sensors", nargs="+", choices=sorted(CARRY),
                        help="with --carry: these sensors only (default all)")
    parser.add_argument("--policy", nargs="+", default=[], metavar="FIELD=VALUE",
                        help="with --carry: the loop's policy with these fields changed "
                             "(strain_comp.diagnosis.policy.LoopPolicy, e.g. spread=1)")
    args = parser.parse_args(argv)
    if args.carry:
        return carry(args)

    from strain_comp.core.calibration import Calibration
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.diagnosis.conditions import diagnose_conditions
    from strain_comp.diagnosis.report import SESSION_RECORDS, write_plots
    from strain_comp.errors import StrainCompError
    from strain_comp.io.csv_import import import_csv
    from strain_comp.offline.fit import fit_sensor

    args.out.mkdir(parents=True, exist_ok=True)
    rows, failures = [], []
    for name, spec in DATASETS.items():
        recs = {}
        for role in ("fit", "diagnose", "validate"):
            path = args.data / spec["dir"] / spec[role]
            try:
                recs[role] = import_csv(path, fmt=spec["format"], sensor=name).recording
            except StrainCompError as err:
                raise SystemExit(f"import of {path} failed: {err}") from None
        for model in args.models:
            start = time.perf_counter()
            try:
                fitted = fit_sensor([recs["fit"]], model, name=name,
                                    options={"progress": False}
                                    if model in ("apl", "pl", "mpi") else {})
                fitted.strain_unit = spec["unit"]
                cal = Calibration({name: fitted})
                result = diagnose_conditions({name: recs["diagnose"]}, cal,
                                             validate_recordings={name: recs["validate"]},
                                             tare="auto",
                                             session_start=args.session_start == "on")
            except StrainCompError as err:
                failures.append(f"{name}/{model}: {err}")
                continue
            seconds = time.perf_counter() - start
            save_calibration(result.calibration, args.out / f"{name}_{model}_diagnosed.yaml")
            write_plots(result, args.out / "plots" / f"{name}_{model}")
            added = result.added
            rows.append({
                "data": name, "model": model, "unit": spec["unit"],
                "fit": spec["fit"], "diagnose": spec["diagnose"], "validate": spec["validate"],
                "before": result.before["rmse"], "after": result.after["rmse"],
                "as_calibrated": {k: v["rmse"] for k, v in
                                  result.sensors[name].as_calibrated.items()},
                "added": [{"name": a.name, "kind": a.kind, "coef": a.coef,
                           "reading": a.reading()}
                          for a in added],
                "conditions": result.conditions,
                "message": result.sensors[name].message, "seconds": round(seconds, 2),
                "top_scores": [(e.name, e.score) for e in sorted(
                    result.sensors[name].scores, key=lambda e: -e.score)[:3]]})
            print(f"## {name}/{model}: {result.sensors[name].message} ({seconds:.1f} s)",
                  file=sys.stderr)
    print("| data (fit -> diagnose -> validate) | model | validation RMSE after the loop: "
          "as calibrated | with tare | with alternation correction | with despike | with "
          "baseline-step correction | chosen: before -> after | chosen, without the session "
          "start: before -> after | effects added (reading) |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|---|")
    for row in rows:
        short = {"cb_pdms": "cb_pdms (v16 -> v19 -> v10)",
                 "cb_levels": "cb_pdms (v16 -> rand_sawtooth -> v9)",
                 "fiber": "fiber (run 1 -> run 3 -> run 4)"}[row["data"]]
        effects = "; ".join(f"{a['name']}: {a['reading']}" for a in row["added"]) \
            or "none (nothing helps)"
        after = {c["name"]: c["after"] for c in row["conditions"]}
        chosen = next(c["name"] for c in row["conditions"] if c["chosen"])

        def cell(key: str, after: dict = after, unit: str = row["unit"]) -> str:
            key = key if key in after else f"{key} + tare"  # chain corrections with tare
            return f"{after[key]:.3f} {unit}" if key in after else "-"

        print(f"| {short} | {row['model']} | {cell('as calibrated')} | {cell('tare')} | "
              f"{cell('alternation')} | {cell('despike')} | {cell('baseline step')} | "
              f"{chosen}: {row['before']:.3f} -> "
              f"{row['after']:.3f} {row['unit']} | {without(row)} | {effects} |")
    starts = [f"{row['data']}/{row['model']}: {c['reading']}" for row in rows
              for c in row["conditions"] if c["name"] in SESSION_RECORDS]
    if starts:
        print("\nsession start on the validation runs: " + "; ".join(starts))
    readings = dict.fromkeys(c["reading"] for row in rows for c in row["conditions"]
                             if c["name"] == "measurement chain")
    if readings:
        print("\nmeasurement chain found in the diagnosed runs: " + "; ".join(readings))
    if failures:
        print("\nFailures:")
        for line in failures:
            print(f"- {line}")
    (args.out / "results.json").write_text(json.dumps({"rows": rows, "failures": failures},
                                                      indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
