#!/usr/bin/env python3
"""Replay's and evaluate's peak resident memory and time against bag length (both stream:
RSS flat, time linear in messages).

    python bench/bench_replay_memory.py [--messages 100000,1000000,10000000] [--sensors 10]

For each size a bag of that many Float64 messages is written in /tmp (streamed:
``BagWriter.flush`` every block): half ``/sI/resistance`` at 1 kHz per sensor, half
``/sI/strain_reference`` on the same stamps, as a rig records them. Then ``replay_bag`` and
``evaluate_bag`` (the ``evaluate`` command minus printing) each run on it in a fresh
process that reports its own peak RSS (``ru_maxrss``) and wall time. Baselines in the same
run: the peak RSS of a fresh process doing the same on a 1 000-message bag (import and
kernel compilation), so the table shows what the bag's length adds; for time, each size's
time against the previous size's (10x the messages: about 10x the time when linear), and
within one run the time per message over the second half of the bag's pieces against the
first half's (1x when linear; the first piece carries the kernels' compilation or cache
load, so it favours the second half).
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
from _common import R_HI, R_LO, calibration, resistance, row

from strain_comp.core.calibration_file import save_calibration
from strain_comp.io.bag import BagWriter

CHILD = """
import json, resource, sys, time
import numpy as np
import strain_comp.offline.evaluate, strain_comp.offline.replay
from strain_comp.core.calibration_file import load_calibration
from strain_comp.io.bag import iter_bag
done, sizes = [], []
def timed(*args, **kwargs):  # when each piece has been read and processed
    for piece in iter_bag(*args, **kwargs):
        sizes.append(sum(s.t.size for s in piece.series.values()))
        yield piece
        done.append(time.perf_counter())
strain_comp.offline.evaluate.iter_bag = strain_comp.offline.replay.iter_bag = timed
cal = load_calibration(sys.argv[3])
start = time.perf_counter()
if sys.argv[1] == "replay":
    strain_comp.offline.replay.replay_bag(sys.argv[2], cal, sys.argv[4])
else:
    result, _ = strain_comp.offline.evaluate.evaluate_bag(sys.argv[2], cal)
    assert all(ev.stats.n > 0 for ev in result.sensors.values())
seconds = time.perf_counter() - start
# time per message in the second half of the bag's pieces against the first half's
cost = np.diff(np.array([start] + done[:len(sizes)]))
half = len(cost) // 2
halves = (cost[half:].sum() / max(sum(sizes[half:]), 1)) / \
    (cost[:half].sum() / max(sum(sizes[:half]), 1)) if half else float("nan")
print(json.dumps({"seconds": seconds, "pieces": len(sizes), "halves": halves,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""
COMMANDS = ("replay", "evaluate")


def make_bag(path: Path, n: int, names: list[str], block: int = 100_000) -> None:
    """``n`` messages over the sensors, half resistance and half reference strain (a
    linear map of it), written block by block (bounded memory)."""
    per = n // (2 * len(names))
    step = block // (2 * len(names))
    with BagWriter(path) as writer:
        for a in range(0, per, step):
            b = min(a + step, per)
            t = np.arange(a, b) * 1e-3
            r = resistance(t, len(names), seed=1)
            for i, name in enumerate(names):
                writer.write_float64(f"/{name}/resistance", t, r[:, i])
                writer.write_float64(f"/{name}/strain_reference", t,
                                     50.0 * (r[:, i] - R_LO) / (R_HI - R_LO))
            writer.flush(before=b * 1e-3)


def child(command: str, bag: Path, cal: Path, out: Path) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-c", CHILD, command, str(bag), str(cal),
                           str(out)], check=True, capture_output=True, text=True)
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
        base = {c: child(c, d / "small.mcap", cal, d / "out.mcap") for c in COMMANDS}
        for c in COMMANDS:
            print(f"{c} baseline (1,000 messages: import + compile): peak RSS "
                  f"{base[c]['rss_mb']:.0f} MB")
        print(f"{'command':>9}{'messages':>12}{'bag MB':>9}{'seconds':>9}{'us/msg':>8}"
              f"{'peak RSS MB':>13}{'vs baseline':>13}{'time vs previous':>18}")
        previous: dict[str, tuple[int, float]] = {}
        for n in (int(x) for x in args.messages.split(",")):
            bag = d / f"in_{n}.mcap"
            make_bag(bag, n, names)
            for c in COMMANDS:
                res = child(c, bag, cal, d / "out.mcap")
                memory = res["rss_mb"] / base[c]["rss_mb"]
                parts = []
                if res["pieces"] >= 4:
                    parts.append(f"second half {res['halves']:.2f}x the first's time per "
                                 "message")
                if c in previous:
                    m, seconds = previous[c]
                    parts.append(f"{res['seconds'] / seconds:.1f}x the time for {n / m:.0f}x "
                                 "the messages")
                growth = "; ".join(parts)
                previous[c] = (n, res["seconds"])
                print(f"{c:>9}{n:>12,}{bag.stat().st_size / 1e6:>9.1f}{res['seconds']:>9.2f}"
                      f"{1e6 * res['seconds'] / n:>8.2f}{res['rss_mb']:>13.0f}"
                      f"{memory:>12.2f}x  {growth}", flush=True)
                row(f"streaming {c}, {n:,} messages on {args.sensors} sensors, half of them "
                    f"references (`bench_replay_memory.py`)",
                    f"{res['seconds']:.2f} s, {1e6 * res['seconds'] / n:.2f} us/msg",
                    f"{c} of 1,000 msgs (import + compile): {base[c]['rss_mb']:.0f} MB peak",
                    f"{memory:.2f}x the baseline's memory"
                    + (f"; {growth}" if growth else ""), memory_mb=res["rss_mb"])
            bag.unlink()


if __name__ == "__main__":
    main()
