#!/usr/bin/env python3
"""Replay cost against the bag's duration: the same messages over a short and a long run.

    python bench/bench_replay_duration.py [--messages 100000] [--short 10] [--long 10000]
                                          [--model cubic] [--repeat 3]

Two bags of ``--messages`` std_msgs/Float64 messages on ``/s0/resistance``, evenly spread
over ``--short`` and ``--long`` seconds (written into a temporary directory). ``replay_bag``
writes the same strain / direction / status / strain_stamped outputs for both, plus one
/diagnostics message per second of log time that holds input (``diagnostics_period`` 1 s),
so the long bag carries ``--long / --short`` times more DiagnosticArray messages.

Timed (best of ``--repeat``, kernels warm), with the package's CDR encoder
(``strain_comp.io.cdr``) and, as the baseline in the same run, with the generic encoder
the writer used before (``mcap_ros2._dynamic.serialize_dynamic`` on the schema text, the
message built as nested dicts): long / short ratio for each, and old / new per bag.
Goal: long / short close to 1 (cost linear in messages, not in duration).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, calibration, resistance, row

from strain_comp.io import cdr
from strain_comp.io.bag import SCHEMAS, BagWriter
from strain_comp.offline.replay import replay_bag


def generic_diagnostic_array() -> Callable[..., bytes]:
    """``cdr.diagnostic_array``'s signature through mcap_ros2's generic encoder (the
    writer's former path; a private module, used here only as the baseline)."""
    from mcap_ros2._dynamic import serialize_dynamic

    kind = "diagnostic_msgs/msg/DiagnosticArray"
    encode = serialize_dynamic(kind, SCHEMAS[kind])[kind]

    def diagnostic_array(sec: int, nanosec: int, frame_id: str,
                         statuses: Sequence[tuple[str, int, str, str, Any]]) -> bytes:
        return encode({"header": {"stamp": {"sec": sec, "nanosec": nanosec},
                                  "frame_id": frame_id},
                       "status": [{"level": level, "name": name, "message": message,
                                   "hardware_id": hw,
                                   "values": [{"key": k, "value": v} for k, v in values]}
                                  for name, level, message, hw, values in statuses]})

    return diagnostic_array


@contextmanager
def encoder(fn: Callable[..., bytes]) -> Iterator[None]:
    """Make the writer encode DiagnosticArray messages with ``fn`` inside the block."""
    saved = cdr.diagnostic_array
    cdr.diagnostic_array = fn  # type: ignore[assignment]
    try:
        yield
    finally:
        cdr.diagnostic_array = saved  # type: ignore[assignment]


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
    old = generic_diagnostic_array()
    times: dict[tuple[str, float], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for duration in (args.short, args.long):
            bag = Path(tmp) / f"in_{duration:g}.mcap"
            with BagWriter(bag) as writer:
                writer.write_float64("/s0/resistance",
                                     np.linspace(0.0, duration, args.messages), r)
            out = Path(tmp) / "out.mcap"
            replay_bag(bag, cal, out)  # warm-up: compile every kernel the replay uses
            for name, fn in (("generic (mcap_ros2)", old), ("cdr.py", cdr.diagnostic_array)):
                with encoder(fn):
                    times[name, duration] = best_time(lambda b=bag, o=out: replay_bag(b, cal, o),
                                                      args.repeat)
    n = args.messages
    print(f"replay of {n:,} Float64 messages ({args.model} calibration), over "
          f"{args.short:g} s ({int(args.short):,} /diagnostics) and {args.long:g} s "
          f"({int(args.long):,} /diagnostics); best of {args.repeat}; "
          f"{os.cpu_count()} cores")
    print(f"{'DiagnosticArray encoder':<22}{'short s':>9}{'long s':>9}{'long/short':>12}")
    for name in ("generic (mcap_ros2)", "cdr.py"):
        short, long_ = times[name, args.short], times[name, args.long]
        print(f"{name:<22}{short:>9.3f}{long_:>9.3f}{long_ / short:>11.2f}x")
    new_l, old_l = times["cdr.py", args.long], times["generic (mcap_ros2)", args.long]
    new_s = times["cdr.py", args.short]
    per_diag = (new_l - new_s) / (int(args.long) - int(args.short)) * 1e6
    per_diag_old = (old_l - times["generic (mcap_ros2)", args.short]) / (
        int(args.long) - int(args.short)) * 1e6
    print(f"long bag, old / new encoder: {old_l / new_l:.1f}x; cost of one /diagnostics "
          f"message (long - short, per message): {per_diag:.0f} us new, {per_diag_old:.0f} us "
          "old")
    row(f"replay of {n:,} messages over {args.long:g} s vs over {args.short:g} s "
        "(`bench_replay_duration.py`)", f"{new_l:.2f} s vs {new_s:.2f} s",
        f"generic encoder: {old_l:.2f} s vs {times['generic (mcap_ros2)', args.short]:.2f} s",
        f"{new_l / new_s:.2f}x long/short ({old_l / new_l:.1f}x faster than generic)")


if __name__ == "__main__":
    main()
