"""``strain-comp fit``: a calibration file fitted to bags with a strain reference
(docs/design.md)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from strain_comp.cli.common import Parser, note, output
from strain_comp.io.atomic import check_distinct, write_text

if TYPE_CHECKING:
    from strain_comp.core.calibration import SensorCalibration
from strain_comp.errors import InputError, StrainCompError

NAME = "fit"
SUMMARY = "fit a model to bags with a strain reference"
DESCRIPTION = ("Fit a compensation model (resistance in, strain out) to recordings with a "
               "reference strain and write a calibration file. The file passes the checks "
               "every reader applies before it is written; a fit that would not load is "
               "refused. --model auto chooses the model by leaving runs out: each candidate "
               "fitted on all runs but one, started on the run left out (strain-comp start) "
               "and scored over it; the lowest median wins (a simpler model within 2 % of "
               "it before it), the table of every candidate is printed and stored with the "
               "error to expect on a new session.")
EXAMPLE = ("strain-comp fit run1.mcap run2.mcap run3.mcap --model auto --sensor s1 "
           "--out s1.yaml")
MODELS = "cubic, mpi, apl, creep_pi, pl, sinh_pl, rational, spike_decay"
"""Every model, in the order ``fit --help`` names them (``strain_comp.models``)."""


def _options_help() -> str:
    """Every model's fit options (imports the models: built only for ``--help``)."""
    from strain_comp.offline.options import describe_options

    return describe_options()


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bags, the model, the sensors, the file to write, the fit options."""
    if isinstance(p, Parser):
        p.notes = _options_help
    p.add_argument("bags", nargs="+", metavar="BAG.mcap",
                   help="recordings with /NAME/resistance and /NAME/strain_reference")
    p.add_argument("--model", required=True, metavar="MODEL",
                   help=f"auto (chosen by leaving runs out, below), or one of {MODELS}")
    p.add_argument("--candidates", metavar="M1,M2,...",
                   help="with --model auto: the models tried (default cubic,mpi,apl,"
                        "creep_pi)")
    p.add_argument("--groups", metavar="G1,G2,...",
                   help="with --model auto: one label per bag, e.g. 1,1,1,2,2; runs of a "
                        "label (a session, a mounting) are left out together (default: each "
                        "run alone)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="with --model auto: worker processes for the runs left out "
                        "(default 1)")
    p.add_argument("--report", metavar="OUT.html",
                   help="with --model auto: one page comparing the candidates on every run "
                        "left out")
    p.add_argument("--sensor", required=True, action="append", metavar="NAME",
                   help="sensor to fit (repeatable), or 'all'")
    p.add_argument("--out", required=True, metavar="CAL.yaml",
                   help="calibration file to write (replaced atomically)")
    p.add_argument("--option", action="append", metavar="K=V",
                   help="fit option (repeatable), e.g. N=11; the list below")
    p.add_argument("--strain-unit", default="%", metavar="UNIT",
                   help="unit of the bags' strain_reference (default %%; mm for an extension "
                   "imported without a gauge length): errors, plots and readings are given "
                   "in it")
    p.add_argument("--input-unit", default="ohm", metavar="UNIT",
                   help="unit of the bags' resistance (default ohm; e.g. R/R0 for a "
                   "resistance divided by its first sample): stored in the calibration, "
                   "the dead zone is given in it per second")
    p.add_argument("--pool", choices=("spanned", "joint", "stretch", "raw"), default="spanned",
                   help="several bags of a sensor: put each run's input zero and span onto "
                        "the run of median sensitivity before pooling (as recalibrate "
                        "--input does); spanned (default) keeps the session start that "
                        "reads the runs left out best: joint (the calibration's steady "
                        "outputs, then an output gain and offset) or stretch (a new run's "
                        "stretch line put onto the line the training runs' stretches "
                        "share); raw pools the resistance as recorded")


def run(args: argparse.Namespace) -> int:
    """The model fitted (``api.fit``), the calibration written, one line per sensor."""
    output(args.out, args.bags)  # the bags are checked where api.fit reads them
    auto = args.model == "auto"
    for flag, value in (("--candidates", args.candidates), ("--groups", args.groups),
                        ("--report", args.report)):
        if value is not None and not auto:
            raise InputError(f"fit {flag} needs --model auto")
    if args.jobs < 1:
        raise InputError(f"--jobs {args.jobs}: expected 1 or more")
    if args.report:
        check_distinct((args.out, args.report))
        output(args.report, args.bags)
    from strain_comp import api
    from strain_comp.core.calibration import strain_unit_words
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.offline.fit import memoryless_note, parse_options
    from strain_comp.progress import wanted

    options = parse_options(args.option or [])  # checked by api.fit before any bag is read
    notes: list[str] = []  # damage the reader skipped: noted once, in the error if any
    try:
        calibration = api.fit(args.bags, args.model, sensors=args.sensor,
                              strain_unit=args.strain_unit, input_unit=args.input_unit,
                              report=notes.append,
                              progress_bar=wanted(args.quiet), pool=args.pool,
                              candidates=args.candidates, groups=args.groups, jobs=args.jobs,
                              **options)
    except StrainCompError as err:
        raise InputError("; ".join([str(err), *notes])) from None
    for line in notes:
        note(args, line)
    for name, cal in calibration.sensors.items():
        memoryless = memoryless_note(name, cal)
        if memoryless:
            note(args, memoryless)
    save_calibration(calibration, args.out, inputs=args.bags)
    for name, cal in calibration.sensors.items():
        for line in choice_lines(name, cal):
            print(line)
        prov = cal.provenance
        print(f"{name}: {cal.model} fitted on {prov['n_samples']} samples in "
              f"{prov['fit_seconds']:.2f} s, training RMSE {prov['fit_rmse']:.4f} "
              f"{strain_unit_words(cal.strain_unit)} "
              f"(dead zone {cal.direction.deadzone:.4g} {cal.input.rate_unit} from "
              f"{prov['direction_from']})")
    note(args, f"wrote {args.out}")
    if args.report:
        from strain_comp.offline.report_page import model_choice_page

        write_text(args.report, model_choice_page(calibration, args.out), inputs=args.bags)
        note(args, f"wrote {args.report}")
    return 0


def choice_lines(name: str, cal: SensorCalibration) -> list[str]:
    """``--model auto``'s table, the model chosen and why, and the error to expect (or none)."""
    from strain_comp.core.calibration import expected_words, strain_unit_words

    choice = cal.provenance.get("model_choice")
    if not choice:
        return []
    unit = strain_unit_words(cal.strain_unit)
    lines = []
    table = choice.get("candidates") or {}
    if table:
        lines.append(f"{name}: RMSE after start on each run left out [{unit}]:")
        lines.append(f"  {'model':<10}{'median':>10}{'worst':>10}")
        for model, cell in table.items():
            lines.append(f"  {model:<10}{cell['median']:>10.4g}{cell['worst']:>10.4g}"
                         if "median" in cell else f"  {model:<10}failed: {cell['failed']}")
    lines.append(f"{name}: model {choice['chosen']}: {choice['why']}")
    expected = expected_words(cal)
    if expected:
        lines.append(f"{name}: {expected}")
    return lines
