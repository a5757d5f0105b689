#!/usr/bin/env python3
"""Engine / node start-up time including numba compilation, cold and warm kernel cache.

    python bench/bench_startup.py [--warm-runs 3] [--no-node]

1. Engine start-up, in a fresh ``python`` subprocess: import ``strain_comp``'s engine,
   load a calibration file (one APL sensor, one cubic sensor and a 16-sensor APL array,
   ``bench/_common.py``), build ``Engine``, ``warm_up()`` (compiles every kernel, as the
   node does at start-up) and the first ``step`` / ``step_array``. The
   child reports each phase; the total is the wall time from spawn to exit.
2. Node start-up: ``bin/compensator --ros-args --params-file config/array_params.yaml``
   (the rclpy node, bundled 6-sensor APL array, discovery on this machine) until it logs
   its ``ready:`` line.
   ``--colcon``: instead, the first and second start of a fresh ``colcon build`` of the
   package (colcon beside this Python, as test/ros/test_node_process.py builds it; the
   install's own numba cache) to ``ready:`` with ``config/compensator_params.yaml``, built
   as shipped (the cache primed by setup.py) and with ``STRAIN_COMP_NO_PRIME=1``.
3. Command-line start-up: ``python -m strain_comp.cli --version`` and ``--help`` (the
   parser assembled from every command's module, no command's machinery imported), median
   of ``--cli-runs`` spawns; baseline in the same run: ``python -c pass``.

Cold: ``NUMBA_CACHE_DIR`` is a new, empty directory (every kernel compiled). Warm: the
same directory again (kernels loaded from the cache). Baseline in the same run: the
interpreter with numpy imported (``python -c "import numpy"``). Ratios: cold / warm.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import calibration

from strain_comp.core.calibration_file import save_calibration

REPO = Path(__file__).resolve().parent.parent

CHILD = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
import strain_comp.models  # the model families register
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
t1 = time.perf_counter()
cal = load_calibration(sys.argv[1])
arr = [n for n in cal.sensors if n.startswith("a")]
engine = Engine(cal, arrays={"arr": arr})
t2 = time.perf_counter()
engine.warm_up()
t3 = time.perf_counter()
engine.step("s_apl", 0.0, 20.0)
engine.step("s_cubic", 0.0, 20.0)
engine.step_array("arr", 0.0, np.full(len(arr), 20.0))
t4 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "build": t2 - t1, "warm_up": t3 - t2, "first": t4 - t3}))
"""


def engine_start(cal_path: Path, cache: Path) -> tuple[float, dict[str, float]]:
    """(wall s from spawn to exit, the child's phase times)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILD, str(cal_path)], env=env, check=True,
                         capture_output=True, text=True, timeout=600)
    return time.perf_counter() - start, json.loads(out.stdout.strip().splitlines()[-1])


def node_start(cache: Path) -> float:
    """Wall s from spawn until the node logs its ``ready:`` line."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(REPO),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": str(100 + os.getpid() % 50), "PYTHONUNBUFFERED": "1"}
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, str(REPO / "bin" / "compensator"), "--ros-args",
                             "--params-file", str(REPO / "config" / "array_params.yaml")],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = ""
        while "ready:" not in line and proc.poll() is None:
            line = proc.stdout.readline()
        ready = time.perf_counter() - start
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    if "ready:" not in line:
        raise SystemExit("the node did not start")
    return ready


def colcon_starts(tmp_path: Path, prime: bool) -> tuple[float, float]:
    """(first, second) start [s] to ``ready:`` of a fresh colcon build's ``compensator``."""
    sys.path.insert(0, str(REPO / "test"))
    from ros_env import copy_package

    ws = tmp_path / f"ws_{'primed' if prime else 'unprimed'}"
    copy_package(ws / "src" / "strain_comp")
    colcon = Path(sys.executable).parent / "colcon"
    env = {**os.environ, "PATH": f"{colcon.parent}:{os.environ['PATH']}"}
    if not prime:
        env["STRAIN_COMP_NO_PRIME"] = "1"
    subprocess.run([str(colcon), "build", "--packages-select", "strain_comp"], cwd=ws,
                   env=env, check=True, capture_output=True, timeout=1200)
    prefix = ws / "install" / "strain_comp"
    env = {**os.environ, "PYTHONPATH": str(next(prefix.glob("lib/python3*/site-packages"))),
           "AMENT_PREFIX_PATH": str(prefix), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": str(100 + os.getpid() % 50), "PYTHONUNBUFFERED": "1"}
    env.pop("NUMBA_CACHE_DIR", None)
    times = []
    for _ in range(2):
        start = time.perf_counter()
        proc = subprocess.Popen([str(prefix / "lib" / "strain_comp" / "compensator"),
                                 "--ros-args", "--params-file",
                                 str(prefix / "share/strain_comp/config/compensator_params.yaml")],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True)
        line = ""
        while "ready:" not in line and proc.poll() is None:
            line = proc.stdout.readline()
        times.append(time.perf_counter() - start)
        proc.terminate()
        proc.wait(timeout=10)
    return times[0], times[1]


def median(values: list[float]) -> float:
    return sorted(values)[len(values) // 2]


def spawn(argv: list[str]) -> float:
    """Wall s of one ``python`` subprocess running ``argv`` to its end."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    start = time.perf_counter()
    subprocess.run([sys.executable, *argv], env=env, cwd=REPO, check=True, capture_output=True)
    return time.perf_counter() - start


def cli_start(runs: int) -> None:
    """``strain-comp --version`` and ``--help`` against a bare interpreter."""
    base = median([spawn(["-c", "pass"]) for _ in range(runs)])
    print(f"command line (median of {runs} spawns): python -c pass {base * 1e3:.0f} ms")
    for flag in ("--version", "--help"):
        wall = median([spawn(["-m", "strain_comp.cli", flag]) for _ in range(runs)])
        print(f"  strain-comp {flag:<10}{wall * 1e3:>6.0f} ms ({wall / base:.1f}x the bare "
              "interpreter)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm-runs", type=int, default=3)
    parser.add_argument("--no-node", action="store_true")
    parser.add_argument("--cli-runs", type=int, default=9)
    parser.add_argument("--cli-only", action="store_true",
                        help="only the command line's start-up")
    parser.add_argument("--colcon", action="store_true",
                        help="only a fresh colcon build's first and second node start")
    args = parser.parse_args()
    if args.colcon:
        with tempfile.TemporaryDirectory(prefix="strain_comp_colcon_") as tmp:
            for prime in (True, False):
                first, second = colcon_starts(Path(tmp), prime)
                print(f"colcon install, cache {'primed' if prime else 'not primed'}: first "
                      f"start {first:.2f} s, second {second:.2f} s to 'ready:' (load "
                      f"{os.getloadavg()[0]:.1f})", flush=True)
        return
    cli_start(args.cli_runs)
    if args.cli_only:
        return
    with tempfile.TemporaryDirectory(prefix="strain_comp_startup_") as tmp:
        tmp_path = Path(tmp)
        names = ["s_apl", "s_cubic"] + [f"a{i:02d}" for i in range(16)]
        save_calibration(calibration(names, ["apl", "cubic"] + ["apl"] * 16),
                         tmp_path / "cal.yaml")
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        base = time.perf_counter() - start
        print(f"baseline: python -c 'import numpy': {base:.2f} s")
        print(f"{'engine start-up (subprocess)':<34}{'total':>8}{'import':>8}{'build':>8}"
              f"{'warm_up':>9}{'1st step':>10}")
        cache = tmp_path / "numba_engine"
        cache.mkdir()
        rows = [("cold cache", *engine_start(tmp_path / "cal.yaml", cache))]
        warm = [engine_start(tmp_path / "cal.yaml", cache) for _ in range(args.warm_runs)]
        mid = sorted(warm, key=lambda w: w[0])[len(warm) // 2]
        rows.append((f"warm cache (median of {len(warm)})", *mid))
        for what, total, phase in rows:
            print(f"{what:<34}{total:>8.2f}{phase['import']:>8.2f}{phase['build']:>8.2f}"
                  f"{phase['warm_up']:>9.2f}{phase['first'] * 1e3:>8.2f}ms")
        print(f"engine start-up ratio cold / warm: {rows[0][1] / rows[1][1]:.1f}x "
              f"(warm_up alone {rows[0][2]['warm_up'] / rows[1][2]['warm_up']:.0f}x)")
        if args.no_node:
            return
        cache = tmp_path / "numba_node"
        cache.mkdir()
        cold = node_start(cache)
        warm_node = median([node_start(cache) for _ in range(args.warm_runs)])
        print(f"rclpy node (config/array_params.yaml) spawn -> 'ready:': cold {cold:.2f} s, "
              f"warm {warm_node:.2f} s; ratio cold / warm {cold / warm_node:.1f}x")


if __name__ == "__main__":
    main()
