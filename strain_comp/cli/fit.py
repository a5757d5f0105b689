"""``strain-comp fit``: a calibration file fitted to bags with a strain reference
(docs/design.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import Parser, bag, note, output
from strain_comp.errors import InputError, StrainCompError

NAME = "fit"
SUMMARY = "fit a model to bags with a strain reference"
DESCRIPTION = ("Fit a compensation model (resistance in, strain out) to recordings with a "
               "reference strain and write a calibration file. The file passes the checks "
               "every reader applies before it is written; a fit that would not load is "
               "refused.")
EXAMPLE = ("strain-comp fit run1.mcap run2.mcap --model apl --sensor s1 --out s1.yaml "
           "--option N=11")


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
                   help="apl, pl, mpi, cubic, sinh_pl, rational, spike_decay")
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
    for path in args.bags:
        bag(path)
    output(args.out, args.bags)
    from strain_comp import api
    from strain_comp.core.calibration import strain_unit_words, unit_ok
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.offline.fit import memoryless_note, parse_options
    from strain_comp.offline.options import check_fit_options
    from strain_comp.progress import wanted

    options = parse_options(args.option or [])
    check_fit_options(args.model, options)
    for flag, unit in (("--strain-unit", args.strain_unit), ("--input-unit", args.input_unit)):
        if not unit_ok(unit):
            raise InputError(f"{flag} {unit!r}: expected a unit such as % or mm for strain, "
                             "ohm or R/R0 for the input (1-16 letters, digits, %, / or .)")
    notes: list[str] = []  # damage the reader skipped: noted once, in the error if any
    try:
        calibration = api.fit(args.bags, args.model, sensors=args.sensor,
                              strain_unit=args.strain_unit, input_unit=args.input_unit,
                              report=notes.append,
                              progress_bar=wanted(args.quiet), pool=args.pool, **options)
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
        prov = cal.provenance
        print(f"{name}: {cal.model} fitted on {prov['n_samples']} samples in "
              f"{prov['fit_seconds']:.2f} s, training RMSE {prov['fit_rmse']:.4f} "
              f"{strain_unit_words(cal.strain_unit)} "
              f"(dead zone {cal.direction.deadzone:.4g} {cal.input.rate_unit} from "
              f"{prov['direction_from']})")
    note(args, f"wrote {args.out}")
    return 0
