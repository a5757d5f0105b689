#!/usr/bin/env python3
"""Replay's peak resident memory and time against bag length (streaming: RSS flat).

    python bench/bench_replay_memory.py [--messages 100000,1000000,10000000] [--sensors 10]

For each size a bag of Float64 ``/sI/resistance`` messages at 1 kHz per sensor is written
in /tmp (streamed: ``BagWriter.flush`` every block), then ``replay_bag`` runs in a fresh
process that reports its own peak RSS (``ru_maxrss``) and wall time. Baseline in the same
run: the peak RSS of a fresh process that only imports the package and compiles the
kernels (replay of a 1 000-message bag), so the table shows what the bag's length adds.
Bags are deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import calibration, resistance, row

from strain_comp.core.calibration import save_calibration
from strain_comp.io.bag import BagWriter

CHILD = """
import json, resource, sys, time
from strain_comp.core.calibration import load_calibration
from strain_comp.offline.replay import replay_bag
cal = load_calibration(sys.argv[2])
start = time.perf_counter()
summary = replay_bag(sys.argv[1], cal, sys.argv[3])
print(json.dumps({"seconds": time.perf_counter() - start,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "n_in": summary.n_input_messages, "n_out": summary.n_output_messages}))
"""


def make_bag(path: Path, n: int, names: list[str], block: int = 100_000) -> None:
    """``n`` messages over the sensors, written block by block (bounded memory)."""
    per = n // len(names)
    with BagWriter(path) as writer:
        for a in range(0, per, block // len(names)):
            b = min(a + block // len(names), per)
            t = np.arange(a, b) * 1e-3
            r = resistance(t, len(names), seed=1)
            for i, name in enumerate(names):
                writer.write_float64(f"/{name}/resistance", t, r[:, i])
            writer.flush(before=b * 1e-3)


def child(bag: Path, cal: Path, out: Path) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-c", CHILD, str(bag), str(cal), str(out)],
                          check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", default="100000,1000000,10000000")
    parser.add_argument("--sensors", type=int, default=10)
    args = parser.parse_args()
    names = [f"s{i}" for i in range(args.sensors)]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cal = d / "cal.yaml"
        save_calibration(calibration(names, ["apl"]), cal)
        make_bag(d / "small.mcap", 1000, names)
        base = child(d / "small.mcap", cal, d / "out.mcap")
        print(f"baseline (1,000 messages: import + compile): peak RSS {base['rss_mb']:.0f} MB")
        print(f"{'messages':>12}{'bag MB':>9}{'seconds':>9}{'us/msg':>8}{'peak RSS MB':>13}"
              f"{'vs baseline':>13}")
        for n in (int(x) for x in args.messages.split(",")):
            bag = d / f"in_{n}.mcap"
            make_bag(bag, n, names)
            res = child(bag, cal, d / "out.mcap")
            print(f"{n:>12,}{bag.stat().st_size / 1e6:>9.1f}{res['seconds']:>9.2f}"
                  f"{1e6 * res['seconds'] / n:>8.2f}{res['rss_mb']:>13.0f}"
                  f"{res['rss_mb'] / base['rss_mb']:>12.2f}x", flush=True)
            row(f"streaming replay, {n:,} messages on {args.sensors} sensors "
                f"(`bench_replay_memory.py`)",
                f"{res['seconds']:.1f} s, {1e6 * res['seconds'] / n:.1f} us/msg",
                f"import + compile only (1,000 msgs): {base['rss_mb']:.0f} MB peak",
                f"{res['rss_mb'] / base['rss_mb']:.2f}x the baseline's memory",
                memory_mb=res["rss_mb"])
            bag.unlink()


if __name__ == "__main__":
    main()
