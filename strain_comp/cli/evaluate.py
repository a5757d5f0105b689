"""``strain-comp evaluate``: a calibration's error table on one bag or many
(docs/design.md)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterable
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
from strain_comp.io.inputs import existing

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
    """Every input and output checked before any bag is read; one bag streamed through
    ``api.evaluate``, several through ``offline.batch``."""
    from strain_comp import api
    from strain_comp.core.engine import tracking_off
    from strain_comp.core.fusion import check_every
    from strain_comp.offline.batch import check_jobs, expand_bags, plot_dirs
    from strain_comp.offline.plots import plot_files

    check_jobs(args.jobs)  # before any bag is read
    tracking_off(args.baseline_tracking)
    if args.references_every is not None:
        check_every(args.references_every)
    for path in args.bags:
        bag(path)
    existing(args.calibration, "calibration file")
    bags = expand_bags(args.bags)
    for path in bags:
        bag(path)
    inputs = [*bags, args.calibration]
    calibration = api.load_calibration(args.calibration)  # a bad one: one line before any bag
    many = len(bags) > 1 or any(os.path.isdir(b) and not os.path.isfile(
        os.path.join(b, "metadata.yaml")) for b in args.bags)
    plots = [p for d in (plot_dirs(bags, args.plots) if many else [args.plots])
             if d is not None for p in plot_files(d, list(calibration.sensors))]
    check_distinct((args.json, args.csv, args.plots, args.report, *plots))
    if args.json == "-" and args.csv == "-":
        raise InputError("--json - and --csv -: only one of them can go to stdout")
    for out in (args.json, args.csv, args.report):
        if out is not None and out != "-":
            output(out, inputs)
    if many:
        return _evaluate_many(args, bags, inputs, calibration)
    return _evaluate_one(args, bags[0], inputs, calibration)


def print_expected(args: argparse.Namespace, calibration: Calibration,
                   sensors: Iterable[str]) -> None:
    """Beside the table: per sensor the error its calibration expects on a new session
    (``core.calibration.expected_words``), where it holds one (``fit --model auto``)."""
    from strain_comp.core.calibration import expected_words

    for name in sensors:
        cal = calibration.sensors.get(name)
        words = None if cal is None else expected_words(cal)
        if words:
            print(f"{name}: {words}", file=results(args))


def _evaluate_one(args: argparse.Namespace, path: str, inputs: list[str],
                  calibration: Calibration) -> int:
    """``evaluate`` over one bag (``api.evaluate``, streamed)."""
    from strain_comp import api
    from strain_comp.offline.evaluate import PLOT_POINTS
    from strain_comp.offline.evaluation import format_notes

    # streamed; an error when nothing can be scored names what the bag reader skipped
    evaluation = api.evaluate(calibration, path, tare=args.tare,
                              out_of_range=args.out_of_range,
                              tracking=args.baseline_tracking, in_run_bound=args.in_run_bound,
                              plot_points=PLOT_POINTS if args.plots or args.report else 0,
                              references_every=args.references_every,
                              csv=args.csv, inputs=[args.calibration])
    result = evaluation.result
    print(evaluation.table(), file=results(args))
    print_expected(args, calibration, result.sensors)
    for line in evaluation.problems + format_notes(result):
        note(args, line)
    # drawn before anything is written: a drawing that fails leaves no JSON behind
    page = evaluation.to_html(args.calibration) if args.report else None
    if args.plots:
        from strain_comp.offline.plots import plot_evaluation

        written = plot_evaluation(result, args.plots, inputs=inputs, calibration=calibration,
                                  bag=path, calibration_path=args.calibration, tare=args.tare)
        note(args, f"wrote {len(written)} plots to {args.plots}")
    if args.json:
        write_json(args.json, evaluation.to_json(), inputs)
    if page is not None:
        write_text(args.report, page, inputs=inputs)
        note(args, f"wrote {args.report}")
    if args.csv not in (None, "-"):
        note(args, f"wrote {args.csv}")
    return 0


def _evaluate_many(args: argparse.Namespace, bags: list[str], inputs: list[str],
                   calibration: Calibration) -> int:
    """``evaluate`` over several bags (``strain_comp.offline.batch``)."""
    from strain_comp.offline.batch import evaluate_bags, format_aggregate, format_bag, to_json
    from strain_comp.offline.evaluate import PLOT_POINTS
    from strain_comp.offline.series import series_csv
    from strain_comp.progress import bar, wanted

    with series_csv(args.csv, inputs=inputs, bag=True) as table, \
            bar(len(bags), "evaluate", enabled=wanted(args.quiet)) as shown:
        outcomes = evaluate_bags(bags, args.calibration, tare=args.tare, jobs=args.jobs,
                                 plot_points=PLOT_POINTS if args.plots or args.report else 0,
                                 in_run=args.in_run_bound, plots=args.plots, series=table,
                                 progress=lambda done, total, bag: shown.update(1),
                                 out_of_range=args.out_of_range,
                                 references_every=args.references_every,
                                 figures=bool(args.report))
        if args.json:  # the table is committed only once the JSON is written too
            write_json(args.json, to_json(outcomes), inputs)
    stream = results(args)
    for outcome in outcomes:
        text, notes = format_bag(outcome)
        print(text, file=stream)
        for line in notes:
            note(args, f"{outcome.bag}: {line}")
        if outcome.plots:
            note(args, f"wrote {len(outcome.plots)} plots to "
                 f"{os.path.dirname(outcome.plots[0])}")
    print(format_aggregate(outcomes), file=stream)
    print_expected(args, calibration, calibration.sensors)
    if args.report:
        from strain_comp.offline.batch import aggregate
        from strain_comp.offline.report_page import BagSection, evaluation_page

        page = evaluation_page([BagSection(o.bag, o.result, o.error, o.problems, o.figures)
                                for o in outcomes], calibration, args.calibration,
                               tare=args.tare, pooled=aggregate(outcomes))
        write_text(args.report, page, inputs=inputs)
        note(args, f"wrote {args.report}")
    if args.csv not in (None, "-"):
        note(args, f"wrote {args.csv}")
    failed = [o for o in outcomes if o.error is not None]
    if failed:
        raise InputError(f"{len(failed)} of {len(outcomes)} bags could not be evaluated "
                         f"(first: {failed[0].error})")
    return 0
