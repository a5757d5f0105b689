"""Per-message latency: the engine alone, and publish -> receive through the real node.

    python bench/bench_latency.py [--messages N] [--round-trips M]

1. ``Engine.step`` per message, cubic and APL (N = 11, M = 9) calibrations, kernels warm.
2. ``Engine.step_array`` per tick for a 256-sensor APL array (one kernel call per tick).
3. Round trip through the rclpy node in another process (``strain_comp.ros.node`` as shipped:
   EventsExecutor, outputs built when subscribed; Fast DDS on
   this machine): this process publishes one std_msgs/Float64 on /s1/resistance and waits
   for /s1/strain; one message in flight at a time. Baseline in the same run: the same round
   trip through a bare rclpy echo node (republishes each Float64), so the ratio is what the
   compensator adds to ROS's own transport.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np
from _common import calibration, resistance
from _ros import start_node, stop_node

from strain_comp.core.engine import Engine

ECHO = """
import rclpy
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Float64
rclpy.init()
node = rclpy.create_node("echo")
pub = node.create_publisher(Float64, "/s1/strain", 10)
node.create_subscription(Float64, "/s1/resistance", pub.publish, qos_profile_sensor_data)
print("ready:", flush=True)
try:
    rclpy.spin(node)
except BaseException:
    pass
"""


def stats(seconds: np.ndarray) -> str:
    us = np.asarray(seconds) * 1e6
    return f"median {np.median(us):8.1f} us   p99 {np.percentile(us, 99):8.1f} us"


def bench_step(model: str, n: int) -> np.ndarray:
    engine = Engine(calibration(["s1"], [model]))
    engine.warm_up()
    r = resistance(np.arange(n) * 1e-3, 1)[:, 0]
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        engine.step("s1", i * 1e-3, r[i])
        out[i] = time.perf_counter() - t0
    return out


def bench_array(k: int, n: int) -> np.ndarray:
    names = [f"x{i}" for i in range(k)]
    engine = Engine(calibration(names, ["apl"]), arrays={"arr": names})
    engine.warm_up()
    r = resistance(np.arange(n) * 1e-3, k)
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        engine.step_array("arr", i * 1e-3, r[i])
        out[i] = time.perf_counter() - t0
    return out


def round_trips(n: int) -> np.ndarray:
    """Publish -> receive times [s] against whatever node answers /s1/resistance."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    node = rclpy.create_node("bench_latency")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    got: list[float] = []
    pub = node.create_publisher(Float64, "/s1/resistance", 10)
    sub = node.create_subscription(Float64, "/s1/strain", lambda m: got.append(m.data), 10)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() == 0 or sub.get_publisher_count() == 0:
        executor.spin_once(timeout_sec=0.05)
        if time.monotonic() > deadline:
            raise RuntimeError("discovery did not complete")
    time.sleep(0.5)
    r = resistance(np.arange(n) * 1e-2, 1)[:, 0]
    out = []
    for i in range(n):
        before = len(got)
        t0 = time.perf_counter()
        pub.publish(Float64(data=float(r[i])))
        while len(got) == before and time.perf_counter() - t0 < 1.0:
            executor.spin_once(timeout_sec=0.001)
        if len(got) > before:
            out.append(time.perf_counter() - t0)
    executor.shutdown()
    node.destroy_node()
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20000)
    parser.add_argument("--round-trips", type=int, default=2000)
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the "
          "start (other work on the machine lowers every figure)")
    for model in ("cubic", "apl"):
        print(f"Engine.step, {model:5s}:              {stats(bench_step(model, args.messages))}")
    ticks = bench_array(256, max(args.messages // 10, 500))
    print(f"Engine.step_array, 256 x apl:     {stats(ticks)}   "
          f"(median {np.median(ticks) / 1e-3:.1%} of a 1 ms tick)")

    import rclpy

    rclpy.init()
    echo = subprocess.Popen([sys.executable, "-c", ECHO], stdout=subprocess.PIPE, text=True)
    assert echo.stdout is not None and echo.stdout.readline().startswith("ready:")
    base = round_trips(args.round_trips)
    echo.terminate()
    echo.wait()
    node = start_node(calibration(["s1"], ["apl"]))
    try:
        rtt = round_trips(args.round_trips)
    finally:
        stop_node(node)
    rclpy.try_shutdown()
    print(f"rclpy echo node round trip:       {stats(base)}   ({base.size} of "
          f"{args.round_trips} answered)")
    print(f"compensator node round trip, apl: {stats(rtt)}   ({rtt.size} of "
          f"{args.round_trips} answered)   median ratio to echo "
          f"{np.median(rtt) / np.median(base):.2f}x, p99 ratio "
          f"{np.percentile(rtt, 99) / np.percentile(base, 99):.2f}x")


if __name__ == "__main__":
    main()
