#!/usr/bin/env python3
"""Bag replay throughput against the ``rosbags`` library's read + deserialize of the same bag.

    python bench/bench_replay.py [--messages 1000000] [--sensors 10] [--model apl] [--cache DIR]

The bag: ``--messages`` std_msgs/Float64 resistance messages spread over ``--sensors``
topics ``/sI/resistance`` at 1 kHz each (``strain_comp.io.bag.BagWriter``), with a matching
calibration (``bench/_common.py``: the paper's APL parameters per sensor, perturbed, or the
cubic). A second bag adds ``/sI/strain_reference`` for ``evaluate``. Both are generated
once and cached (default: ``$TMPDIR/strain_comp_bench``; ``--cache`` to choose).

Timed (best of ``--repeat``, kernels and caches warm):

* baseline: ``rosbags.highlevel.AnyReader`` reading and deserializing every message;
* ``strain_comp.io.bag.read_bag`` alone;
* ``strain_comp.offline.replay.replay_bag``: read + compensate (engine batch path) + write;
* ``strain-comp evaluate`` minus printing: ``evaluate_bag`` (streamed: read + compensate +
  score) on the bag with the reference (baseline: rosbags on that bag).

Goal: full replay faster than the rosbags read alone (ratio > 1).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, calibration, resistance, row

from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.offline.evaluate import evaluate_bag
from strain_comp.offline.replay import replay_bag


def make_bags(cache: Path, n: int, k: int, model: str) -> tuple[Path, Path, Path]:
    """(resistance bag, bag with reference, calibration file), generated once."""
    tag = f"{n}_{k}_{model}"
    bag, ref_bag, cal_path = (cache / f"replay_{tag}.mcap", cache / f"replay_ref_{tag}.mcap",
                              cache / f"replay_{tag}.yaml")
    if bag.exists() and ref_bag.exists() and cal_path.exists():
        return bag, ref_bag, cal_path
    cache.mkdir(parents=True, exist_ok=True)
    names = [f"s{i}" for i in range(k)]
    cal = calibration(names, [model])
    per = n // k
    t = np.arange(per) * 1e-3
    r = resistance(t, k, seed=1)
    # a stand-in reference: strain linear in R over the valid range (what matters here is
    # the message count, not the error figures)
    s = 50.0 * (r - cal.sensors[names[0]].valid_range.r_lo) / (
        cal.sensors[names[0]].valid_range.r_hi - cal.sensors[names[0]].valid_range.r_lo)
    for path, with_ref in ((bag, False), (ref_bag, True)):
        tmp = path.with_suffix(".tmp")
        with BagWriter(tmp) as writer:
            for i, name in enumerate(names):
                writer.write_float64(f"/{name}/resistance", t, r[:, i])
                if with_ref:
                    writer.write_float64(f"/{name}/strain_reference", t, s[:, i])
        tmp.replace(path)
    save_calibration(cal, cal_path)
    return bag, ref_bag, cal_path


def rosbags_read(path: Path) -> int:
    """Read and deserialize every message with rosbags; the number of messages."""
    count = 0
    with AnyReader([path]) as reader:
        for connection, _, raw in reader.messages(connections=reader.connections):
            reader.deserialize(raw, connection.msgtype)
            count += 1
    return count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=1_000_000)
    parser.add_argument("--sensors", type=int, default=10)
    parser.add_argument("--model", choices=("apl", "cubic"), default="apl")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cache", type=Path,
                        default=Path(tempfile.gettempdir()) / "strain_comp_bench")
    args = parser.parse_args()
    start = time.perf_counter()
    bag, ref_bag, cal_path = make_bags(args.cache, args.messages, args.sensors, args.model)
    made = time.perf_counter() - start
    cal = load_calibration(cal_path)
    n = sum(s.t.size for s in read_bag(bag).series.values())  # also compiles / warms up
    n_ref = sum(s.t.size for s in read_bag(ref_bag).series.values())
    print(f"bag: {n:,} Float64 resistance messages on {args.sensors} topics, "
          f"{bag.stat().st_size / 1e6:.1f} MB ({bag}); calibration: {args.model} "
          f"(bags ready in {made:.1f} s)")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.mcap"
        replay_bag(bag, cal, out)  # warm-up: compile every kernel the replay uses
        counted: dict[str, int] = {}

        def rb(path: Path = bag) -> None:
            counted[str(path)] = rosbags_read(path)

        t_rosbags = best_time(rb, args.repeat)
        t_read = best_time(lambda: read_bag(bag), args.repeat)
        t_replay = best_time(lambda: replay_bag(bag, cal, out), args.repeat)
        n_out = sum(s.t.size for s in read_bag(out).series.values())
        t_rosbags_ref = best_time(lambda: rb(ref_bag), args.repeat)

        def evaluate() -> None:
            evaluate_bag(ref_bag, cal)

        t_eval = best_time(evaluate, args.repeat)
    assert counted[str(bag)] == n and counted[str(ref_bag)] == n_ref
    rows = [
        ("rosbags read + deserialize (baseline)", t_rosbags, n, t_rosbags),
        ("strain_comp read_bag", t_read, n, t_rosbags),
        ("strain_comp replay (read+compensate+write)", t_replay, n, t_rosbags),
        (f"rosbags read + deserialize, bag with reference ({n_ref:,} msgs)", t_rosbags_ref,
         n_ref, t_rosbags_ref),
        ("strain_comp evaluate (streamed read + compensate + score), same bag", t_eval,
         n_ref, t_rosbags_ref),
    ]
    print(f"replay wrote {n_out:,} numeric output messages (strain, direction, status + "
          f"copied inputs); best of {args.repeat}, {os.cpu_count()} cores")
    print(f"{'what':<66}{'seconds':>9}{'msg/s':>14}{'vs rosbags':>12}")
    for what, sec, count, base in rows:
        print(f"{what:<66}{sec:>9.3f}{count / sec:>14,.0f}{base / sec:>11.1f}x")
        if "baseline" not in what and "rosbags" not in what:
            row(f"{what}, {count:,} Float64 messages, {args.sensors} sensors "
                f"(`bench_replay.py`)", f"{sec:.2f} s, {count / sec / 1e3:.0f} k msg/s",
                f"`rosbags` read + deserialise: {base:.2f} s", f"{base / sec:.1f}x")
    verdict = "holds" if t_replay < t_rosbags else "does NOT hold"
    print(f"goal 'full replay faster than rosbags read alone': {verdict} "
          f"(ratio {t_rosbags / t_replay:.1f}x)")


if __name__ == "__main__":
    main()
