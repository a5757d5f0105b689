"""The ``strain-comp`` command line (docs/design.md, "Command line": a contract).

Every subcommand imports its machinery only when it runs, so ``strain-comp --help`` stays
fast. Exit codes are 0 (done), 2 (refused or failed) and 130 (interrupted), nothing else,
and never a traceback: every ``StrainCompError``, unreadable or missing file, usage error
(argparse's included) and, as a last resort, any unexpected exception ends the command with
exit code 2 and exactly one line on stderr, ``strain-comp: error: ...``.

Inputs (bags, CSV files, calibrations, parameter files) must be regular files (a bag may be
a rosbag2 directory): a FIFO or a device is refused before it is opened, so a command never
blocks on one. Every output goes through ``strain_comp.io.atomic`` with the command's
inputs, so an output that is an input (the same file, or a hard or symbolic link to it) or
not a regular file is refused before any work is done, and a kill leaves the old file or
the complete new one.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import stat
import sys
from collections.abc import Sequence
from typing import NoReturn

from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.atomic import check_distinct, check_output, write_text

PROG = "strain-comp"


class UsageError(StrainCompError):
    """A command line argparse cannot parse (printed as one line, exit code 2)."""


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line (``UsageError``) instead of usage + exit."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix(PROG).strip()
        hint = f"see {self.prog} --help"
        raise UsageError(f"{command + ': ' if command else ''}{message} ({hint})")

    def exit(self, status: int = 0, message: str | None = None) -> NoReturn:
        if status != 0 or message:
            raise UsageError(message or f"exit status {status}")
        raise SystemExit(0)


def _err(line: str) -> None:
    print(line, file=sys.stderr)


def _existing(path: str, what: str, *, directory: bool = False) -> str:
    """``path`` if it is a regular file (or, with ``directory``, a directory); InputError
    naming it otherwise, before anything opens it (a FIFO would block a reader)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except OSError as err:
        raise InputError(f"{path}: {what} cannot be read ({err.strerror})") from None
    if not (stat.S_ISREG(mode) or (directory and stat.S_ISDIR(mode))):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
        raise InputError(f"{path}: {what} is {kind}")
    return path


def _bag(path: str, what: str = "bag") -> str:
    """An input bag: an MCAP file or a rosbag2 directory."""
    return _existing(path, what, directory=True)


def _output(path: str, inputs: Sequence[str | None]) -> str:
    """``path`` if it may be written: not one of ``inputs``, not a non-regular file."""
    check_output(path, [i for i in inputs if i is not None])
    return path


def _finite(value: object) -> object:
    """NaN and inf (not JSON) as null, recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _write_json(path: str, data: object, inputs: Sequence[str]) -> None:
    text = json.dumps(_finite(data), indent=2, allow_nan=False) + "\n"
    write_text(path, text, inputs=inputs)


def cmd_simulate(args: argparse.Namespace) -> int:
    from strain_comp.offline import rig

    if args.list:
        for name, description in rig.SCENARIOS.items():
            print(f"{name:<12} {description}")
        print("\neffects (--effect NAME=VALUE):")
        print(rig.RigEffects.describe())
        return 0
    if not args.scenario or not args.out:
        raise InputError("simulate needs --scenario NAME and --out BAG.mcap (or --list)")
    rig.check_size(args.scenario, seed=args.seed, duration=args.duration)
    effects = rig.RigEffects.parse(args.effect) if args.effect else None
    _output(args.out, [])
    run = rig.simulate(args.scenario, seed=args.seed, effects=effects, duration=args.duration)
    rig.write_sim_bag(run, args.out)
    print(f"wrote {args.out} (scenario {args.scenario}, seed {args.seed})")
    return 0


def parse_columns(items: Sequence[str]) -> dict[str, int | str]:
    """``["time=0,resistance=3", "strain=ext_mm"]`` -> {key: column index or header name}."""
    columns: dict[str, int | str] = {}
    for item in (part for text in items for part in text.split(",") if part.strip()):
        key, sep, column = item.partition("=")
        if not sep or not key.strip() or not column.strip():
            raise InputError(f"--columns {item!r}: expected KEY=COLUMN (index or header name)")
        column = column.strip()
        columns[key.strip()] = int(column) if column.isdigit() else column
    return columns


def parse_scales(items: Sequence[str]) -> dict[str, float]:
    """``["time=1e-3,resistance=1000"]`` -> {key: factor}."""
    scales: dict[str, float] = {}
    for item in (part for text in items for part in text.split(",") if part.strip()):
        key, sep, value = item.partition("=")
        try:
            scales[key.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep or not key.strip():
            raise InputError(f"--scales {item!r}: expected KEY=FACTOR, e.g. time=1e-3")
    return scales


def cmd_import_csv(args: argparse.Namespace) -> int:
    _existing(args.csv, "CSV file")
    _output(args.out, [args.csv])
    from strain_comp.io import csv_import

    result = csv_import.import_csv(
        args.csv, fmt=args.format, sensor=args.sensor, gauge_length_mm=args.gauge_length_mm,
        columns=parse_columns(args.columns) if args.columns else None,
        scales=parse_scales(args.scales) if args.scales else None, delimiter=args.delimiter)
    csv_import.write_recording_bag(result.recording, args.out, inputs=[args.csv])
    print("\n".join(result.report.lines()))
    print(f"wrote {args.out} (sensor {args.sensor}, {len(result.recording.t)} samples)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    for bag in args.bags:
        _bag(bag)
    _output(args.out, args.bags)
    from strain_comp.core.calibration import save_calibration, strain_unit_words, unit_ok
    from strain_comp.offline.fit import fit_bags, parse_options
    from strain_comp.offline.options import check_fit_options

    options = parse_options(args.option or [])
    check_fit_options(args.model, options)
    if not unit_ok(args.strain_unit):
        raise InputError(f"--strain-unit {args.strain_unit!r}: expected a unit such as % or "
                         "mm (1-16 letters, digits, %, / or .)")
    notes: list[str] = []  # damage the reader skipped: noted once, in the error if any
    try:
        calibration = fit_bags(args.bags, args.model, args.sensor, options, report=notes.append)
    except StrainCompError as err:
        raise InputError("; ".join([str(err), *notes])) from None
    for line in notes:
        _err(line)
    for cal in calibration.sensors.values():
        cal.strain_unit = args.strain_unit
    save_calibration(calibration, args.out, inputs=args.bags)
    for name, cal in calibration.sensors.items():
        prov = cal.provenance
        print(f"{name}: {cal.model} fitted on {prov['n_samples']} samples in "
              f"{prov['fit_seconds']:.2f} s, training RMSE {prov['fit_rmse']:.4f} "
              f"{strain_unit_words(cal.strain_unit)} "
              f"(dead zone {cal.direction.deadzone:.4g} ohm/s from {prov['direction_from']})")
    print(f"wrote {args.out}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    _bag(args.bag)
    _existing(args.calibration, "calibration file")
    inputs = [args.bag, args.calibration]
    check_distinct((args.json, args.plots))
    if args.json:
        _output(args.json, inputs)
    from strain_comp.core.calibration import load_calibration
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import (
        PLOT_POINTS,
        evaluate_bag,
        format_notes,
        format_table,
        in_run_bound,
    )

    calibration = load_calibration(args.calibration)
    # streamed; an error when nothing can be scored names what the bag reader skipped
    result, problems = evaluate_bag(args.bag, calibration, tare=args.tare,
                                    plot_points=PLOT_POINTS if args.plots else 0)
    if args.in_run_bound:  # fits a model to each whole run: loads the recordings whole
        in_run_bound(result, load_recordings(args.bag)[0], calibration)
    print(format_table(result))
    for line in problems + format_notes(result):
        print(line)
    if args.json:
        _write_json(args.json, result.to_json(), inputs)
    if args.plots:
        from strain_comp.offline.plots import plot_evaluation

        written = plot_evaluation(result, args.plots, inputs=inputs)
        print(f"wrote {len(written)} plots to {args.plots}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    _bag(args.bag)
    _existing(args.calibration, "calibration file")
    _output(args.out, [args.bag, args.calibration])
    from strain_comp.core.calibration import load_calibration
    from strain_comp.offline.replay import replay_bag

    calibration = load_calibration(args.calibration)
    summary = replay_bag(args.bag, calibration, args.out, inputs=[args.calibration],
                         tare=args.tare)
    print(f"replayed {summary.n_input_messages} input messages of {len(summary.sensors)} "
          f"sensors into {args.out} ({summary.n_output_messages} output messages)")
    for name, health in summary.sensors.items():
        if health.n_bad or health.n_out_of_range or health.n_gaps:
            print(f"{name}: {health.n_bad} bad samples (estimate held), {health.n_out_of_range} "
                  f"out of range, {health.n_gaps} gap resets")
    for problem in summary.problems:
        print(problem)
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    _bag(args.bag)
    if args.validate:
        _bag(args.validate, "validation bag")
    _existing(args.calibration, "calibration file")
    inputs = [i for i in (args.bag, args.validate, args.calibration) if i is not None]
    check_distinct((args.out, args.json, args.plots))
    for out in (args.out, args.json):
        if out is not None:
            _output(out, inputs)
    from strain_comp.core.calibration import load_calibration
    from strain_comp.diagnosis.loop import diagnose_bag

    calibration = load_calibration(args.calibration)
    report = diagnose_bag(args.bag, calibration, validate=args.validate, out=args.out,
                          plots=args.plots, inputs=[args.calibration], tare=args.tare)
    print(report.summary())
    if args.json:
        _write_json(args.json, report.to_json(), inputs)
    if args.plots:
        print(f"wrote plots to {args.plots}")
    print(f"wrote {args.out}")
    return 0


def cmd_recalibrate(args: argparse.Namespace) -> int:
    from strain_comp.core.calibration import load_calibration, save_calibration
    from strain_comp.offline.recalibrate import parse_point, recalibrate

    if bool(args.point) == bool(args.from_bag):
        raise InputError("recalibrate needs either two --point R:S or --from BAG.mcap")
    calibration = load_calibration(_existing(args.calibration, "calibration file"))
    points = [parse_point(p) for p in args.point or []]
    bag = None if args.from_bag is None else _bag(args.from_bag)
    _output(args.out, [args.calibration, bag])
    new, lines = recalibrate(calibration, points=points, bag=bag, sensors=args.sensor,
                             tare=args.tare)
    save_calibration(new, args.out,
                     inputs=[p for p in (args.calibration, bag) if p is not None])
    print("\n".join(lines))
    print(f"wrote {args.out}")
    return 0


def cmd_node(args: argparse.Namespace) -> int:
    _existing(args.params, "parameter file")
    from strain_comp.ros.node import main as node_main

    code = node_main(["--ros-args", "--params-file", str(args.params)])
    return code if code in (0, 2, 130) else 2


def cmd_play(args: argparse.Namespace) -> int:
    _existing(args.bag, "bag")
    from strain_comp.ros.player import main as play_main

    n = play_main(args.bag, clock=args.clock, rate=args.rate, topics=args.topic,
                  lockstep=args.lockstep)
    print(f"played {n} messages")
    return 0


def _tare_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tare", choices=("calibration", "auto"), default="calibration",
                   help="rest resistance from the calibration (default) or from the run's "
                   "first seconds at rest (auto)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser; subcommand names and flags as docs/design.md fixes them."""
    parser = _Parser(
        prog=PROG, description="Calibrated strain from soft resistive strain sensors: "
        "simulate or import data, fit, evaluate, replay, diagnose, run.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="make a bag on the virtual test rig")
    p.add_argument("--scenario", metavar="NAME", help="scenario name (see --list)")
    p.add_argument("--out", metavar="BAG.mcap", help="bag to write")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed, 0 .. 2^63-1 (default 0)")
    p.add_argument("--effect", action="append", metavar="K=V",
                   help="rig effect switch and magnitude, e.g. drift=0.5 (repeatable)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="duration in seconds; at most 2,000,000 samples x sensors "
                   "(40,000 s for a 50 Hz scenario)")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("import-csv", help="turn a tensile-tester CSV into a bag")
    p.add_argument("csv", metavar="IN.csv")
    p.add_argument("--out", required=True, metavar="BAG.mcap")
    p.add_argument("--sensor", required=True, metavar="NAME")
    p.add_argument("--format", required=True, choices=("cb_pdms", "fiber", "generic"))
    p.add_argument("--gauge-length-mm", type=float, metavar="X",
                   help="gauge length for strain in %% (fiber: else strain = extension in mm)")
    p.add_argument("--columns", action="append", metavar="KEY=COL,...",
                   help="column mapping (index or header name) for keys time, resistance, "
                   "strain, strain_time, e.g. time=0,resistance=3,strain=1")
    p.add_argument("--scales", action="append", metavar="KEY=FACTOR,...",
                   help="factor per column key into s, ohm and the strain unit, e.g. "
                   "time=1e-3 (ms),resistance=1000 (kohm),strain=100 (a fraction)")
    p.add_argument("--delimiter", metavar="C",
                   help="field delimiter (default: detected among tab ; , | and spaces)")
    p.set_defaults(func=cmd_import_csv)

    p = sub.add_parser("fit", help="fit a model to bags with a strain reference")
    p.add_argument("bags", nargs="+", metavar="BAG.mcap")
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="apl, pl, mpi, cubic, sinh_pl, rational, spike_decay")
    p.add_argument("--sensor", required=True, action="append", metavar="NAME",
                   help="sensor to fit (repeatable), or 'all'")
    p.add_argument("--out", required=True, metavar="CAL.yaml")
    p.add_argument("--option", action="append", metavar="K=V",
                   help="fit option, e.g. N=11, M=9, mode=split, k_sigma=3 (repeatable)")
    p.add_argument("--strain-unit", default="%", metavar="UNIT",
                   help="unit of the bags' strain_reference (default %%; mm for an extension "
                   "imported without a gauge length): errors and readings are given in it")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("evaluate", help="error table of a calibration on a bag")
    p.add_argument("bag", metavar="BAG.mcap")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml")
    p.add_argument("--json", metavar="OUT.json", help="also write the errors as JSON")
    p.add_argument("--plots", metavar="DIR", help="also write PNG plots per sensor")
    p.add_argument("--in-run-bound", action="store_true",
                   help="also fit the same model on this run itself and give its RMSE "
                   "(JSON key in_run_rmse; costs a fit)")
    _tare_flag(p)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("replay", help="write estimated strain and direction into a new bag")
    p.add_argument("bag", metavar="IN.mcap")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml")
    p.add_argument("--out", required=True, metavar="OUT.mcap")
    _tare_flag(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("diagnose", help="find the effect a calibration lacks and add it")
    p.add_argument("bag", metavar="BAG.mcap")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml")
    p.add_argument("--validate", metavar="BAG2.mcap", help="held-out bag for before/after")
    p.add_argument("--out", required=True, metavar="CAL2.yaml")
    p.add_argument("--json", metavar="OUT.json")
    p.add_argument("--plots", metavar="DIR")
    _tare_flag(p)
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("recalibrate",
                       help="output gain and offset through two known strains or a bag")
    p.add_argument("calibration", metavar="CAL.yaml")
    p.add_argument("--point", action="append", metavar="R:S",
                   help="a resistance [ohm] and its known strain [%%] (give two)")
    p.add_argument("--from", dest="from_bag", metavar="BAG.mcap",
                   help="a bag with a strain reference (least-squares gain and offset)")
    p.add_argument("--sensor", action="append", metavar="NAME",
                   help="sensor to recalibrate (needed with --point if several)")
    p.add_argument("--out", required=True, metavar="CAL2.yaml")
    _tare_flag(p)
    p.set_defaults(func=cmd_recalibrate)

    p = sub.add_parser("node", help="run the rclpy compensator node (as `ros2 run` does)")
    p.add_argument("--params", required=True, metavar="FILE", help="node parameter YAML")
    p.set_defaults(func=cmd_node)

    p = sub.add_parser("play", help="publish a bag's messages over ROS 2 (ros2 bag play "
                       "where ROS is installed)")
    p.add_argument("bag", metavar="BAG.mcap")
    p.add_argument("--clock", action="store_true",
                   help="publish /clock with each message's log time (for use_sim_time)")
    p.add_argument("--rate", type=float, default=1.0, metavar="X",
                   help="speed factor (default 1; 0: as fast as possible)")
    p.add_argument("--topic", action="append", metavar="TOPIC",
                   help="play only this topic (repeatable; default all)")
    p.add_argument("--lockstep", metavar="TOPIC",
                   help="after each message wait for one message on TOPIC (the node's answer)")
    p.set_defaults(func=cmd_play)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad input, 130 interrupted)."""
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit:  # --help or --list printed; nothing else exits
            return 0
        import numpy as np

        # overflow on hostile data gives inf / NaN, which the commands screen where it
        # matters; numpy's warning lines would break the one-line contract
        with np.errstate(all="ignore"):
            return int(args.func(args))
    except StrainCompError as err:
        message = str(err)
    except OSError as err:
        where = err.filename if err.filename is not None else ""
        message = f"{where}: {err.strerror or err}" if where else str(err)
    except KeyboardInterrupt:
        return 130
    except (Exception, SystemExit) as err:  # a fault of strain_comp: still one line
        message = f"unexpected {type(err).__name__}: {err}"
    _err(f"{PROG}: error: " + " ".join(message.split()))
    return 2


if __name__ == "__main__":
    sys.exit(main())
