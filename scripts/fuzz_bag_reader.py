#!/usr/bin/env python3
"""Fuzz the MCAP bag reader for a bounded time: any exception other than BagError is a bug.

Random mutations (byte flips, overwrites with 0x00/0xff, truncation, duplicated or deleted
spans) of small valid bags written by strain_comp.io.bag.BagWriter (every message type, a few
chunk sizes). A crashing input is saved under --out for a regression test.

    python scripts/fuzz_bag_reader.py --seconds 60 [--seed 0] [--out /tmp/bag_fuzz]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from strain_comp.errors import BagError
from strain_comp.io.bag import BagWriter, read_bag


def _seeds(directory: Path) -> list[bytes]:
    t = np.arange(400) * 0.01
    out = []
    for chunk_size in (500, 4000, 1 << 20):
        path = directory / f"seed_{chunk_size}.mcap"
        with BagWriter(path, chunk_size=chunk_size) as w:
            w.write_float64("/s1/resistance", t, 10 + np.sin(t))
            w.write_int8("/s1/direction", t, np.sign(np.cos(t)))
            w.write_float64_array("/a/resistance", t, np.c_[t, t], ["p", "q"])
            w.write_temperature("/s1/temperature", t[::50], 20 + t[::50])
            w.write_diagnostics(t[:3], [[("s1", 0, "ok", {"k": "v"})]] * 3)
        out.append(path.read_bytes())
    return out


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 6))):
        op = int(rng.integers(0, 5))
        i = int(rng.integers(0, len(buf)))
        if op == 0:
            buf[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            buf[i:i + 8] = bytes([int(rng.choice([0, 255]))]) * len(buf[i:i + 8])
        elif op == 2:
            del buf[i:]
        elif op == 3:
            j = int(rng.integers(i, min(len(buf), i + 64) + 1))
            buf[i:i] = buf[i:j]
        else:
            del buf[i:i + int(rng.integers(1, 64))]
        if len(buf) < 2:
            break
    return bytes(buf)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "bag_fuzz")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        seeds = _seeds(Path(tmp))
        target = Path(tmp) / "input.mcap"
        deadline = time.monotonic() + args.seconds
        runs = crashes = bag_errors = 0
        while time.monotonic() < deadline:
            data = _mutate(seeds[int(rng.integers(0, len(seeds)))], rng)
            target.write_bytes(data)
            runs += 1
            try:
                read_bag(target)
            except BagError:
                bag_errors += 1
            except Exception:  # this is what the fuzzer looks for
                crashes += 1
                saved = args.out / f"crash_{crashes}.mcap"
                saved.write_bytes(data)
                print(f"CRASH saved to {saved}:\n{traceback.format_exc()}")
    print(f"{runs} inputs, {bag_errors} BagError, {crashes} crashes")
    return 1 if crashes else 0


if __name__ == "__main__":
    raise SystemExit(main())
