#!/usr/bin/env python3
"""Replay's and evaluate's cost against the bag's duration: the same messages over a short
and a long run.

    python bench/bench_duration.py [--messages 100000] [--sensors 10] [--short 10]
                                   [--long 10000] [--repeat 3]

Two bags of ``--messages`` std_msgs/Float64 resistance messages over ``--sensors`` sensors
(APL calibration), evenly spread over ``--short`` and ``--long`` seconds, each with a
reference strain message on every stamp (for ``evaluate``); written into a temporary
directory. ``replay_bag`` and ``evaluate_bag`` run on each in a fresh process that reports
its wall time and peak RSS (``bench_replay_memory.py``'s child), ``--repeat`` times,
alternating the bags: the least time and the largest peak. Baseline in the same run:
the short bag. Goals: long / short within 1.5x in time and 1.2x in peak memory (the cost
linear in messages, not in duration; docs/reliability.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import R_HI, R_LO, calibration, resistance, row
from bench_replay_memory import COMMANDS, child

from strain_comp.core.calibration_file import save_calibration
from strain_comp.io.bag import BagWriter


def make_bag(path: Path, n: int, names: list[str], duration: float) -> None:
    """``n`` resistance messages over the sensors, spread over ``duration`` seconds, and a
    reference strain (a linear map of it) on each stamp."""
    per = n // len(names)
    t = np.linspace(0.0, duration, per)
    r = resistance(np.arange(per) * 1e-3, len(names), seed=1)  # the same values in both bags
    with BagWriter(path) as writer:
        for i, name in enumerate(names):
            writer.write_float64(f"/{name}/resistance", t, r[:, i])
            writer.write_float64(f"/{name}/strain_reference", t,
                                 50.0 * (r[:, i] - R_LO) / (R_HI - R_LO))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=100_000)
    parser.add_argument("--sensors", type=int, default=10)
    parser.add_argument("--short", type=float, default=10.0)
    parser.add_argument("--long", type=float, default=10_000.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    names = [f"s{i}" for i in range(args.sensors)]
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cal = d / "cal.yaml"
        save_calibration(calibration(names, ["apl"]), cal)
        result: dict[tuple[str, float], dict[str, float]] = {}
        for duration in (args.short, args.long):
            make_bag(d / f"in_{duration:g}.mcap", args.messages, names, duration)
        for _ in range(args.repeat):  # a shared machine's load moves: the least time
            for duration in (args.short, args.long):
                for c in COMMANDS:
                    run = child(c, d / f"in_{duration:g}.mcap", cal, d / "out.mcap")
                    best = result.setdefault((c, duration), run)
                    best["seconds"] = min(best["seconds"], run["seconds"])
                    best["rss_mb"] = max(best["rss_mb"], run["rss_mb"])
        for c in COMMANDS:
            short, long_ = result[c, args.short], result[c, args.long]
            ratio_t = long_["seconds"] / short["seconds"]
            ratio_m = long_["rss_mb"] / short["rss_mb"]
            goal = "goal met" if ratio_t <= 1.5 and ratio_m <= 1.2 else "goal missed"
            print(f"{c:>9} of {args.messages:,} messages on {args.sensors} sensors: "
                  f"over {args.short:g} s {short['seconds']:.2f} s, {short['rss_mb']:.0f} "
                  f"MB; over {args.long:g} s {long_['seconds']:.2f} s, "
                  f"{long_['rss_mb']:.0f} MB; long/short time {ratio_t:.2f}x, memory "
                  f"{ratio_m:.2f}x   {goal} (<= 1.5x, <= 1.2x)")
            row(f"{c} of {args.messages:,} messages over {args.long:g} s vs {args.short:g} s "
                "(`bench_duration.py`)",
                f"{long_['seconds']:.2f} s, {long_['rss_mb']:.0f} MB",
                f"{short['seconds']:.2f} s, {short['rss_mb']:.0f} MB",
                f"{ratio_t:.2f}x time, {ratio_m:.2f}x memory", memory_mb=long_["rss_mb"])


if __name__ == "__main__":
    main()
