"""``strain-comp start``: the start of a session, a calibration corrected on a recording's
calibration stretch in one step (docs/design.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import bag, note, output

NAME = "start"
SUMMARY = "the start of a session: correct a calibration on a warm-up and a stretch"
DESCRIPTION = ("The start of a session (a new day, a re-mounted sensor): record a warm-up "
               "stretch and back, then the calibration stretch and back, to about the "
               "largest strain you will use, with the reference. start finds the "
               "calibration stretch itself (the second stretch and return, else the first), "
               "makes the correction the calibration's fit chose on it (the input zero and "
               "span, then the output gain and offset where the calibration takes one) and "
               "prints per sensor the stretch used, the correction and the error (RMSE) on "
               "the stretch, beside the error the calibration expects (fit --model auto). "
               "A recording it cannot read is refused in one line that says what to record "
               "instead; nothing is written.")
EXAMPLE = "strain-comp start s1.yaml start.mcap --out today.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The calibration, the start recording, the file to write, the sensors, the window."""
    p.add_argument("calibration", metavar="CAL.yaml", help="calibration file to start from")
    p.add_argument("recording", metavar="START.mcap",
                   help="the start recording, with the reference strain: a warm-up stretch "
                        "and back, then the calibration stretch and back")
    p.add_argument("--out", required=True, metavar="TODAY.yaml",
                   help="calibration to write (replaced atomically)")
    p.add_argument("--sensor", action="append", metavar="NAME",
                   help="sensor to start (repeatable; default every calibrated one with a "
                        "reference; the first gives the stretch)")
    p.add_argument("--window", metavar="START:END",
                   help="read this stretch instead of the one found, START to END seconds "
                        "after the recording's start (it must hold a stretch and back)")


def run(args: argparse.Namespace) -> int:
    """The session start written; one line per sensor on stdout, the steps not made on stderr."""
    from strain_comp import api
    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.offline.session_start import parse_window, start

    calibration = api.load_calibration(args.calibration)
    source = bag(args.recording)
    output(args.out, [args.calibration, source])
    window = None if args.window is None else parse_window(args.window)
    started = start(calibration, api.read_recordings(source), window=window,
                    sensors=args.sensor, source=source)
    save_calibration(started.calibration, args.out, inputs=[args.calibration, source])
    print("\n".join(started.lines()))
    for line in started.notes:
        note(args, line)
    note(args, f"wrote {args.out}")
    return 0
