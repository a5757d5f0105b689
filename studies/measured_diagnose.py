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

``--another-day`` closes the loop on the thread's other day (``another_day``): fitted on
session 1, every split of the five session-2 runs, through the user's commands:

    python studies/measured_diagnose.py --another-day --models creep_pi --jobs 2 \
        --out /tmp/another_day

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
        sim = simulate(run, seed=1)["s1"]
        return Recording(name, sim.t, sim.r, sim.s)
    return import_csv(Path(spec["data"]) / spec["dir"] / run, fmt=spec["format"], sensor=name,
                      columns=spec.get("columns"), scales=spec.get("scales")).recording


def policy_of(changes: list[str]) -> Any:
    """``LOOP_POLICY`` with the fields ``FIELD=VALUE`` of ``changes`` changed."""
    import dataclasses

    from strain_comp.diagnosis.selection import LOOP_POLICY

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


DAY2_RUNS = ("sin_20", "sin_40", "tri_20", "tri_30", "mixed_20_30")
"""``--another-day``: the thread's session-2 runs (nylon_silver/session2_10Hz)."""


def _cli(argv: list[str]) -> int:
    """``strain-comp ARGV`` (``strain_comp.cli.main``), quiet."""
    from strain_comp.cli import main as cli

    return cli([*argv, "-q"])


def _started_rmse(cal: Path, bag: Path, work: Path) -> float:
    """``strain-comp start CAL BAG`` then ``evaluate BAG`` with the started calibration
    (a run ``start`` refuses is evaluated with ``CAL`` as it is): the RMSE."""
    started = work / f"{cal.stem}__{bag.stem}.yaml"
    if _cli(["start", str(cal), str(bag), "--out", str(started)]) != 0:
        started = cal
    report = work / f"{cal.stem}__{bag.stem}.json"
    assert _cli(["evaluate", str(bag), "--calibration", str(started), "--json",
                 str(report)]) == 0
    return float(json.loads(report.read_text())["sensors"]["nylon"]["rmse"])


def _split(job: tuple[str, tuple[str, str], dict[str, Path], Path, Path]) -> dict[str, Any]:
    """One split of ``another_day``: diagnose, then each test run after its start."""
    run, pair, bags, cal, out = job
    tests = [r for r in DAY2_RUNS if r != run and r not in pair]
    name = f"{run}__{pair[0]}__{pair[1]}"
    cal2, report = out / f"{name}.yaml", out / f"{name}.json"
    start = time.perf_counter()
    code = _cli(["diagnose", str(bags[run]), "--calibration", str(cal), "--validate",
                 *(str(bags[p]) for p in pair), "--out", str(cal2), "--json", str(report)])
    assert code == 0, f"diagnose {name} exited {code}"
    seconds = time.perf_counter() - start
    found = json.loads(report.read_text())["sensors"]["nylon"]
    after = {r: _started_rmse(cal2, bags[r], out) for r in tests}
    return {"diagnosed": run, "validate": list(pair), "test": tests, "after": after,
            "added": [e["name"] for e in found["added"]], "message": found["message"],
            "seconds": round(seconds, 1)}


def carried_anywhere(day2: dict[str, Path], cal: Path, tried: int) -> None:
    """``--another-day --evidence``: per diagnosed run, its ``tried`` best candidates (as
    the loop ranks them on it), each fitted there and scored after ``start`` on each of
    the four other runs, as the loop scores its validation runs
    (``diagnosis.loop._setup``, ``selection._passing``, ``SessionHeldOut.per_run``): the
    change of each run's RMSE, and how many candidates lower all four."""
    import numpy as np

    from strain_comp.core.calibration_file import load_calibration
    from strain_comp.diagnosis import loop, selection
    from strain_comp.diagnosis.residuals import base_runs
    from strain_comp.diagnosis.selection import LOOP_POLICY
    from strain_comp.io.recording import load_recordings

    calibration = load_calibration(cal)
    bags = {r: load_recordings(day2[r])[0] for r in DAY2_RUNS}
    print("| fitted on | candidate | on it (folds) | "
          + " | ".join(f"run {k + 1}" for k in range(4)) + " |")
    print("|---|---|---:|" + "---:|" * 4)
    for run in DAY2_RUNS:
        others = [r for r in DAY2_RUNS if r != run]
        fit, val = [bags[run]], [bags[r] for r in others]
        setup = loop._setup("nylon", calibration, fit, val,
                            [base_runs(b, calibration) for b in fit],
                            [base_runs(b, calibration) for b in val], None, False, True)
        assert setup is not None and setup.session is not None
        gram, cands, session = setup.gram, setup.cands, setup.session
        n = len(cands.names)
        skip = [j for j in range(n) if j in cands.baselines or session.redundant(j)]
        passing = selection._passing(gram, [], cands.offset, n, skip, LOOP_POLICY)
        none = session.per_run([], np.zeros(0))
        lowers_all = 0
        for j in sorted(passing, key=passing.__getitem__, reverse=True)[:tried]:
            cols = selection.with_intercept([j], cands.offset)
            coef = gram.solve(cols)
            ratios = selection.run_log_ratios(session.per_run(cols, coef), none)
            lowers_all += all(x < 0 for x in ratios)
            print(f"| {run} | {cands.names[j]} | {-100 * passing[j]:+.0f} % | "
                  + " | ".join(f"{o} {100 * (np.exp(x) - 1):+.0f} %"
                               for o, x in zip(others, ratios, strict=True)) + " |",
                  flush=True)
        print(f"\n{run}: {lowers_all} of {min(tried, len(passing))} candidates lower all "
              "four other runs\n", flush=True)


def another_day(args: argparse.Namespace) -> int:
    """The loop on another day, through the user's commands (``strain_comp.cli.main``):
    ``import-csv`` every thread run of both sessions, ``fit --model MODEL`` on the seven
    session-1 runs (cached in ``--out``), then for every split of the five session-2 runs
    (one diagnosed, two validating, the other two tested: 30) ``diagnose RUN --calibration
    S1 --validate A B``, and each test run through ``start`` and ``evaluate``, with the
    session-1 calibration (before) and with the diagnosed one (after)."""
    import itertools
    from multiprocessing import Pool

    import numpy as np

    out = args.out
    (out / "bags").mkdir(parents=True, exist_ok=True)
    bags: dict[str, Path] = {}
    for tag, folder in (("s1", "session1_100Hz"), ("s2", "session2_10Hz")):
        for csv in sorted((args.data / "nylon_silver" / folder).glob("*.csv")):
            bag = out / "bags" / f"{tag}_{csv.stem}.mcap"
            if not bag.exists():
                assert _cli(["import-csv", str(csv), "--format", "generic", "--columns",
                             "time=time_s,resistance=r_over_r0,strain=position", "--scales",
                             "strain=100", "--sensor", "nylon", "--out", str(bag)]) == 0
            bags[f"{tag}_{csv.stem}"] = bag
    model = args.models[0]
    cal = out / f"session1_{model}.yaml"
    if not cal.exists():
        assert _cli(["fit", *(str(b) for k, b in sorted(bags.items()) if k.startswith("s1_")),
                     "--model", model, "--sensor", "nylon", "--input-unit", "R/R0",
                     "--out", str(cal)]) == 0
    day2 = {r: bags[f"s2_{r}"] for r in DAY2_RUNS}
    if args.evidence:
        carried_anywhere(day2, cal, 16)
        return 0
    before = {r: _started_rmse(cal, day2[r], out) for r in DAY2_RUNS}
    jobs = [(run, pair, day2, cal, out) for run in DAY2_RUNS
            for pair in itertools.combinations([r for r in DAY2_RUNS if r != run], 2)]
    start = time.perf_counter()
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            rows = pool.map(_split, jobs, chunksize=1)
    else:
        rows = [_split(job) for job in jobs]
    total = time.perf_counter() - start
    print("| diagnosed | validate | test runs: before -> after | change | added (or the "
          "refusal) |")
    print("|---|---|---|---:|---|")
    for row in rows:
        tests = row["test"]
        row["before"] = {r: before[r] for r in tests}
        row["change"] = (float(np.median([row["after"][r] for r in tests]))
                         / float(np.median([before[r] for r in tests])) - 1.0)
        what = ", ".join(row["added"]) or row["message"]
        print(f"| {row['diagnosed']} | {', '.join(row['validate'])} | "
              + ", ".join(f"{r} {before[r]:.2f} -> {row['after'][r]:.2f}" for r in tests)
              + f" | {100 * row['change']:+.0f} % | {what} |")
    added = [r for r in rows if r["added"]]
    changes = [r["change"] for r in added]
    worse = [f"{t} {r['before'][t]:.2f} -> {r['after'][t]:.2f} after diagnosing "
             f"{r['diagnosed']}" for r in rows for t in r["test"]
             if r["after"][t] > r["before"][t] * 1.0005]
    seconds = sorted(r["seconds"] for r in rows)
    print(f"\n{len(added)} of {len(rows)} splits add a term, {len(rows) - len(added)} refuse; "
          f"test median change where added: "
          f"{', '.join(f'{100 * c:+.0f} %' for c in changes) or '-'}; splits at "
          f"-25 % or better: {sum(r['change'] <= -0.25 for r in rows)}; test runs worse than "
          f"without the loop: {len(worse)}{': ' + '; '.join(worse) if worse else ''}. "
          f"Before (each run after its start, session-1 calibration): "
          f"{', '.join(f'{r} {v:.2f}' for r, v in before.items())} % strain. Diagnose per "
          f"split: median {seconds[len(seconds) // 2]:.0f} s, at most {seconds[-1]:.0f} s; "
          f"all splits {total / 60:.1f} min with --jobs {args.jobs}")
    (out / "another_day.json").write_text(json.dumps({"before": before, "rows": rows},
                                                     indent=1) + "\n", encoding="utf-8")
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
                             "(strain_comp.diagnosis.selection.LoopPolicy, e.g. level=0.9)")
    parser.add_argument("--another-day", action="store_true",
                        help="the thread fitted on session 1 (the first of --models), the "
                             "loop on every split of session 2 (another_day)")
    parser.add_argument("--evidence", action="store_true",
                        help="with --another-day: each run's 16 best candidates scored on "
                             "the four other runs (carried_anywhere) instead of the splits")
    parser.add_argument("--jobs", type=int, default=1,
                        help="with --another-day: splits diagnosed at once (default 1)")
    args = parser.parse_args(argv)
    if args.another_day:
        return another_day(args)
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
