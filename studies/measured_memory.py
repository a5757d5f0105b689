#!/usr/bin/env python3
# Study: Where do memory models lose to the cubic within a run? (docs/results.md)
"""Where the memory models lose to the cubic within one measured run, by phase and by block.

    python studies/measured_memory.py --data ../shared/data/measured --out out/memory

For each run (the CSVs of ``studies/measured.py``): every model is fitted on the first 60 %
of the run's time, run through the whole run (its state carried on, as online) and scored
on the rest: overall, and split by the phase of the reference (loading, unloading, hold:
the strain moves by at most ``STILL_FRACTION`` of its span in 1 s). Then blocked
cross-validation: the run cut into ``--folds`` equal blocks of time, each block scored
after fitting on the others. A model that loses only on the one block of the 60/40 split
that holds something the training part never showed (an artefact of the measurement
chain, a level outside the trained range) and wins on the others loses by extrapolation,
not by its structure. ``--option k=v`` is passed to every fit (``strain-comp fit
--option``), e.g. ``pair=upper``. ``--effect NAME`` (a candidate of the residual loop,
e.g. ``resistance_peak_tau128``; repeatable) adds that term with an intercept, fitted by
least squares on the training part's residual without the loop's selection: what the term
would do, whether or not the loop would choose it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measured import DEFAULT_DATA, WITHIN_FIT, import_all, short

MODELS = ("cubic", "mpi", "pl", "apl", "spike_decay")
RUNS = ("v9", "v10", "fiber_run1", "fiber_run3", "fiber_run4")
"""The runs with holds or relaxation (the within-run target of the measured-data section)."""


def _part(rec, mask):  # type: ignore[no-untyped-def]
    return dataclasses.replace(rec, **{k: None if getattr(rec, k) is None
                                       else getattr(rec, k)[mask]
                                       for k in ("t", "r", "s", "temperature")})


def with_effects(cal, train: list, effects: list[str]):  # type: ignore[no-untyped-def]
    """``cal`` plus the named loop candidates and an intercept, least squares on ``train``'s
    samples with a reference; the terms run over every sample the engine used, as online."""
    from strain_comp.base.samples import used_mask
    from strain_comp.core.calibration import Calibration
    from strain_comp.core.effects import Batch, regressor_from_dict
    from strain_comp.core.engine import Engine
    from strain_comp.diagnosis.candidates import default_candidates

    known = {c["name"]: c for c in default_candidates()}
    columns, targets = [], []
    for part in train:
        out = Engine(Calibration({cal.name: cal})).run(cal.name, part.t, part.r)
        used = used_mask(out.status)
        ok = np.isfinite(part.s[used])
        batch = Batch.of(part.t[used], out.resistance[used], out.strain[used],
                         out.direction[used])
        columns.append(np.column_stack([np.ones(batch.t.size)] + [
            regressor_from_dict(known[name]).run(batch) for name in effects])[ok])
        targets.append((out.strain[used] - part.s[used])[ok])
    coef = np.linalg.lstsq(np.vstack(columns), np.concatenate(targets), rcond=None)[0]
    terms = [{"name": "offset", "kind": "offset", "params": {}, "coef": float(coef[0])}]
    terms += [dict(known[name], coef=float(c)) for name, c in zip(effects, coef[1:],
                                                                  strict=True)]
    return dataclasses.replace(cal, effects=terms)


def scored_errors(rec, train: list, model: str, options: dict,  # type: ignore[no-untyped-def]
                  effects: list[str] | None = None):
    """(error per sample, scored mask) of ``model`` fitted on ``train`` and run over ``rec``."""
    from strain_comp.core.calibration import Calibration
    from strain_comp.offline.evaluate import evaluate_recordings
    from strain_comp.offline.fit import fit_sensor

    cal = fit_sensor(train, model, name=rec.name, options=options or None)
    if effects:
        cal = with_effects(cal, train, effects)
    ev = evaluate_recordings({rec.name: rec}, Calibration({rec.name: cal})).sensors[rec.name]
    return ev.estimate - ev.reference, ev.scored


def phases(rec) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    """Loading / unloading / hold masks of a run from its reference strain."""
    from strain_comp.offline.input_chain import STILL_FRACTION, strain_change

    s = np.asarray(rec.s, dtype=np.float64)
    moved = strain_change(rec.t, s)
    still = STILL_FRACTION * float(np.nanmax(s) - np.nanmin(s))
    return {"loading": moved > still, "unloading": moved < -still,
            "hold": np.abs(moved) <= still}


def rmse(e: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e[mask] ** 2))) if mask.any() else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=Path("out") / "memory")
    parser.add_argument("--models", nargs="+", default=list(MODELS))
    parser.add_argument("--runs", nargs="+", default=list(RUNS))
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--option", action="append", default=[], metavar="K=V")
    parser.add_argument("--effect", action="append", default=[], metavar="NAME")
    args = parser.parse_args(argv)

    from strain_comp.diagnosis.candidates import default_candidates
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.fit import parse_options

    unknown = set(args.effect) - {c["name"] for c in default_candidates()}
    if unknown:
        parser.error(f"--effect {', '.join(sorted(unknown))}: not a candidate of the loop "
                     "(e.g. resistance_peak_tau128)")

    options = parse_options(args.option)
    args.out.mkdir(parents=True, exist_ok=True)
    bags = import_all(args.data, args.out, None)
    runs = {short(name): load_recordings(path)[0] for name, path in bags.items()
            if short(name) in args.runs}
    split = ["", f"split: fit on the first {100 * WITHIN_FIT:.0f} %, RMSE on the rest, by "
             "phase of the reference (samples)", "",
             "| run | model | rest | loading | unloading | hold |", "|---|---|---:|---:|---:|---:|"]
    folds = ["", f"blocked cross-validation: {args.folds} blocks of time, each scored after "
             "fitting on the others (RMSE per block; all: over every block)", "",
             "| run | model | all | " + " | ".join(f"block {k + 1}" for k in range(args.folds))
             + " |", "|---|---|" + "---:|" * (args.folds + 1)]
    for run, by_sensor in runs.items():
        (_, rec), = by_sensor.items()
        frac = (rec.t - rec.t[0]) / (rec.t[-1] - rec.t[0])
        tail = frac > WITHIN_FIT
        phase = phases(rec)
        for model in args.models:
            e, scored = scored_errors(rec, [_part(rec, ~tail)], model, options, args.effect)
            cells = [rmse(e, scored & tail)] + [rmse(e, scored & tail & m)
                                                for m in phase.values()]
            counts = [int(np.sum(scored & tail & m)) for m in phase.values()]
            split.append(f"| {run} | {model} | {cells[0]:.3f} | " + " | ".join(
                f"{c:.3f} ({n})" for c, n in zip(cells[1:], counts, strict=True)) + " |")
            per_block, all_e = [], []
            for k in range(args.folds):
                block = (frac >= k / args.folds) & ((frac < (k + 1) / args.folds)
                                                    | (k == args.folds - 1))
                train = [_part(rec, ~block & (frac < k / args.folds)),
                         _part(rec, ~block & (frac >= (k + 1) / args.folds))]
                e, scored = scored_errors(rec, [p for p in train if p.t.size > 100],
                                          model, options, args.effect)
                per_block.append(rmse(e, scored & block))
                all_e.append(e[scored & block])
            every = np.concatenate(all_e)
            folds.append(f"| {run} | {model} | {np.sqrt(np.mean(every ** 2)):.3f} | "
                         + " | ".join(f"{v:.3f}" for v in per_block) + " |")
            print(f"## {run} {model} done", file=sys.stderr, flush=True)
    text = "\n".join(split + folds) + "\n"
    print(text)
    (args.out / "memory.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
