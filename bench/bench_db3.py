#!/usr/bin/env python3
"""Reading rosbag2's sqlite3 storage (.db3) against the same messages in MCAP.

    python bench/bench_db3.py [--seconds 4000]

A virtual-rig rate sweep of SECONDS at 50 Hz (resistance and reference: 2 messages per
sample) is written as MCAP (``strain-comp simulate``) and copied message by message into a
rosbag2 sqlite3 bag by rosbags (``test/io/test_db3.py``'s writer). Timed, best of 3: the whole
read (``read_bag``) and ``evaluate`` of each, and their ratio db3 / MCAP. The .db3 path
reads every row by its own sqlite query (apsw) and packs it as an MCAP record; MCAP is
decoded in bulk.
Timings vary by machine and load; state the machine with the figures.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "test" / "io"))

from test_db3 import write_db3  # noqa: E402

from strain_comp import api  # noqa: E402
from strain_comp.io.bag import read_bag  # noqa: E402
from strain_comp.offline import rig  # noqa: E402


def best_of(run: Callable[[Path], object], bag: Path, n: int = 3) -> float:
    """The shortest of ``n`` runs of ``run(bag)`` [s]."""
    times = []
    for _ in range(n):
        start = time.perf_counter()
        run(bag)
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=4000.0)
    args = parser.parse_args()
    cal = api.load_calibration(ROOT / "config" / "demo_calibration.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        mcap = Path(tmp) / "rates.mcap"
        rig.write_sim_bag(rig.simulate("rates", seed=1, duration=args.seconds), mcap)
        db3 = write_db3(mcap, Path(tmp) / "rates")
        n = sum(s.t.size for s in read_bag(mcap).series.values())
        print(f"{n} messages ({args.seconds:g} s at 50 Hz)")
        for what, run in (("read_bag", read_bag), ("evaluate", lambda b: api.evaluate(cal, b))):
            t_mcap = best_of(run, mcap)
            t_db3 = best_of(run, db3)
            print(f"{what:<9} MCAP {t_mcap:7.3f} s   .db3 {t_db3:7.3f} s   ratio "
                  f"{t_db3 / t_mcap:5.1f}   ({1e6 * t_db3 / n:.2f} us per .db3 message)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
