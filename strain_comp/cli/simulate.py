"""``strain-comp simulate``: a bag recorded on the virtual test rig (docs/design.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import note, output
from strain_comp.errors import InputError

NAME = "simulate"
SUMMARY = "make a bag on the virtual test rig"
DESCRIPTION = ("Record a scenario on the virtual test rig (a simulated tensile tester with a "
               "soft sensor): /NAME/resistance and /NAME/strain_reference in an MCAP bag.")
EXAMPLE = "strain-comp simulate --scenario rates --out rates.mcap --seed 2 --effect drift=0.05"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The scenario, the bag to write, the seed, the rig's effects."""
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


def run(args: argparse.Namespace) -> int:
    """The scenario list, or the scenario simulated and written as a bag."""
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
    effects = rig.RigEffects.parse(args.effect) if args.effect else None
    output(args.out, [])
    recorded = rig.simulate(args.scenario, seed=args.seed, effects=effects,
                            duration=args.duration)
    rig.write_sim_bag(recorded, args.out)
    note(args, f"wrote {args.out} (scenario {args.scenario}, seed {args.seed})")
    return 0
