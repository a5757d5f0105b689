"""The ``strain-comp`` command line (DESIGN.md, "Command line": names and flags are a contract).

Every subcommand imports its machinery only when it runs, so ``strain-comp --help`` stays
fast. Bad input never shows a traceback: every ``StrainCompError`` and every unreadable
or missing file ends the command with exit code 2 and one line on stderr,
``strain-comp: error: ...``; argparse usage errors exit 2 as well.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from strain_comp.errors import InputError, StrainCompError

PROG = "strain-comp"


def _err(line: str) -> None:
    print(line, file=sys.stderr)


def _existing(path: str, what: str) -> str:
    """``path`` if it exists; InputError naming it otherwise (before any heavy import)."""
    if not Path(path).exists():
        raise InputError(f"{path}: {what} not found")
    return path


def _output(path: str) -> str:
    """``path`` with its parent directory created."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
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


def _write_json(path: str, data: object) -> None:
    text = json.dumps(_finite(data), indent=2, allow_nan=False) + "\n"
    Path(_output(path)).write_text(text, encoding="utf-8")


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
    effects = rig.RigEffects.parse(args.effect) if args.effect else None
    run = rig.simulate(args.scenario, seed=args.seed, effects=effects, duration=args.duration)
    rig.write_sim_bag(run, _output(args.out))
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


def cmd_import_csv(args: argparse.Namespace) -> int:
    _existing(args.csv, "CSV file")
    from strain_comp.io import csv_import

    result = csv_import.import_csv(
        args.csv, fmt=args.format, sensor=args.sensor, gauge_length_mm=args.gauge_length_mm,
        columns=parse_columns(args.columns) if args.columns else None)
    csv_import.write_recording_bag(result.recording, _output(args.out))
    print("\n".join(result.report.lines()))
    print(f"wrote {args.out} (sensor {args.sensor}, {len(result.recording.t)} samples)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    for bag in args.bags:
        _existing(bag, "bag")
    from strain_comp.core.calibration import save_calibration
    from strain_comp.offline.fit import fit_bags, parse_options

    options = parse_options(args.option or [])
    calibration = fit_bags(args.bags, args.model, args.sensor, options, report=_err)
    save_calibration(calibration, args.out)
    for name, cal in calibration.sensors.items():
        prov = cal.provenance
        print(f"{name}: {cal.model} fitted on {prov['n_samples']} samples in "
              f"{prov['fit_seconds']:.2f} s, training RMSE {prov['fit_rmse']:.4f} % "
              f"(dead zone {cal.direction.deadzone:.4g} ohm/s from {prov['direction_from']})")
    print(f"wrote {args.out}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    _existing(args.bag, "bag")
    from strain_comp.core.calibration import load_calibration
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import (
        evaluate_recordings,
        format_notes,
        format_table,
        in_run_bound,
    )

    calibration = load_calibration(_existing(args.calibration, "calibration file"))
    recordings, problems = load_recordings(args.bag)
    try:
        result = evaluate_recordings(recordings, calibration, tare=args.tare)
    except InputError as err:  # nothing to score: say what the bag reader skipped, if anything
        raise InputError("; ".join([f"{args.bag}: {err}", *problems])) from None
    if args.in_run_bound:
        in_run_bound(result, recordings, calibration)
    print(format_table(result))
    for line in problems + format_notes(result):
        print(line)
    if args.json:
        _write_json(args.json, result.to_json())
    if args.plots:
        from strain_comp.offline.plots import plot_evaluation

        written = plot_evaluation(result, args.plots)
        print(f"wrote {len(written)} plots to {args.plots}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    _existing(args.bag, "bag")
    from strain_comp.core.calibration import load_calibration
    from strain_comp.offline.replay import replay_bag

    calibration = load_calibration(_existing(args.calibration, "calibration file"))
    summary = replay_bag(args.bag, calibration, _output(args.out), tare=args.tare)
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
    _existing(args.bag, "bag")
    from strain_comp.core.calibration import load_calibration
    from strain_comp.diagnosis.loop import diagnose_bag

    if args.validate:
        _existing(args.validate, "validation bag")
    calibration = load_calibration(_existing(args.calibration, "calibration file"))
    report = diagnose_bag(args.bag, calibration, validate=args.validate, out=args.out,
                          plots=args.plots, tare=args.tare)
    print(report.summary())
    if args.json:
        _write_json(args.json, report.to_json())
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
    bag = None if args.from_bag is None else _existing(args.from_bag, "bag")
    new, lines = recalibrate(calibration, points=points, bag=bag, sensors=args.sensor,
                             tare=args.tare)
    save_calibration(new, _output(args.out),
                     inputs=[p for p in (args.calibration, bag) if p is not None])
    print("\n".join(lines))
    print(f"wrote {args.out}")
    return 0


def cmd_node(args: argparse.Namespace) -> int:
    _existing(args.params, "parameter file")
    from strain_comp.ros.node import main as node_main

    return node_main(["--ros-args", "--params-file", str(args.params)])


def _tare_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tare", choices=("calibration", "auto"), default="calibration",
                   help="rest resistance from the calibration (default) or from the run's "
                   "first seconds at rest (auto)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser; subcommand names and flags as DESIGN.md fixes them."""
    parser = argparse.ArgumentParser(
        prog=PROG, description="Calibrated strain from soft resistive strain sensors: "
        "simulate or import data, fit, evaluate, replay, diagnose, run.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="make a bag on the virtual test rig")
    p.add_argument("--scenario", metavar="NAME", help="scenario name (see --list)")
    p.add_argument("--out", metavar="BAG.mcap", help="bag to write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--effect", action="append", metavar="K=V",
                   help="rig effect switch and magnitude, e.g. drift=0.5 (repeatable)")
    p.add_argument("--duration", type=float, metavar="S", help="duration in seconds")
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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad input, 130 interrupted)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (2, already printed)
        return exc.code if isinstance(exc.code, int) else 2
    try:
        return int(args.func(args))
    except StrainCompError as err:
        message = str(err)
    except OSError as err:
        where = err.filename if err.filename is not None else ""
        message = f"{where}: {err.strerror or err}" if where else str(err)
    except KeyboardInterrupt:
        return 130
    _err(f"{PROG}: error: " + " ".join(message.split()))
    return 2


if __name__ == "__main__":
    sys.exit(main())
