#!/usr/bin/env python3
"""Replay cost against the bag's duration: the same messages over a short and a long run.

    python bench/bench_replay_duration.py [--messages 100000] [--short 10] [--long 10000]
                                          [--model cubic] [--repeat 3]

Two bags of ``--messages`` std_msgs/Float64 messages on ``/s0/resistance`` (one sensor),
evenly spread over ``--short`` and ``--long`` seconds (written into a temporary directory).
``replay_bag`` writes the same strain / direction / status / strain_stamped outputs for
both, plus one /diagnostics message per second of log time that holds input
(``diagnostics_period`` 1 s), so the long bag carries ``--long / --short`` times more
DiagnosticArray messages, and at 10 messages a second of the long bag every 1 s stretch of
baseline tracking holds enough samples to be judged.

Timed (best of ``--repeat``, kernels warm) with baseline tracking on (the default) and, as
the baseline in the same run, off: long / short ratio for each. Goal: long / short close
to 1 (cost linear in messages, not in duration); ``bench_duration.py`` measures the same
for ten sensors in fresh processes, with peak memory.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, calibration, resistance, row

from strain_comp.io.bag import BagWriter
from strain_comp.offline.replay import replay_bag

MODES = ("on", "off")
"""Baseline tracking: the default, then the baseline."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=100_000)
    parser.add_argument("--short", type=float, default=10.0)
    parser.add_argument("--long", type=float, default=10_000.0)
    parser.add_argument("--model", choices=("apl", "cubic"), default="cubic")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    cal = calibration(["s0"], [args.model])
    r = resistance(np.arange(args.messages) * 1e-3, 1, seed=1)[:, 0]
    times: dict[tuple[str, float], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for duration in (args.short, args.long):
            bag = Path(tmp) / f"in_{duration:g}.mcap"
            with BagWriter(bag) as writer:
                writer.write_float64("/s0/resistance",
                                     np.linspace(0.0, duration, args.messages), r)
            out = Path(tmp) / "out.mcap"
            replay_bag(bag, cal, out)  # warm-up: compile every kernel the replay uses
            for mode in MODES:
                times[mode, duration] = best_time(
                    lambda b=bag, o=out, m=mode: replay_bag(b, cal, o, tracking=m), args.repeat)
    n = args.messages
    print(f"replay of {n:,} Float64 messages ({args.model} calibration), over "
          f"{args.short:g} s ({int(args.short):,} /diagnostics) and {args.long:g} s "
          f"({int(args.long):,} /diagnostics); best of {args.repeat}; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"{'baseline tracking':<22}{'short s':>9}{'long s':>9}{'long/short':>12}")
    for mode in MODES:
        short, long_ = times[mode, args.short], times[mode, args.long]
        print(f"{mode:<22}{short:>9.3f}{long_:>9.3f}{long_ / short:>11.2f}x")
    on_s, on_l = times["on", args.short], times["on", args.long]
    off_s, off_l = times["off", args.short], times["off", args.long]
    row(f"replay of {n:,} messages of one sensor over {args.long:g} s vs over "
        f"{args.short:g} s (`bench_replay_duration.py`)",
        f"tracking on: {on_l:.2f} s vs {on_s:.2f} s",
        f"tracking off: {off_l:.2f} s vs {off_s:.2f} s",
        f"{on_l / on_s:.2f}x long/short on, {off_l / off_s:.2f}x off")


if __name__ == "__main__":
    main()
