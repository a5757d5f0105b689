#!/usr/bin/env python3
# Study: What does a known strain every N seconds buy across runs? (docs/results.md)
"""What a known strain every N seconds buys across runs: ``evaluate --references-every``.

    python studies/references.py --every 60,30 --out out/references

For the silver-nylon thread session (``nylon_silver/session1_100Hz``, seven runs, imported
as docs/csv.md's generic format) and for the other measured sensors (carbon black, fibre)
and the virtual rig: every model in ``--models`` fitted on one run (``strain-comp fit
RUN``; ``--protocol loro``: on all other runs, ``strain-comp fit A B C ...``), used on
every other run B of the same sensor after the session start on B's first cycle
(``recalibrate --input --from B --first S``, then ``recalibrate --from B --first S``, S the
first load and unload: ``strain_comp.offline.session_start.first_cycle``; ``--session-cycle
2``: on B's second cycle, the first one an unreferenced warm-up), then scored
on all of B (``strain-comp evaluate``) without references and with B's own reference every
N seconds fused (``--references-every N``). Prints a
Markdown table of the median and worst RMSE per sensor, model and workflow (errors in the
sensor's unit) and writes ``OUT/references.json``; ``--variants`` adds a table of other
fusion settings (the offset alone, a tighter gain prior, slower random walks) and of the
per-run least-squares gain and offset.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
NYLON = "nylon_silver/session1_100Hz/"
NYLON_RUNS = ("sin_20", "sin_30", "sin_40", "tri_50", "mixed_10_20", "mixed_15_25",
              "mixed_20_30")
NYLON_IMPORT = ("--format", "generic", "--columns", "time=time_s,resistance=r_over_r0,"
                "strain=position", "--scales", "strain=100")
CB = "cb_pdms_7p5wt/2_7-5_"
FIBER = "conductive_fiber/oldthread_sensorfiber_5x_"
SENSORS: dict[str, list[tuple[str, str, tuple[str, ...]]]] = {
    "nylon": [(k, f"{NYLON}{k}.csv", NYLON_IMPORT) for k in NYLON_RUNS],
    "cb": [(k, CB + f, ("--format", "cb_pdms")) for k, f in (
        ("v16", "E4pin_20mm_v16_0.3Strain.csv"), ("v19", "E4pin_20mm_v19_0.3Strain.csv"),
        ("v10", "E4pin_20mm_v10_0.3Strain.csv"))],
    "fiber": [(f"run{i}", f"{FIBER}{i}_synced.csv", ("--format", "fiber")) for i in (1, 3, 4)],
    "rig": [(k, f"rig:{k}", ()) for k in ("triangle", "rates", "patterns")],
}


def bag(data: Path, out: Path, sensor: str, label: str, source: str,
        args: tuple[str, ...]) -> Path:
    """The run's bag, made once (``strain-comp import-csv``, or the rig's writer)."""
    from strain_comp.cli import main as cli
    from strain_comp.offline import rig

    path = out / "bags" / sensor / f"{label}.mcap"
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    if source.startswith("rig:"):
        rig.write_sim_bag(rig.simulate(source[4:], seed=1), path)
        return path
    with contextlib.redirect_stdout(sys.stderr):
        if cli(["import-csv", str(data / source), "--out", str(path), "--sensor", sensor,
                *args, "-q"]) != 0:
            raise SystemExit(f"import of {source} failed")
    return path


def cycle_seconds(rec: Any) -> float:
    """Seconds of the recording's first load and unload (``first_cycle``, capped)."""
    from strain_comp.offline.session_start import FIRST_CYCLE_CAP, first_cycle

    return first_cycle(rec.t, rec.s) or FIRST_CYCLE_CAP * float(rec.t[-1] - rec.t[0])


def session_start(cal: Any, rec: Any, cycle: int = 1) -> Any:
    """``recalibrate --input --from B --first S`` then ``recalibrate --from B --first S``
    on B's first cycle (``cycle`` 1), or on its second one after an unreferenced warm-up
    cycle (``cycle`` 2: the recording from the end of the first cycle on, as a window);
    a step that cannot be made is skipped, as for a user."""
    from dataclasses import replace

    from strain_comp.errors import StrainCompError
    from strain_comp.offline.session_start import recalibrate_recordings, session_forms

    if cycle == 2:
        k = int(np.searchsorted(rec.t, rec.t[0] + cycle_seconds(rec), side="left"))
        rec = replace(rec, t=rec.t[k:], r=rec.r[k:], s=rec.s[k:],
                      temperature=None if rec.temperature is None else rec.temperature[k:])
    seconds = cycle_seconds(rec)
    for form in session_forms(cal.sensors[rec.name]):
        with contextlib.suppress(StrainCompError):
            cal = recalibrate_recordings(cal, {rec.name: rec}, form=form, first=seconds)[0]
    return cal


def variants(ev: Any, span: float, every: float) -> dict[str, float]:
    """RMSE of the fused output under other fusion settings (``--variants``), from the
    engine's estimate ``ev`` (no references), and of the per-run least-squares gain and
    offset over the whole run (an oracle: it knows every reference of the run)."""
    from strain_comp.core import fusion
    from strain_comp.core.fusion import OutputFusion, SparseFusion

    # the fusion's module constants (read when a filter is built or updated), set per variant
    settings: dict[str, dict[str, float]] = {
        "default": {},
        "offset alone": {"GAIN_SD": 1e-9, "GAIN_WALK": 0.0},
        "gain prior 0.1": {"GAIN_SD": 0.1, "GAIN_WALK": fusion.GAIN_WALK / 3.0},
        "walks 4x slower": {"GAIN_WALK": fusion.GAIN_WALK / 4.0,
                            "OFFSET_WALK_SHARE": fusion.OFFSET_WALK_SHARE / 4.0},
    }
    eligible = ev.scored & ~ev.out_of_range
    out = {}
    for name, numbers in settings.items():
        defaults = {key: getattr(fusion, key) for key in numbers}
        vars(fusion).update(numbers)
        try:
            fused = SparseFusion(OutputFusion(span), every).run(ev.t, ev.estimate,
                                                                ev.reference, eligible)
        finally:
            vars(fusion).update(defaults)
        out[name] = float(np.sqrt(np.mean((fused - ev.reference)[ev.scored] ** 2)))
    a = np.column_stack([ev.estimate[eligible], np.ones(int(eligible.sum()))])
    g, b = np.linalg.lstsq(a, ev.reference[eligible], rcond=None)[0]
    out["oracle"] = float(np.sqrt(np.mean((g * ev.estimate + b - ev.reference)[ev.scored]
                                          ** 2)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=Path("out/references"))
    parser.add_argument("--every", default="60,30", help="spacings [s], comma separated")
    parser.add_argument("--models", default="cubic,mpi")
    parser.add_argument("--sensors", default="nylon,cb,fiber,rig")
    parser.add_argument("--protocol", choices=("pairs", "loro"), default="pairs",
                        help="pairs: fit on one run, used on each other; loro: fit on all "
                        "other runs of the session (strain-comp fit A B C ...)")
    parser.add_argument("--session-cycle", type=int, choices=(1, 2), default=1,
                        help="the session start on the test run's first cycle, or on its "
                        "second after a warm-up cycle")
    parser.add_argument("--variants", action="store_true",
                        help="also other fusion settings at the first spacing, and the "
                        "per-run least-squares gain and offset (a table of medians)")
    args = parser.parse_args(argv)
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import evaluate_recordings
    from strain_comp.offline.fit import fit_bags

    start = time.perf_counter()
    spacings = [float(x) for x in args.every.split(",") if x]
    rows: list[dict[str, Any]] = []
    for sensor in args.sensors.split(","):
        runs = SENSORS[sensor]
        if sensor != "rig" and not all((args.data / s).is_file() for _, s, _ in runs):
            print(f"## {sensor}: data not found under {args.data}; skipped", file=sys.stderr)
            continue
        name = "s1" if sensor == "rig" else sensor
        bags = {label: bag(args.data, args.out, sensor, label, source, imp)
                for label, source, imp in runs}
        recs = {label: load_recordings(path)[0][name] for label, path in bags.items()}
        for model in args.models.split(","):
            cals = {}
            for label, path in bags.items():
                training = ([path] if args.protocol == "pairs" else
                            [p for k, p in bags.items() if k != label])
                with contextlib.redirect_stdout(sys.stderr):
                    cals[label] = fit_bags(training, model, [name])
            for train in bags:
                for test in bags:
                    if (train == test) != (args.protocol == "loro"):
                        continue
                    rec = recs[test]
                    cal = session_start(cals[train], rec, args.session_cycle)
                    row: dict[str, Any] = {"sensor": sensor, "model": model, "test": test,
                                           "train": train if args.protocol == "pairs" else
                                           "all others"}
                    for every in [None, *spacings]:
                        ev = evaluate_recordings({name: rec}, cal,
                                                 references_every=every).sensors[name]
                        key = "none" if every is None else f"{every:g}s"
                        row[key] = float(ev.stats.rmse)
                        if every is not None and ev.references is not None:
                            row[key + "_used"] = ev.references["n_used"]
                            row[key + "_refused"] = ev.references["n_refused"]
                    if args.variants:
                        from strain_comp.core.range_policy import fitted_rest

                        ev = evaluate_recordings({name: rec}, cal).sensors[name]
                        span = fitted_rest(cal.sensors[name].valid_range)[1]
                        row["variants"] = variants(ev, span, spacings[0])
                    rows.append(row)
                    print(f"## {sensor} {model} {train} -> {test}: " + ", ".join(
                        f"{k} {v:.2f}" for k, v in row.items()
                        if isinstance(v, float)), file=sys.stderr)
    keys = ["none" if e is None else f"{e:g}s" for e in [None, *spacings]]
    print("| sensor | model | pairs | " + " | ".join(
        f"{k} median / worst" for k in keys) + " |")
    print("|---|---|---|" + "---|" * len(keys))
    for sensor in dict.fromkeys(r["sensor"] for r in rows):
        for model in dict.fromkeys(r["model"] for r in rows if r["sensor"] == sensor):
            sel = [r for r in rows if r["sensor"] == sensor and r["model"] == model]
            cells = []
            for k in keys:
                v = np.array([r[k] for r in sel])
                cells.append(f"{np.median(v):.2f} / {np.max(v):.2f}")
            print(f"| {sensor} | {model} | {len(sel)} | " + " | ".join(cells) + " |")
    if args.variants:
        names = list(rows[0]["variants"]) if rows else []
        print(f"\n| sensor | model | {' | '.join(names)} (median RMSE, every "
              f"{spacings[0]:g} s) |")
        print("|---|---|" + "---|" * len(names))
        for sensor in dict.fromkeys(r["sensor"] for r in rows):
            for model in dict.fromkeys(r["model"] for r in rows if r["sensor"] == sensor):
                sel = [r for r in rows if r["sensor"] == sensor and r["model"] == model]
                print(f"| {sensor} | {model} | " + " | ".join(
                    f"{np.median([r['variants'][n] for r in sel]):.2f}" for n in names)
                    + " |")
    refused = sum(r.get(k + "_refused", 0) for r in rows for k in keys)
    used = sum(r.get(k + "_used", 0) for r in rows for k in keys)
    print(f"references used {used}, refused {refused}; "
          f"{time.perf_counter() - start:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "references.json").write_text(json.dumps(
        {"rows": rows}, indent=1, default=lambda x: None if isinstance(x, float)
        and not math.isfinite(x) else x), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
