"""``strain-comp import-csv``: a tensile tester's CSV file as a bag (docs/design.md)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import TypeVar

from strain_comp.cli.common import PROG, note, output
from strain_comp.errors import InputError
from strain_comp.io.inputs import existing

T = TypeVar("T")
NAME = "import-csv"
SUMMARY = "turn a tensile-tester CSV into a bag"
DESCRIPTION = (
    "Read a tensile tester's CSV into a bag: /NAME/resistance [ohm, or --resistance-unit] and "
    "/NAME/strain_reference [%, or the unit the CSV gives]. Presets: cb_pdms (7 "
    "columns: R outer, R inner, t_R, position mm, t_pos, force, t_force; strain "
    "= 100 |position| / 40 mm), fiber (4 columns: time s, extension mm, force, "
    "R ohm; strain in mm unless --gauge-length-mm), generic (--columns). Bad rows "
    "are dropped and counted; suspicious references get a warning on stderr.")
EXAMPLE = ("strain-comp import-csv run.csv --out run.mcap --sensor s1 --format generic "
           "--columns time=time_ms,resistance=R_kohm,strain=strain "
           "--scales time=1e-3,resistance=1000,strain=100")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The CSV file, the bag to write, the sensor, the column layout."""
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
    p.add_argument("--resistance-unit", default="ohm", metavar="UNIT",
                   help="unit of the resistance column after --scales (default ohm; e.g. "
                   "R/R0 for a resistance divided by its first sample): fit the bag with "
                   "--input-unit UNIT")
    p.add_argument("--delimiter", metavar="C",
                   help="field delimiter (default: detected among tab ; , | and spaces)")


def _key_values(items: Sequence[str], flag: str, form: str,
                value: Callable[[str], T]) -> dict[str, T]:
    """{key: value(text)} of each ``KEY=VALUE`` of comma-separated ``items``."""
    out: dict[str, T] = {}
    for item in (part for text in items for part in text.split(",") if part.strip()):
        key, sep, text = item.partition("=")
        try:
            if not sep or not key.strip() or not text.strip():
                raise ValueError(item)
            out[key.strip()] = value(text.strip())
        except ValueError:
            raise InputError(f"{flag} {item!r}: expected {form}") from None
    return out


def run(args: argparse.Namespace) -> int:
    """The CSV read, checked and written as a bag; the import report on stdout."""
    existing(args.csv, "CSV file")
    output(args.out, [args.csv])
    from strain_comp.core.calibration import unit_problem
    from strain_comp.io import csv_import
    from strain_comp.io.recording import write_recordings

    if (problem := unit_problem(args.resistance_unit, "ohm or R/R0")) is not None:
        raise InputError(f"--resistance-unit: {problem}")

    recording, report = csv_import.import_csv(
        args.csv, fmt=args.format, sensor=args.sensor, gauge_length_mm=args.gauge_length_mm,
        columns=_key_values(args.columns or [], "--columns",
                            "KEY=COLUMN (index or header name)", str),
        scales=_key_values(args.scales or [], "--scales", "KEY=FACTOR, e.g. time=1e-3", float),
        delimiter=args.delimiter,
        resistance_unit=args.resistance_unit)
    write_recordings({recording.name: recording}, args.out, inputs=[args.csv])
    print("\n".join(report.lines()))
    for line in report.notes:
        note(args, f"{PROG}: note: {line}")
    for line in report.warnings:
        note(args, f"{PROG}: warning: {line}")
    note(args, f"wrote {args.out} (sensor {args.sensor}, {len(recording.t)} samples)")
    return 0
