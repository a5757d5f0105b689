#!/usr/bin/env python3
"""Bag I/O throughput: write and read 1e6 std_msgs/Float64 messages on 10 topics, with the
rosbags library's read + deserialize of the same file as the baseline in the same run.

    python bench/bench_bag.py [--messages 1000000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from strain_comp.io.bag import BagWriter, read_bag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=10**6)
    n = parser.parse_args().messages
    t = np.arange(n) * 1e-3
    r = np.random.default_rng(0).normal(100.0, 1.0, n)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.mcap"
        t0 = time.perf_counter()
        with BagWriter(path) as writer:
            for i in range(10):
                writer.write_float64(f"/s{i}/resistance", t[i::10], r[i::10])
        t1 = time.perf_counter()
        read_bag(path)  # first read includes numba compile/cache load
        t2 = time.perf_counter()
        contents = read_bag(path)
        t3 = time.perf_counter()
        assert sum(s.t.size for s in contents.series.values()) == n
        with AnyReader([path]) as reader:
            count = sum(1 for con, _, raw in reader.messages()
                        if reader.deserialize(raw, con.msgtype) is not None)
        t4 = time.perf_counter()
        size = path.stat().st_size / 1e6
    print(f"{n} Float64 messages, {size:.1f} MB")
    print(f"write           {t1 - t0:6.2f} s  {n / (t1 - t0) / 1e6:5.2f} M msg/s")
    print(f"read (first)    {t2 - t1:6.2f} s")
    print(f"read            {t3 - t2:6.2f} s  {n / (t3 - t2) / 1e6:5.2f} M msg/s")
    print(f"rosbags read    {t4 - t3:6.2f} s  {count / (t4 - t3) / 1e6:5.2f} M msg/s "
          f"(ratio {(t4 - t3) / (t3 - t2):.1f}x)")


if __name__ == "__main__":
    main()
