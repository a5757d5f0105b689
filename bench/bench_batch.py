#!/usr/bin/env python3
"""``strain-comp evaluate`` over a folder of bags: one process against ``--jobs N``.

    python bench/bench_batch.py [--bags 6] [--duration 2000] [--jobs 2]

Writes ``--bags`` rig recordings (the ``rates`` scenario, ``--duration`` s each at 25 Hz,
different seeds) into a temporary folder and times the whole command, as a user runs it,
in a fresh ``python`` process: ``evaluate FOLDER --calibration config/demo_calibration.yaml``
(an APL calibration) with ``--jobs 1`` (the baseline, same run) and with ``--jobs N``. The
pool's processes are spawned and import strain_comp afresh, which costs about a second
each; the ratio is what is left of N after that and after what other work the machine
carries. The outputs of both runs are compared (the same JSON). Memory: the largest
child process's peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import row

REPO = Path(__file__).resolve().parent.parent


def timed(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "strain_comp.cli", *argv], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bags", type=int, default=6)
    parser.add_argument("--duration", type=float, default=2000.0)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    cal = str(REPO / "config" / "demo_calibration.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "study"
        folder.mkdir()
        for k in range(args.bags):
            subprocess.run([sys.executable, "-m", "strain_comp.cli", "simulate", "--scenario",
                            "rates", "--seed", str(k + 1), "--duration", str(args.duration),
                            "--out", str(folder / f"run{k:02d}.mcap"), "-q"], check=True)
        timed(["evaluate", str(folder / "run00.mcap"), "--calibration", cal, "-q"])  # warm
        serial = timed(["evaluate", str(folder), "--calibration", cal, "--jobs", "1",
                        "--json", str(Path(tmp) / "1.json"), "-q"])
        pooled = timed(["evaluate", str(folder), "--calibration", cal, "--jobs",
                        str(args.jobs), "--json", str(Path(tmp) / "n.json"), "-q"])
        same = json.loads((Path(tmp) / "1.json").read_text()) == json.loads(
            (Path(tmp) / "n.json").read_text())
    samples = int(args.duration * 25) * args.bags
    print(f"{args.bags} bags x {args.duration:g} s at 25 Hz ({samples} samples), "
          f"{os.cpu_count()} cores: --jobs 1 {serial:.2f} s, --jobs {args.jobs} "
          f"{pooled:.2f} s, same JSON: {same}")
    row(f"`evaluate FOLDER --jobs {args.jobs}`, {args.bags} bags of {samples // args.bags} "
        f"APL samples (`bench_batch.py`)", f"{pooled:.2f} s",
        f"`--jobs 1`, same run: {serial:.2f} s", f"{serial / pooled:.2f}x",
        memory_mb=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)


if __name__ == "__main__":
    main()
