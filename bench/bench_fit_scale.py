#!/usr/bin/env python3
"""`strain-comp fit` on long runs: time and peak memory, and the fit error on the full data.

    python bench/bench_fit_scale.py [--samples 10000000] [--model apl] [--small 100000]

Training data: the virtual rig's ``rates`` scenario (0-20 % triangles at five speeds,
``strain_comp.offline.rig``) at 25 Hz, linearly resampled to a fast logger's rate and given
white read-out noise (0.2 % of the resistance's standard deviation): the physics of the rig,
sampled like a 1-2.5 kHz DAQ. Written as a bag (``/s1/resistance`` + ``/s1/strain_reference``)
into a temporary directory; each fit runs as ``strain-comp fit`` in a fresh process
(peak RSS: the child's own ``VmHWM``, Linux).

Rows, each ``fit_sensor`` (the code of ``strain-comp fit``, bag read included) in a fresh
process: ``--small`` samples with a budget that forces the reduction by the factor the
default budget gives ``--samples``; the same ``--small`` samples fitted on every sample
(the baseline both sizes can afford); then ``--samples`` with the default budget
(``strain_comp.offline.reduce``). Each prints the fit error ``fit_rmse`` (the engine over
the FULL training data), the reduction factor, the fit and wall time and the peak RSS.
Then ``strain-comp diagnose`` (``api.diagnose``) on both bags with a ``--diagnose-model``
calibration fitted on the small one: time, peak RSS, held-out RMSE before and after and
the terms added (``--only fit|diagnose`` runs one part).
Goal: 1e7 samples in <= 2 GB and minutes, with a full-data
error close to the unreduced fit's on the size both can handle.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import row

from strain_comp.io.bag import BagWriter
from strain_comp.offline import rig
from strain_comp.offline.reduce import FIT_SAMPLE_BUDGET

FIT_ONE = """
import json, sys, time
from strain_comp.io.recording import load_recordings
from strain_comp.offline.fit import fit_sensor
bag, model, budget = sys.argv[1], sys.argv[2], int(sys.argv[3])
start = time.perf_counter()
rec = load_recordings(bag)[0]["s1"]
cal = fit_sensor([rec], model, name="s1", bags=[bag], options={"fit_budget": budget})
seconds = time.perf_counter() - start
with open("/proc/self/status") as status:  # VmHWM: this process's peak since exec
    peak = next(int(ln.split()[1]) for ln in status if ln.startswith("VmHWM")) / 1024
print(json.dumps({"seconds": seconds, "peak_mb": peak, **cal.provenance}))
"""

DIAGNOSE_ONE = """
import json, sys, time
from strain_comp.core.calibration import Calibration
from strain_comp.api import diagnose
from strain_comp.io.recording import load_recordings
from strain_comp.offline.fit import fit_sensor
small, bag, model = sys.argv[1], sys.argv[2], sys.argv[3]
cal = Calibration({"s1": fit_sensor([load_recordings(small)[0]["s1"]], model, name="s1")})
start = time.perf_counter()
result = diagnose(cal, bag).result
seconds = time.perf_counter() - start
with open("/proc/self/status") as status:
    peak = next(int(ln.split()[1]) for ln in status if ln.startswith("VmHWM")) / 1024
print(json.dumps({"seconds": seconds, "peak_mb": peak, "before": result.before["rmse"],
                  "after": result.after["rmse"], "added": [a.name for a in result.added],
                  "message": result.sensors["s1"].message}))
"""


def make_bag(path: Path, n: int) -> None:
    """``n`` samples of the rig's ``rates`` run, resampled (module docstring)."""
    base = 25.0
    up = max(1, round(n / (1000 * base)))  # about 1000 s of motion, resampled to n
    run = rig.simulate("rates", seed=0, duration=n / (up * base) + 1.0)
    s1 = run["s1"]
    t = np.arange(n) / (up * base)
    rng = np.random.default_rng(1)
    r = np.interp(t, s1.t, s1.r)
    r += 0.002 * float(np.std(s1.r)) * rng.standard_normal(n)
    s = np.interp(t, s1.t, s1.s)
    with BagWriter(path) as writer:
        writer.write_float64("/s1/resistance", t, r)
        writer.write_float64("/s1/strain_reference", t, s)


def child(args: list[str]) -> tuple[dict[str, object], float]:
    """Run ``args`` in a fresh process: its last stdout line as JSON, wall time [s]."""
    start = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    return json.loads([ln for ln in done.stdout.splitlines() if ln.startswith("{")][-1]), wall


def fits(args: argparse.Namespace, small: Path, large: Path) -> None:
    """The three fit rows (module docstring) and the goal line."""
    factor = max(2, math.ceil(args.samples / FIT_SAMPLE_BUDGET))
    runs = []
    for label, bag, budget in (
            (f"{args.small:,}, reduced by {factor} (budget forced)", small,
             args.small // factor),
            (f"{args.small:,}, every sample", small, 10**12),
            (f"{args.samples:,}, default budget", large, FIT_SAMPLE_BUDGET)):
        info, wall = child([sys.executable, "-c", FIT_ONE, str(bag), args.model,
                            str(budget)])
        runs.append((label, info, wall, float(info["peak_mb"])))
    print(f"{'fit (' + args.model + ')':<40}{'fit_rmse %':>11}{'factor':>8}{'fit s':>8}"
          f"{'wall s':>8}{'peak MB':>9}")
    for label, info, wall, peak in runs:
        red = info.get("fit_reduction") or {"factor": 1}
        assert isinstance(red, dict)
        print(f"{label:<40}{float(info['fit_rmse']):>11.4f}{red['factor']:>8}"
              f"{float(info['fit_seconds']):>8.1f}{wall:>8.1f}{peak:>9.0f}")
    (_, reduced, _, _), (_, full, _, _), (_, big, wall, peak) = runs
    print(f"full-data error, reduced / unreduced fit at {args.small:,}: "
          f"{float(reduced['fit_rmse']) / float(full['fit_rmse']):.3f}")
    row(f"`fit` {args.model} on {args.samples:,} samples (`bench_fit_scale.py`)",
        f"{wall:.0f} s, fit_rmse {float(big['fit_rmse']):.3f} % on all samples",
        f"{args.small:,} samples unreduced: fit_rmse {float(full['fit_rmse']):.3f} %",
        f"{float(reduced['fit_rmse']) / float(full['fit_rmse']):.3f} error ratio reduced/"
        f"full at {args.small:,}", memory_mb=peak)


def diagnoses(args: argparse.Namespace, small: Path, large: Path) -> None:
    """``api.diagnose`` on both bags (calibration fitted on the small one)."""
    print(f"diagnose (calibration: {args.diagnose_model} fitted on the {args.small:,}-sample "
          "bag; s = api.diagnose alone, peak = the whole process):")
    print(f"{'bag':<14}{'s':>8}{'peak MB':>9}  held-out RMSE before -> after, added")
    for label, bag in ((f"{args.small:,}", small), (f"{args.samples:,}", large)):
        d, _ = child([sys.executable, "-c", DIAGNOSE_ONE, str(small), str(bag),
                      args.diagnose_model])
        print(f"{label:<14}{float(d['seconds']):>8.1f}{float(d['peak_mb']):>9.0f}  "
              f"{float(d['before']):.4f} -> {float(d['after']):.4f} %, {d['added']}")
        if bag is large:
            print(f"  {d['message']}")
            row(f"`diagnose` on {args.samples:,} samples (`bench_fit_scale.py`)",
                f"{float(d['seconds']):.0f} s", "-", "-", memory_mb=float(d["peak_mb"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000_000)
    parser.add_argument("--small", type=int, default=100_000)
    parser.add_argument("--model", default="apl")
    parser.add_argument("--diagnose-model", default="cubic")
    parser.add_argument("--only", choices=("fit", "diagnose"), default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        small, large = Path(tmp) / "small.mcap", Path(tmp) / "large.mcap"
        start = time.perf_counter()
        make_bag(small, args.small)
        make_bag(large, args.samples)
        print(f"bags: {args.small:,} and {args.samples:,} samples "
              f"({large.stat().st_size / 1e6:.0f} MB), made in "
              f"{time.perf_counter() - start:.0f} s; {os.cpu_count()} cores; "
              f"budget {FIT_SAMPLE_BUDGET:,} samples")
        if args.only in (None, "fit"):
            fits(args, small, large)
        if args.only in (None, "diagnose"):
            diagnoses(args, small, large)


if __name__ == "__main__":
    main()
