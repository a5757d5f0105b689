"""``strain-comp diagnose``: the residual loop, the effects a calibration lacks added
(docs/design.md, docs/results.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import bag, note, output, results, tare_flag, write_json
from strain_comp.io.atomic import check_distinct, write_text

NAME = "diagnose"
SUMMARY = "find the effect a calibration lacks and add it"
DESCRIPTION = ("The residual loop: score candidate effects (rate, relaxation, drift, "
               "temperature, Mullins, cross-talk, the measurement chain, the tare) on "
               "held-out blocks of time, add those that lower the held-out error, and "
               "write the calibration with them (docs/design.md).")
EXAMPLE = ("strain-comp diagnose run3.mcap --calibration s1.yaml --validate run4.mcap "
           "--out s1_v2.yaml --json report.json")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bag, the calibration, the held-out bags, the outputs, the candidates."""
    p.add_argument("bag", metavar="BAG.mcap", help="bag with a strain reference")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml",
                   help="calibration file to improve")
    p.add_argument("--validate", metavar="BAG2.mcap", nargs="+",
                   help="held-out bag(s) for the before/after error (default: held-out "
                   "blocks of BAG); after the session start a term is added only if it "
                   "lowers their error beyond the spread between them: give two or more")
    p.add_argument("--out", required=True, metavar="CAL2.yaml",
                   help="calibration to write, with the added terms (replaced atomically)")
    p.add_argument("--json", metavar="OUT.json",
                   help="also write the report as JSON ('-': stdout)")
    p.add_argument("--plots", metavar="DIR",
                   help="also write residual plots per sensor (PNG)")
    p.add_argument("--report", metavar="OUT.html",
                   help="also write one self-contained HTML page: each effect found with "
                   "its reading, the error before and after, the residual plots and the "
                   "calibration's provenance")
    tare_flag(p)
    p.add_argument("--stretch-history", action="store_true",
                   help="also try terms for a rest level or a sensitivity that moves with "
                        "the stretch done (effect kind stretch)")
    p.add_argument("--session-start", choices=("on", "off"), default="on",
                   help="on (default): measure the --validate run after recalibrating it "
                        "on its second cycle after a warm-up one, or on its first where "
                        "that is refused (recalibrate --input, then the output map), as a "
                        "session is started; off: as calibrated")


def run(args: argparse.Namespace) -> int:
    """The loop run (``api.diagnose``); its summary, the calibration and reports written."""
    bag(args.bag)
    for validate in args.validate or ():
        bag(validate, "validation bag")
    inputs = [args.bag, *(args.validate or ()), args.calibration]
    from strain_comp import api
    from strain_comp.diagnosis.report import plot_file
    from strain_comp.progress import wanted

    calibration = api.load_calibration(args.calibration)
    plots = [] if args.plots is None else [plot_file(args.plots, n) for n in calibration.sensors]
    check_distinct((args.out, args.json, args.plots, args.report, *plots))
    for out in (args.out, args.json, args.report):
        if out is not None and out != "-":
            output(out, inputs)
    report = api.diagnose(calibration, args.bag, validate=args.validate, out=args.out,
                          plots=args.plots, inputs=[args.calibration], tare=args.tare,
                          stretch_history=args.stretch_history,
                          session_start=args.session_start == "on",
                          progress_bar=wanted(args.quiet))
    print(report.summary(), file=results(args))
    page = report.to_html(args.calibration) if args.report else None  # drawn first
    if args.json:
        write_json(args.json, report.to_json(), inputs)
    if page is not None:
        write_text(args.report, page, inputs=inputs)
        note(args, f"wrote {args.report}")
    if args.plots:
        note(args, f"wrote plots to {args.plots}")
    note(args, f"wrote {args.out}")
    return 0
