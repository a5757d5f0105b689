"""``strain-comp replay``: a calibration run over a bag as the node would, into a new bag
(docs/design.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import (
    OUT_OF_RANGE_HINT,
    bag,
    note,
    references_flag,
    results,
    tare_flag,
    tracking_flag,
)
from strain_comp.io.inputs import existing

NAME = "replay"
SUMMARY = "write estimated strain and direction into a new bag"
DESCRIPTION = ("Run a calibration over a bag as the node would: a new bag with every input "
               "and /NAME/strain, /NAME/direction, /NAME/status, /NAME/strain_stamped "
               "(sensor_msgs/JointState) and /diagnostics at each input's time; --csv also "
               "writes the series as a table.")
EXAMPLE = ("strain-comp replay run3.mcap --calibration s1.yaml --out run3_strain.mcap "
           "--csv run3_strain.csv")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bag, the calibration, the bag and table to write, the engine's settings."""
    p.add_argument("bag", metavar="IN.mcap", help="bag with /NAME/resistance")
    p.add_argument("--calibration", required=True, metavar="CAL.yaml",
                   help="calibration file")
    p.add_argument("--out", required=True, metavar="OUT.mcap",
                   help="bag to write (replaced atomically)")
    p.add_argument("--csv", metavar="OUT.csv",
                   help="also write the series: time [s], resistance [ohm], estimate and "
                   "reference [strain unit], direction, status per sensor ('-': stdout)")
    tare_flag(p)
    tracking_flag(p)
    references_flag(p)


def run(args: argparse.Namespace) -> int:
    """The bag replayed (``api.replay``); what was compensated and held, printed."""
    bag(args.bag)
    existing(args.calibration, "calibration file")  # the outputs: checked by replay_bag first
    from strain_comp import api
    from strain_comp.core.fusion import check_every, fusion_note

    if args.references_every is not None:
        check_every(args.references_every)
    calibration = api.load_calibration(args.calibration)
    summary = api.replay(calibration, args.bag, args.out, inputs=[args.calibration],
                         tare=args.tare, csv=args.csv, tracking=args.baseline_tracking,
                         references_every=args.references_every)
    stream = results(args)
    print(f"replayed {summary.n_compensated} resistance messages of {len(summary.sensors)} "
          f"sensors into {args.out} ({summary.n_output_messages} messages written, "
          f"{summary.n_input_messages} of them input messages copied through)",
          file=stream)
    for name, health in summary.sensors.items():
        if health.n_bad or health.n_out_of_range or health.n_gaps:
            print(f"{name}: {health.n_bad} bad samples (estimate held), {health.n_out_of_range} "
                  f"out of range, {health.n_gaps} gap resets", file=stream)
            if health.n_out_of_range:
                note(args, f"{name}: {OUT_OF_RANGE_HINT}")
    for problem in summary.problems:
        note(args, problem)
    for name, state in summary.references.items():
        unit = calibration.sensors[name].strain_unit
        note(args, fusion_note(name, state, state["every"], unit))
    if args.csv not in (None, "-"):
        note(args, f"wrote {args.csv}")
    return 0
