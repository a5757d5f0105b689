"""Highest sustained input rate of the rclpy node on one core, and its CPU share.

    python bench/bench_node_throughput.py [--seconds S] [--rates 250,500,...]

The node (``bin/compensator``, another process) is pinned to core 1 with taskset; this
process publishes on core 0 at a fixed rate for S seconds, then counts the outputs (its
subscription's history holds every answer, so counting does not compete with publishing).
1. One std_msgs/Float64 topic, APL calibration: rates from ``--rates``; the node keeps up at
   a rate when >= 99 % of the inputs are answered.
2. A 256-sensor std_msgs/Float64MultiArray topic (APL array kernel) at 1 kHz.
Node CPU share = its user + system CPU time / wall time of the window (1.0 = one core).
Baseline in the same run: a bare rclpy echo node (republishes each Float64) at each rate,
so the ratio of CPU shares is what the compensator adds to ROS's own message handling.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np
from _common import calibration, resistance
from _ros import cpu_seconds, start_node, stop_node
from bench_latency import ECHO


def drive(topic: str, out_topic: str, kind: str, k: int, rate: float, seconds: float,
          pid: int) -> tuple[float, float]:
    """(answered share, node CPU share) for ``rate`` messages/s during ``seconds``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64, Float64MultiArray

    cls = Float64 if kind == "single" else Float64MultiArray
    node = rclpy.create_node("bench_throughput")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    count = [0]
    pub = node.create_publisher(cls, topic, 100)
    n = int(rate * seconds)
    sub = node.create_subscription(cls, out_topic,  # history holds every answer: read later
                                   lambda _m: count.__setitem__(0, count[0] + 1), n + 100)
    while pub.get_subscription_count() == 0 or sub.get_publisher_count() == 0:
        executor.spin_once(timeout_sec=0.05)
    time.sleep(0.5)
    r = resistance(np.arange(n) / rate, k)
    msgs = ([Float64(data=float(v)) for v in r[:, 0]] if kind == "single"
            else [Float64MultiArray(data=row.tolist()) for row in r])
    cpu0, start = cpu_seconds(pid), time.perf_counter()
    for i, msg in enumerate(msgs):  # paced by a busy wait: this process only publishes
        while time.perf_counter() < start + i / rate:
            pass
        pub.publish(msg)
    time.sleep(0.2)  # the last inputs still in flight
    cpu = (cpu_seconds(pid) - cpu0) / (time.perf_counter() - start)
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)
    executor.shutdown()
    node.destroy_node()
    return count[0] / n, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rates", default="250,500,1000,2000")
    args = parser.parse_args()
    os.sched_setaffinity(0, {0})
    import rclpy

    rclpy.init()
    rates = [float(v) for v in args.rates.split(",")]
    echo = subprocess.Popen(["taskset", "-c", "1", sys.executable, "-c", ECHO],
                            stdout=subprocess.PIPE, text=True)
    assert echo.stdout is not None and echo.stdout.readline().startswith("ready:")
    base = {rate: drive("/s1/resistance", "/s1/strain", "single", 1, rate, args.seconds,
                        echo.pid) for rate in rates}
    echo.terminate()
    echo.wait()
    node = start_node(calibration(["s1"], ["apl"]), cpu=1)
    try:
        for rate in rates:
            answered, cpu = drive("/s1/resistance", "/s1/strain", "single", 1, rate,
                                  args.seconds, node.pid)
            b_answered, b_cpu = base[rate]
            print(f"one Float64 topic, apl, {rate:6.0f} Hz: answered {answered:6.1%}, node CPU "
                  f"{cpu:5.1%} of a core   (echo node: answered {b_answered:6.1%}, CPU "
                  f"{b_cpu:5.1%}; CPU ratio {cpu / max(b_cpu, 1e-9):.1f}x)   "
                  f"keeps up: {'yes' if answered >= 0.99 else 'no'}")
    finally:
        stop_node(node)
    names = [f"x{i}" for i in range(256)]
    node = start_node(calibration(names, ["apl"]), array="hand", cpu=1)
    try:
        answered, cpu = drive("/hand/resistance", "/hand/strain", "array", 256, 1000.0,
                              args.seconds, node.pid)
        print(f"256-sensor Float64MultiArray, apl, 1000 Hz: answered {answered:6.1%}, node "
              f"CPU {cpu:5.1%} of a core   keeps up: {'yes' if answered >= 0.99 else 'no'}")
    finally:
        stop_node(node)
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
