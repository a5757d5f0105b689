"""``strain-comp recalibrate``: a calibration re-spanned in the field through two known
points or a bag (docs/design.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import bag, note, output, tare_flag
from strain_comp.errors import InputError

NAME = "recalibrate"
SUMMARY = ("output gain and offset (or input zero and span) through two known strains or "
           "a bag")
DESCRIPTION = ("Re-span a calibration in the field: a gain and offset on its output through "
               "two known (resistance, strain) points, or by least squares over a bag with "
               "a reference, stored as effect terms every reader applies alike. With "
               "--input: zero and span on the input resistance instead (the rest and one "
               "known stretch, or a bag's first cycle).")
EXAMPLE = ("strain-comp recalibrate s1.yaml --point 35200:0 --point 44100:20 "
           "--out s1_field.yaml")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The calibration, the points or the bag, the form, the file to write."""
    p.add_argument("calibration", metavar="CAL.yaml", help="calibration file to re-span")
    p.add_argument("--point", action="append", metavar="R:S",
                   help="a resistance [ohm] and its known strain [the calibration's strain "
                   "unit, %% by default] (give two)")
    p.add_argument("--from", dest="from_bag", metavar="BAG.mcap",
                   help="a bag with a strain reference (least-squares gain and offset)")
    p.add_argument("--sensor", action="append", metavar="NAME",
                   help="sensor to recalibrate (needed with --point if several)")
    p.add_argument("--input", action="store_true",
                   help="zero and span on the input resistance, R' = R_rest,cal + "
                        "k (R - R_rest), instead of the output gain and offset (with --from: "
                        "from the first rest and the largest strain)")
    p.add_argument("--first", type=float, metavar="SECONDS",
                   help="with --from: use only the bag's first SECONDS (its first cycle; "
                        "= --window 0:SECONDS)")
    p.add_argument("--window", metavar="START:END",
                   help="with --from: use only the bag's samples from START to END seconds "
                        "after its start, which must hold a load and unload (the "
                        "calibration stretch after a warm-up stretch)")
    p.add_argument("--out", required=True, metavar="CAL2.yaml",
                   help="calibration to write (replaced atomically)")
    tare_flag(p)


def run(args: argparse.Namespace) -> int:
    """The new map (``api.recalibrate``) written; one line per sensor on what changed."""
    from strain_comp import api
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.offline.session_start import parse_point, parse_window

    calibration = api.load_calibration(args.calibration)
    points = [parse_point(p) for p in args.point or []]
    source = None if args.from_bag is None else bag(args.from_bag)
    output(args.out, [args.calibration, source])
    for flag, value in (("--first", args.first), ("--window", args.window)):
        if value is not None and source is None:
            raise InputError(f"recalibrate {flag} needs --from BAG.mcap")
    window = None if args.window is None else parse_window(args.window)
    new, lines = api.recalibrate(calibration, source, points=points, sensors=args.sensor,
                                 tare=args.tare, form="input" if args.input else "output",
                                 first=args.first, window=window)
    save_calibration(new, args.out,
                     inputs=[p for p in (args.calibration, source) if p is not None])
    print("\n".join(lines))
    note(args, f"wrote {args.out}")
    return 0
