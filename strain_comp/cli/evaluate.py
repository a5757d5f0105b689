"""``strain-comp evaluate``: a calibration's error table on one bag or many
(docs/design.md)."""

from __future__ import annotations

import argparse
import os
from typing import TYPE_CHECKING

from strain_comp.cli.common import (
    bag,
    note,
    output,
    references_flag,
    results,
    tare_flag,
    tracking_flag,
    write_json,
)
from strain_comp.errors import InputError
from strain_comp.io.atomic import check_distinct, write_text

if TYPE_CHECKING:
    from strain_comp.core.calibration import Calibration

NAME = "evaluate"
SUMMARY = "error table of a calibration on one or many bags"
DESCRIPTION = ("Run a calibration over recordings with a reference strain and print the "
               "errors per sensor (n, RMSE, MAE, max |error| in the calibration's strain "
               "unit, R^2). Several bags or a folder: a table per bag and the errors pooled "
               "over all of them.")
EXAMPLE = ("strain-comp evaluate run3.mcap run4.mcap --calibration s1.yaml "
           "--csv series.csv --json errors.json --jobs 2")
MAX_JOBS = 64


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bags, the calibration, the outputs, the engine's settings."""
    p.add_argument("bags", nargs="+", metavar="BAG.mcap",
                   help="bags (MCAP files, rosbag2 directories) or folders of them")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml",
                   help="calibration file (from fit, diagnose or recalibrate)")
    p.add_argument("--json", metavar="OUT.json",
                   help="also write the errors as JSON ('-': stdout; several bags: keyed by "
                   "bag, docs/design.md)")
    p.add_argument("--csv", metavar="OUT.csv",
                   help="also write every sample: time [s], resistance [ohm], estimate and "
                   "reference [strain unit], direction, status per sensor ('-': stdout)")
    p.add_argument("--plots", metavar="DIR",
                   help="also write PNG plots per sensor (several bags: a folder per bag)")
    p.add_argument("--report", metavar="OUT.html",
                   help="also write one self-contained HTML page: the tables, the plots "
                   "and the calibration's provenance (opens without a network)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="bags evaluated at once, in N processes (default 1)")
    p.add_argument("--out-of-range", choices=("clamp", "extrapolate", "extend"),
                   default="extend",
                   help="strain beyond the calibrated resistance range: extended with a "
                   "bounded slope within a bounded reach (extend, default), clamped to the "
                   "calibrated strain range, or extended with the model's end slope "
                   "(flagged in every mode; docs/design.md)")
    tracking_flag(p)
    p.add_argument("--in-run-bound", action="store_true",
                   help="also fit the same model on each run itself and give its RMSE "
                   "(JSON key in_run_rmse; costs a fit per bag)")
    tare_flag(p)
    references_flag(p)


def run(args: argparse.Namespace) -> int:
    """Every input and output checked before any bag is read, then the bags evaluated."""
    from strain_comp import api
    from strain_comp.core.engine import tracking_off
    from strain_comp.core.fusion import check_every
    from strain_comp.offline.batch import expand_bags, plot_dirs
    from strain_comp.offline.plots import plot_files

    if not 1 <= args.jobs <= MAX_JOBS:  # before any bag is read
        raise InputError(f"--jobs {args.jobs}: must be 1 to {MAX_JOBS}")
    tracking_off(args.baseline_tracking)
    if args.references_every is not None:
        check_every(args.references_every)
    for path in args.bags:
        bag(path)
    bags = expand_bags(args.bags)  # a folder's bags exist: the given paths were checked
    inputs = [*bags, args.calibration]
    calibration = api.load_calibration(args.calibration)  # a bad one: one line before any bag
    many = len(bags) > 1 or any(os.path.isdir(b) and not os.path.isfile(
        os.path.join(b, "metadata.yaml")) for b in args.bags)
    dirs = plot_dirs(bags, args.plots) if many else [args.plots]
    plots = [p for d in dirs if d is not None for p in plot_files(d, list(calibration.sensors))]
    check_distinct((args.json, args.csv, args.plots, args.report, *plots))
    if args.json == "-" and args.csv == "-":
        raise InputError("--json - and --csv -: only one of them can go to stdout")
    for out in (args.json, args.csv, args.report):
        if out is not None and out != "-":
            output(out, inputs)
    return _evaluate(args, bags, dirs, many, inputs, calibration)


def _evaluate(args: argparse.Namespace, bags: list[str], dirs: list[str | None], many: bool,
              inputs: list[str], calibration: Calibration) -> int:
    """The bags evaluated; then the tables, notes, JSON and report."""
    from strain_comp.core.calibration import expected_words
    from strain_comp.offline.batch import aggregate, evaluate_bags, format_aggregate, to_json
    from strain_comp.offline.evaluate import PLOT_POINTS
    from strain_comp.offline.evaluation import format_notes, format_table
    from strain_comp.offline.report_page import evaluation_page
    from strain_comp.offline.series import series_csv
    from strain_comp.progress import bar, wanted

    with series_csv(args.csv, inputs=inputs, bag=many) as table, \
            bar(len(bags), "evaluate", enabled=many and wanted(args.quiet)) as shown:
        outcomes = evaluate_bags(bags, args.calibration, tare=args.tare, jobs=args.jobs,
                                 plot_points=PLOT_POINTS if args.plots or args.report else 0,
                                 in_run=args.in_run_bound, dirs=dirs, series=table,
                                 progress=lambda done, total, bag: shown.update(1),
                                 out_of_range=args.out_of_range,
                                 references_every=args.references_every,
                                 figures=bool(args.report), keep_going=many)
        one = None if many else outcomes[0].result  # one bag: it raised, or it has a result
        if args.json:  # the table is committed only once the JSON is written too
            write_json(args.json, to_json(outcomes) if one is None else one.to_json(), inputs)
    stream = results(args)
    for outcome, folder in zip(outcomes, dirs, strict=True):
        if many:
            print(f"== {outcome.bag}", file=stream)
        if outcome.result is None:
            print(f"not evaluated: {outcome.error}", file=stream)
            continue
        print(format_table(outcome.result), file=stream)
        for line in outcome.problems + format_notes(outcome.result):
            note(args, f"{outcome.bag}: {line}" if many else line)
        if outcome.plots:
            note(args, f"wrote {len(outcome.plots)} plots to {folder}")
    if many:
        print(format_aggregate(outcomes), file=stream)
    for name in calibration.sensors if one is None else one.sensors:  # fit --model auto's
        words = expected_words(calibration.sensors[name])
        if words:
            print(f"{name}: {words}", file=stream)
    if args.report:
        page = evaluation_page(outcomes, calibration, args.calibration, tare=args.tare,
                               pooled=aggregate(outcomes) if many else None)
        write_text(args.report, page, inputs=inputs)
        note(args, f"wrote {args.report}")
    if args.csv not in (None, "-"):
        note(args, f"wrote {args.csv}")
    failed = [o for o in outcomes if o.error is not None]
    if failed:
        raise InputError(f"{len(failed)} of {len(outcomes)} bags could not be evaluated "
                         f"(first: {failed[0].error})")
    return 0
