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

Results (tables, readings, ``-`` outputs) go to stdout; notes (what was written, tares,
out-of-range counts, skipped data) and progress go to stderr, and ``--quiet`` drops the
notes. ``--json -`` and ``--csv -`` write to stdout; the table then goes to stderr, so stdout
holds the JSON or CSV alone.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import signal
import stat
import sys
import textwrap
import threading
from collections.abc import Callable, Sequence
from typing import NoReturn, TextIO

from strain_comp import __version__
from strain_comp.errors import InputError, StrainCompError, Terminated, raise_terminated
from strain_comp.io.atomic import check_distinct, check_output, write_text

PROG = "strain-comp"
OUT_OF_RANGE_HINT = ("samples out of the calibrated range: if the run's rest level moved, "
                     "try --tare auto, or strain-comp recalibrate")


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


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples (epilogs) printed as written."""


def _err(line: str) -> None:
    print(line, file=sys.stderr)


def _note(args: argparse.Namespace, line: str) -> None:
    """A note on stderr, unless ``--quiet``."""
    if not getattr(args, "quiet", False):
        _err(line)


def _results(args: argparse.Namespace) -> TextIO:
    """Where the command's table goes: stdout, or stderr when stdout carries ``-`` output."""
    dash = "-" in (getattr(args, "json", None), getattr(args, "csv", None))
    return sys.stderr if dash else sys.stdout


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
    """JSON to ``path`` (atomically) or to stdout for ``-``."""
    text = json.dumps(_finite(data), indent=2, allow_nan=False) + "\n"
    if path == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
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
        raise InputError("simulate needs --scenario NAME and --out BAG.mcap (or --list; "
                         "see strain-comp simulate --help)")
    rig.check_size(args.scenario, seed=args.seed, duration=args.duration)
    effects = rig.RigEffects.parse(args.effect) if args.effect else None
    _output(args.out, [])
    run = rig.simulate(args.scenario, seed=args.seed, effects=effects, duration=args.duration)
    rig.write_sim_bag(run, args.out)
    _note(args, f"wrote {args.out} (scenario {args.scenario}, seed {args.seed})")
    return 0


def parse_columns(items: Sequence[str]) -> dict[str, int | str]:
    """``["time=0,resistance=3", "strain=ext_mm"]`` -> {key: column index or header name}."""
    columns: dict[str, int | str] = {}
    for item in (part for text in items for part in text.split(",") if part.strip()):
        key, sep, column = item.partition("=")
        if not sep or not key.strip() or not column.strip():
            raise InputError(f"--columns {item!r}: expected KEY=COLUMN (index or header name)")
        column = column.strip()
        # an index is ASCII digits only ("²" is a digit to str.isdigit, not to int)
        columns[key.strip()] = int(column) if column.isascii() and column.isdigit() else column
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
    for line in result.report.notes:
        _note(args, f"{PROG}: note: {line}")
    for line in result.report.warnings:
        _note(args, f"{PROG}: warning: {line}")
    _note(args, f"wrote {args.out} (sensor {args.sensor}, {len(result.recording.t)} samples)")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    for bag in args.bags:
        _bag(bag)
    _output(args.out, args.bags)
    from strain_comp.core.calibration import save_calibration, strain_unit_words, unit_ok
    from strain_comp.offline.fit import fit_bags, memoryless_note, parse_options
    from strain_comp.offline.options import check_fit_options

    options = parse_options(args.option or [])
    check_fit_options(args.model, options)
    if args.quiet and args.model in ("apl", "pl", "mpi"):
        options.setdefault("progress", False)
    if not unit_ok(args.strain_unit):
        raise InputError(f"--strain-unit {args.strain_unit!r}: expected a unit such as % or "
                         "mm (1-16 letters, digits, %, / or .)")
    notes: list[str] = []  # damage the reader skipped: noted once, in the error if any
    try:
        calibration = fit_bags(args.bags, args.model, args.sensor, options, report=notes.append)
    except StrainCompError as err:
        raise InputError("; ".join([str(err), *notes])) from None
    for line in notes:
        _note(args, line)
    for name, cal in calibration.sensors.items():
        cal.strain_unit = args.strain_unit
        note = memoryless_note(name, cal)
        if note:
            _note(args, note)
    save_calibration(calibration, args.out, inputs=args.bags)
    for name, cal in calibration.sensors.items():
        prov = cal.provenance
        print(f"{name}: {cal.model} fitted on {prov['n_samples']} samples in "
              f"{prov['fit_seconds']:.2f} s, training RMSE {prov['fit_rmse']:.4f} "
              f"{strain_unit_words(cal.strain_unit)} "
              f"(dead zone {cal.direction.deadzone:.4g} ohm/s from {prov['direction_from']})")
    _note(args, f"wrote {args.out}")
    return 0


def _progress(args: argparse.Namespace) -> Callable[[int, int, str], None] | None:
    """A progress line on stderr, rewritten in place; only where stderr is a terminal."""
    if args.quiet or not sys.stderr.isatty():
        return None

    def show(done: int, total: int, bag: str) -> None:
        end = "\n" if done == total else ""
        sys.stderr.write(f"\r[{done}/{total}] {os.path.basename(bag.rstrip('/'))[:60]:<60}"
                         + end)
        sys.stderr.flush()
    return show


def cmd_evaluate(args: argparse.Namespace) -> int:
    from strain_comp.offline.batch import check_jobs, expand_bags

    check_jobs(args.jobs)  # before any bag is read
    for bag in args.bags:
        _bag(bag)
    _existing(args.calibration, "calibration file")
    bags = expand_bags(args.bags)
    for bag in bags:
        _bag(bag)
    inputs = [*bags, args.calibration]
    check_distinct((args.json, args.csv, args.plots))
    if args.json == "-" and args.csv == "-":
        raise InputError("--json - and --csv -: only one of them can go to stdout")
    for out in (args.json, args.csv):
        if out is not None and out != "-":
            _output(out, inputs)
    if len(bags) > 1 or any(os.path.isdir(b) and not os.path.isfile(
            os.path.join(b, "metadata.yaml")) for b in args.bags):
        return _evaluate_many(args, bags, inputs)
    bag = bags[0]
    from strain_comp.core.calibration import load_calibration
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import (
        PLOT_POINTS,
        evaluate_bag,
        format_notes,
        format_table,
        in_run_bound,
    )
    from strain_comp.offline.series import series_csv

    calibration = load_calibration(args.calibration)
    with series_csv(args.csv, inputs=inputs) as table:
        # streamed; an error when nothing can be scored names what the bag reader skipped
        result, problems = evaluate_bag(bag, calibration, tare=args.tare,
                                        plot_points=PLOT_POINTS if args.plots else 0,
                                        series=table, out_of_range=args.out_of_range,
                                        tracking=args.baseline_tracking)
    if args.in_run_bound:  # fits a model to each whole run: loads the recordings whole
        in_run_bound(result, load_recordings(bag)[0], calibration)
    print(format_table(result), file=_results(args))
    for line in problems + format_notes(result):
        _note(args, line)
    if args.json:
        _write_json(args.json, result.to_json(), inputs)
    if args.plots:
        from strain_comp.offline.plots import plot_evaluation

        written = plot_evaluation(result, args.plots, inputs=inputs, calibration=calibration,
                                  bag=bag, calibration_path=args.calibration, tare=args.tare)
        _note(args, f"wrote {len(written)} plots to {args.plots}")
    if args.csv not in (None, "-"):
        _note(args, f"wrote {args.csv}")
    return 0


def _evaluate_many(args: argparse.Namespace, bags: list[str], inputs: list[str]) -> int:
    """``evaluate`` over several bags (``strain_comp.offline.batch``)."""
    from strain_comp.core.calibration import load_calibration
    from strain_comp.offline.batch import evaluate_bags, format_aggregate, format_bag, to_json
    from strain_comp.offline.evaluate import PLOT_POINTS
    from strain_comp.offline.series import series_csv

    load_calibration(args.calibration)  # a bad calibration: one line before any bag
    with series_csv(args.csv, inputs=inputs, bag=True) as table:
        outcomes = evaluate_bags(bags, args.calibration, tare=args.tare, jobs=args.jobs,
                                 plot_points=PLOT_POINTS if args.plots else 0,
                                 in_run=args.in_run_bound, plots=args.plots, series=table,
                                 progress=_progress(args), out_of_range=args.out_of_range,
                                 tracking=args.baseline_tracking)
        if args.json:  # the table is committed only once the JSON is written too
            _write_json(args.json, to_json(outcomes), inputs)
    results = _results(args)
    for outcome in outcomes:
        text, notes = format_bag(outcome)
        print(text, file=results)
        for line in notes:
            _note(args, f"{outcome.bag}: {line}")
        if outcome.plots:
            _note(args, f"wrote {len(outcome.plots)} plots to "
                  f"{os.path.dirname(outcome.plots[0])}")
    print(format_aggregate(outcomes), file=results)
    if args.csv not in (None, "-"):
        _note(args, f"wrote {args.csv}")
    failed = [o for o in outcomes if o.error is not None]
    if failed:
        raise InputError(f"{len(failed)} of {len(outcomes)} bags could not be evaluated "
                         f"(first: {failed[0].error})")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    _bag(args.bag)
    _existing(args.calibration, "calibration file")
    _output(args.out, [args.bag, args.calibration])
    if args.csv not in (None, "-"):
        _output(args.csv, [args.bag, args.calibration, args.out])
    from strain_comp.core.calibration import load_calibration
    from strain_comp.offline.replay import replay_bag

    calibration = load_calibration(args.calibration)
    summary = replay_bag(args.bag, calibration, args.out, inputs=[args.calibration],
                         tare=args.tare, csv=args.csv,
                         tracking=args.baseline_tracking)
    results = _results(args)
    print(f"replayed {summary.n_compensated} resistance messages of {len(summary.sensors)} "
          f"sensors into {args.out} ({summary.n_output_messages} messages written, "
          f"{summary.n_input_messages} of them input messages copied through)",
          file=results)
    for name, health in summary.sensors.items():
        if health.n_bad or health.n_out_of_range or health.n_gaps:
            print(f"{name}: {health.n_bad} bad samples (estimate held), {health.n_out_of_range} "
                  f"out of range, {health.n_gaps} gap resets", file=results)
            if health.n_out_of_range:
                _note(args, f"{name}: {OUT_OF_RANGE_HINT}")
    for problem in summary.problems:
        _note(args, problem)
    if args.csv not in (None, "-"):
        _note(args, f"wrote {args.csv}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    _bag(args.bag)
    for validate in args.validate or ():
        _bag(validate, "validation bag")
    _existing(args.calibration, "calibration file")
    inputs = [args.bag, *(args.validate or ()), args.calibration]
    check_distinct((args.out, args.json, args.plots))
    for out in (args.out, args.json):
        if out is not None and out != "-":
            _output(out, inputs)
    from strain_comp.core.calibration import load_calibration
    from strain_comp.diagnosis.loop import diagnose_bag

    calibration = load_calibration(args.calibration)
    report = diagnose_bag(args.bag, calibration, validate=args.validate, out=args.out,
                          plots=args.plots, inputs=[args.calibration], tare=args.tare,
                          stretch_history=args.stretch_history,
                          session_start=args.session_start == "on")
    print(report.summary(), file=_results(args))
    if args.json:
        _write_json(args.json, report.to_json(), inputs)
    if args.plots:
        _note(args, f"wrote plots to {args.plots}")
    _note(args, f"wrote {args.out}")
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
    if args.first is not None and bag is None:
        raise InputError("recalibrate --first needs --from BAG.mcap")
    new, lines = recalibrate(calibration, points=points, bag=bag, sensors=args.sensor,
                             tare=args.tare, form="input" if args.input else "output",
                             first=args.first)
    save_calibration(new, args.out,
                     inputs=[p for p in (args.calibration, bag) if p is not None])
    print("\n".join(lines))
    _note(args, f"wrote {args.out}")
    return 0


def _require_ros(command: str) -> None:
    """InputError saying how to get ROS 2's Python client when rclpy is not installed."""
    if importlib.util.find_spec("rclpy") is None:
        raise InputError(f"{command} needs ROS 2's Python client (rclpy): pip install "
                         "'.[ros]' in this project, or source a ROS 2 Jazzy installation")


def cmd_node(args: argparse.Namespace) -> int:
    _existing(args.params, "parameter file")
    _require_ros("strain-comp node")
    from strain_comp.ros.node import main as node_main

    code = node_main(["--ros-args", "--params-file", str(args.params)])
    return code if code in (0, 2, 130) else 2


def cmd_play(args: argparse.Namespace) -> int:
    _existing(args.bag, "bag")
    _require_ros("strain-comp play")
    from strain_comp.ros.player import main as play_main

    n = play_main(args.bag, clock=args.clock, rate=args.rate, topics=args.topic,
                  lockstep=args.lockstep)
    _note(args, f"played {n} messages")
    return 0


def _tracking_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--baseline-tracking", choices=("off", "on"), default="on",
                   help="let the rest level follow slowly while the sensor rests "
                   "(zero-tracking after OIML R76: at hold, near rest, bounded rate; on "
                   "by default, see docs/generalisation.md)")


def _tare_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tare", choices=("calibration", "auto"), default="calibration",
                   help="rest resistance from the calibration (default) or from the run's "
                   "first seconds at rest (auto)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser; subcommand names and flags as docs/design.md fixes them."""
    parser = _Parser(
        prog=PROG, formatter_class=_Formatter,
        description="Calibrated strain from soft resistive strain sensors: "
        "simulate or import data, fit, evaluate, replay, diagnose, run.",
        epilog="example:\n  strain-comp evaluate bags/demo_rates.mcap --calibration "
        "config/demo_calibration.yaml\n\n'strain-comp COMMAND --help' describes a command.")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, summary: str, description: str, example: str, notes: str = ""
                ) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=summary, description=textwrap.fill(description, 88),
                              epilog=(notes + "\n\n" if notes else "") + "example:\n  "
                              + example, formatter_class=_Formatter)

    p = command("simulate", "make a bag on the virtual test rig",
                "Record a scenario on the virtual test rig (a simulated tensile tester with "
                "a soft sensor): /NAME/resistance and /NAME/strain_reference in an MCAP bag.",
                "strain-comp simulate --scenario rates --out rates.mcap --seed 2 "
                "--effect drift=0.05")
    p.add_argument("--scenario", metavar="NAME", help="scenario name (see --list)")
    p.add_argument("--out", metavar="BAG.mcap", help="bag to write (replaced atomically)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed, 0 .. 2^63-1 (default 0)")
    p.add_argument("--effect", action="append", metavar="K=V",
                   help="rig effect switch and magnitude, e.g. drift=0.5 (repeatable)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="duration in seconds; at most 2,000,000 samples x sensors "
                   "(40,000 s for a 50 Hz scenario)")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.set_defaults(func=cmd_simulate)

    p = command("import-csv", "turn a tensile-tester CSV into a bag",
                "Read a tensile tester's CSV into a bag: /NAME/resistance [ohm] and "
                "/NAME/strain_reference [%, or the unit the CSV gives]. Presets: cb_pdms (7 "
                "columns: R outer, R inner, t_R, position mm, t_pos, force, t_force; strain "
                "= 100 |position| / 40 mm), fiber (4 columns: time s, extension mm, force, "
                "R ohm; strain in mm unless --gauge-length-mm), generic (--columns). Bad rows "
                "are dropped and counted; suspicious references get a warning on stderr.",
                "strain-comp import-csv run.csv --out run.mcap --sensor s1 --format generic "
                "--columns time=time_ms,resistance=R_kohm,strain=strain "
                "--scales time=1e-3,resistance=1000,strain=100")
    p.add_argument("csv", metavar="IN.csv", help="the CSV file (delimiter, decimal comma "
                   "and header detected)")
    p.add_argument("--out", required=True, metavar="BAG.mcap",
                   help="bag to write (replaced atomically)")
    p.add_argument("--sensor", required=True, metavar="NAME",
                   help="sensor name: the topics become /NAME/resistance, "
                   "/NAME/strain_reference")
    p.add_argument("--format", required=True, choices=("cb_pdms", "fiber", "generic"),
                   help="column layout: a preset, or generic with --columns")
    p.add_argument("--gauge-length-mm", type=float, metavar="X",
                   help="gauge length [mm] for strain in %% (default: cb_pdms 40 mm; fiber "
                   "none, the reference is then the extension in mm)")
    p.add_argument("--columns", action="append", metavar="KEY=COL,...",
                   help="column mapping (index or header name) for keys time, resistance, "
                   "strain, strain_time, e.g. time=0,resistance=3,strain=1")
    p.add_argument("--scales", action="append", metavar="KEY=FACTOR,...",
                   help="factor per column key into s, ohm and the strain unit, e.g. "
                   "time=1e-3 (ms),resistance=1000 (kohm),strain=100 (a fraction)")
    p.add_argument("--delimiter", metavar="C",
                   help="field delimiter (default: detected among tab ; , | and spaces)")
    p.set_defaults(func=cmd_import_csv)

    from strain_comp.offline.options import describe_options

    p = command("fit", "fit a model to bags with a strain reference",
                "Fit a compensation model (resistance in, strain out) to recordings with a "
                "reference strain and write a calibration file. The file passes the checks "
                "every reader applies before it is written; a fit that would not load is "
                "refused.",
                "strain-comp fit run1.mcap run2.mcap --model apl --sensor s1 --out s1.yaml "
                "--option N=11", notes=describe_options())
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
    p.set_defaults(func=cmd_fit)

    p = command("evaluate", "error table of a calibration on one or many bags",
                "Run a calibration over recordings with a reference strain and print the "
                "errors per sensor (n, RMSE, MAE, max |error| in the calibration's strain "
                "unit, R^2). Several bags or a folder: a table per bag and the errors pooled "
                "over all of them.",
                "strain-comp evaluate run3.mcap run4.mcap --calibration s1.yaml "
                "--csv series.csv --json errors.json --jobs 2")
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
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="bags evaluated at once, in N processes (default 1)")
    p.add_argument("--out-of-range", choices=("clamp", "extrapolate", "extend"),
                   default="extend",
                   help="strain beyond the calibrated resistance range: extended with a "
                   "bounded slope within a bounded reach (extend, default), clamped to the "
                   "calibrated strain range, or extended with the model's end slope "
                   "(flagged in every mode; docs/design.md)")
    _tracking_flag(p)
    p.add_argument("--in-run-bound", action="store_true",
                   help="also fit the same model on each run itself and give its RMSE "
                   "(JSON key in_run_rmse; costs a fit per bag)")
    _tare_flag(p)
    p.set_defaults(func=cmd_evaluate)

    p = command("replay", "write estimated strain and direction into a new bag",
                "Run a calibration over a bag as the node would: a new bag with every input "
                "and /NAME/strain, /NAME/direction, /NAME/status, /NAME/strain_stamped "
                "(sensor_msgs/JointState) and /diagnostics at each input's time; --csv also "
                "writes the series as a table.",
                "strain-comp replay run3.mcap --calibration s1.yaml --out run3_strain.mcap "
                "--csv run3_strain.csv")
    p.add_argument("bag", metavar="IN.mcap", help="bag with /NAME/resistance")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml",
                   help="calibration file")
    p.add_argument("--out", required=True, metavar="OUT.mcap",
                   help="bag to write (replaced atomically)")
    p.add_argument("--csv", metavar="OUT.csv",
                   help="also write the series: time [s], resistance [ohm], estimate and "
                   "reference [strain unit], direction, status per sensor ('-': stdout)")
    _tare_flag(p)
    _tracking_flag(p)
    p.set_defaults(func=cmd_replay)

    p = command("diagnose", "find the effect a calibration lacks and add it",
                "The residual loop: score candidate effects (rate, relaxation, drift, "
                "temperature, Mullins, cross-talk, the measurement chain, the tare) on "
                "held-out blocks of time, add those that lower the held-out error, and "
                "write the calibration with them (docs/loop.md).",
                "strain-comp diagnose run3.mcap --calibration s1.yaml --validate run4.mcap "
                "--out s1_v2.yaml --json report.json")
    p.add_argument("bag", metavar="BAG.mcap", help="bag with a strain reference")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml",
                   help="calibration file to improve")
    p.add_argument("--validate", metavar="BAG2.mcap", nargs="+",
                   help="held-out bag(s) for the before/after error (default: held-out "
                   "blocks of BAG); with several, a term must also lower the median run's")
    p.add_argument("--out", required=True, metavar="CAL2.yaml",
                   help="calibration to write, with the added terms (replaced atomically)")
    p.add_argument("--json", metavar="OUT.json",
                   help="also write the report as JSON ('-': stdout)")
    p.add_argument("--plots", metavar="DIR",
                   help="also write residual plots per sensor (PNG)")
    _tare_flag(p)
    p.add_argument("--stretch-history", action="store_true",
                   help="also try terms for a rest level or a sensitivity that moves with "
                        "the stretch done (effect kind stretch)")
    p.add_argument("--session-start", choices=("on", "off"), default="on",
                   help="on (default): measure the --validate run after recalibrating it "
                        "on its first cycle (recalibrate --input, then the output map), "
                        "as a session is used; off: as calibrated")
    p.set_defaults(func=cmd_diagnose)

    p = command("recalibrate", "output gain and offset (or input zero and span) through "
                "two known strains or a bag",
                "Re-span a calibration in the field: a gain and offset on its output through "
                "two known (resistance, strain) points, or by least squares over a bag with "
                "a reference, stored as effect terms every reader applies alike. With "
                "--input: zero and span on the input resistance instead (the rest and one "
                "known stretch, or a bag's first cycle).",
                "strain-comp recalibrate s1.yaml --point 35200:0 --point 44100:20 "
                "--out s1_field.yaml")
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
                   help="with --from: use only the bag's first SECONDS (its first cycle)")
    p.add_argument("--out", required=True, metavar="CAL2.yaml",
                   help="calibration to write (replaced atomically)")
    _tare_flag(p)
    p.set_defaults(func=cmd_recalibrate)

    p = command("node", "run the rclpy compensator node (as `ros2 run` does)",
                "The live node (needs the ros extra: pip install '.[ros]'): "
                "/NAME/resistance in, /NAME/strain, /NAME/direction and /diagnostics out "
                "(docs/ros.md).",
                "strain-comp node --params config/compensator_params.yaml")
    p.add_argument("--params", required=True, metavar="FILE",
                   help="node parameter YAML (sensors, calibrations, tunables)")
    p.set_defaults(func=cmd_node)

    p = command("play", "publish a bag's messages over ROS 2 (ros2 bag play where ROS is "
                "installed)",
                "Publish a bag's messages at their recorded times, for machines without "
                "rosbag2 (needs the ros extra).",
                "strain-comp play bags/demo_rates.mcap --clock --rate 2")
    p.add_argument("bag", metavar="BAG.mcap", help="bag to play")
    p.add_argument("--clock", action="store_true",
                   help="publish /clock with each message's log time (for use_sim_time)")
    p.add_argument("--rate", type=float, default=1.0, metavar="X",
                   help="speed factor (default 1; 0: as fast as possible)")
    p.add_argument("--topic", action="append", metavar="TOPIC",
                   help="play only this topic (repeatable; default all)")
    p.add_argument("--lockstep", metavar="TOPIC",
                   help="after each message wait for one message on TOPIC (the node's answer)")
    p.set_defaults(func=cmd_play)
    for p in sub.choices.values():
        p.add_argument("-q", "--quiet", action="store_true",
                       help="no notes on stderr (what was written, tares, skipped data); "
                       "results and errors still print")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad input, 130 interrupted,
    143 terminated by SIGTERM)."""
    handler = signal.getsignal(signal.SIGTERM)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return _main(argv)
    except Terminated:
        return 143
    finally:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, signal.SIG_DFL if handler is None else handler)


def _main(argv: Sequence[str] | None) -> int:
    """``main`` under its SIGTERM handler."""
    try:
        parser = build_parser()
        try:
            args, extra = parser.parse_known_args(argv)
        except SystemExit:  # --help, --version or --list printed; nothing else exits
            return 0
        if extra:
            raise UsageError(f"{args.command}: unrecognized arguments: {' '.join(extra)} "
                             f"(see {PROG} {args.command} --help)")
        import numpy as np

        # overflow on hostile data gives inf / NaN, which the commands screen where it
        # matters; numpy's warning lines would break the one-line contract
        with np.errstate(all="ignore"):
            return int(args.func(args))
    except StrainCompError as err:
        message = str(err)
    except BrokenPipeError:  # the reader of stdout went away (e.g. `| head`)
        sys.stdout = open(os.devnull, "w")  # no second error when Python flushes at exit
        message = "stdout closed before the output was complete (broken pipe)"
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
