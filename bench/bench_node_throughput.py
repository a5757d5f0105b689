"""The rclpy node at robot rates on one core: answered share and CPU, against an echo node.

    python bench/bench_node_throughput.py [--seconds S] [--rates 1000,2000] [--overload]
                                          [--arrays 256@1000,1024@250] [--arrays-only]
                                          [--band] [--goals] [--flush K@ROUNDS]

The node (``strain_comp.ros.node``, another process) is pinned to core 1 with taskset; this
process publishes on core 0 at a fixed rate for S seconds (at most 4500 messages) and counts
the answers on ``NAME/strain`` (what a controller reads; the other outputs are built only
when subscribed).
1. One std_msgs/Float64 topic, APL calibration, at each of ``--rates``: the node as shipped
   (EventsExecutor) and with ``executor:=single_threaded``; goal at 1 kHz: >= 99.9 %
   answered with <= 30 % of a core.
2. Each of ``--arrays`` (K sensors @ rate): a K-sensor std_msgs/Float64MultiArray topic
   (APL array kernel) at that rate, the strain alone and every output (strain, direction,
   strain_stamped) subscribed; goal: >= 99.5 % answered with <= 40 % of a core (a skin:
   256 sensors at 1 kHz, 1024 at 250 Hz). The node's start-up (calibration load and
   engine build) is printed.
3. ``--overload``: one Float64 topic at 15 kHz (beyond the node), then at once 1 kHz again:
   the answered share in each phase (best-effort inputs: the overload drops, the 1 kHz phase
   must recover at once).
Node CPU share = its user + system CPU time over the window (``/proc/PID/stat`` utime + stime,
read from this process: the node's own threads, DDS's included) / wall time of the window
(1.0 = one core).
``--goals``: only the three rate goals, each with every output subscribed (one sensor at
1 kHz; 256 sensors at 1 kHz; 1024 at 250 Hz), with the load average (``uptime``) before and
after.
``--flush K@ROUNDS``: no second process; the node in this one (on core 1), on a K-sensor array
(K = 1: one Float64 sensor), every output subscribed; ROUNDS times ten inputs are published into its
intake and one ``_flush`` (what the batch timer runs) is timed with ``time.thread_time``: the
CPU of the node's Python thread per input, which other load on the machine changes less
than the CPU share from outside (the DDS threads are left out).
Baseline in the same run: a bare rclpy echo node (SingleThreadedExecutor, republishes each
Float64), so the CPU ratio is the compensator's cost against ROS's own message handling.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np
from _common import calibration, resistance
from _ros import cpu_seconds, start_node, stop_node
from bench_latency import ECHO

MAX_ANSWERS = 4500
"""Messages per window at most: the answers wait in the counting subscription's history,
which Fast DDS's default resource limits cap at 5000 samples (a longer window at 2 kHz
counted exactly 5010 answers, whatever the node did)."""


def drive(topic: str, out_topic: str, kind: str, k: int, rate: float, seconds: float,
          pid: int, *, extra: tuple[tuple[str, Any], ...] = ()) -> tuple[float, float]:
    """(answered share, node CPU share) for ``rate`` messages/s during ``seconds``;
    ``extra``: (topic, type) of further outputs to subscribe to (not counted)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64, Float64MultiArray

    cls = Float64 if kind == "single" else Float64MultiArray
    node = rclpy.create_node("bench_throughput")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    count = [0]
    pub = node.create_publisher(cls, topic, 100)
    n = min(int(rate * seconds), MAX_ANSWERS)
    sub = node.create_subscription(cls, out_topic,  # history holds every answer: read later
                                   lambda _m: count.__setitem__(0, count[0] + 1), n + 100)
    others = [node.create_subscription(t, name, lambda _m: None, 10) for name, t in extra]
    while (pub.get_subscription_count() == 0 or sub.get_publisher_count() == 0
           or any(o.get_publisher_count() == 0 for o in others)):
        executor.spin_once(timeout_sec=0.05)
    time.sleep(0.5)
    r = resistance(np.arange(n) / rate, k)
    msgs = ([Float64(data=float(v)) for v in r[:, 0]] if kind == "single"
            else [Float64MultiArray(data=row.tolist()) for row in r])
    cpu0, start = cpu_seconds(pid), time.perf_counter()
    for i, msg in enumerate(msgs):  # paced by a sleep, then a busy wait for the last 1 ms:
        # the DDS threads that receive the answers share this core
        due = start + i / rate
        if (ahead := due - time.perf_counter()) > 0.0015:  # read once: a preemption
            time.sleep(ahead - 0.001)  # between two reads made the sleep negative
        while time.perf_counter() < due:
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


OVERLOAD_HZ = 15000.0
"""Beyond the node on one core (it answers 5 kHz in full)."""


def verdict(answered: float, cpu: float, share: float, core: float) -> str:
    return "goal met" if answered >= share and cpu <= core else "goal missed"


SINGLE_OUTPUTS = (("/s1/direction", "Int8"), ("/s1/strain_stamped", "JointState"))
"""The single sensor's outputs besides ``/s1/strain`` (every output subscribed)."""


def single_extra() -> tuple[tuple[str, Any], ...]:
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Int8

    kinds = {"Int8": Int8, "JointState": JointState}
    return tuple((topic, kinds[kind]) for topic, kind in SINGLE_OUTPUTS)


def goals(args: argparse.Namespace) -> None:
    """``--goals``: one sensor at 1 kHz, every output subscribed."""
    node = start_node(calibration(["s1"], ["apl"], band=args.band), cpu=1)
    try:
        answered, cpu = drive("/s1/resistance", "/s1/strain", "single", 1, 1000.0,
                              args.seconds, node.pid, extra=single_extra())
        print(f"one Float64 sensor, apl, 1000 Hz, every output subscribed: answered "
              f"{answered:7.2%}, node CPU {cpu:5.1%} of a core   "
              f"{verdict(answered, cpu, 0.999, 0.30)} (>= 99.9 %, <= 30 %)")
    finally:
        stop_node(node)


def single_topic(args: argparse.Namespace) -> None:
    """Part 1 (and 3 with ``--overload``): one Float64 topic against the echo node."""
    rates = [float(v) for v in args.rates.split(",")]
    echo = subprocess.Popen(["taskset", "-c", "1", sys.executable, "-c", ECHO],
                            stdout=subprocess.PIPE, text=True)
    assert echo.stdout is not None and echo.stdout.readline().startswith("ready:")
    base = {rate: drive("/s1/resistance", "/s1/strain", "single", 1, rate, args.seconds,
                        echo.pid) for rate in rates}
    echo.terminate()
    echo.wait()
    for executor in ("events", "single_threaded"):
        node = start_node(calibration(["s1"], ["apl"], band=args.band), "-p",
                          f"executor:={executor}", cpu=1)
        try:
            for rate in rates:
                answered, cpu = drive("/s1/resistance", "/s1/strain", "single", 1, rate,
                                      args.seconds, node.pid)
                b_answered, b_cpu = base[rate]
                goal = (f"   {verdict(answered, cpu, 0.999, 0.30)} (>= 99.9 %, <= 30 %)"
                        if rate == 1000 else "")
                print(f"one Float64 topic, apl, {executor:15s} {rate:6.0f} Hz: answered "
                      f"{answered:7.2%}, node CPU {cpu:5.1%} of a core   (echo node: answered "
                      f"{b_answered:7.2%}, CPU {b_cpu:5.1%}; CPU ratio "
                      f"{cpu / max(b_cpu, 1e-9):.2f}x){goal}")
            if args.overload and executor == "events":
                for rate in (OVERLOAD_HZ, 1000.0):
                    answered, cpu = drive("/s1/resistance", "/s1/strain", "single", 1, rate,
                                          args.seconds, node.pid)
                    print(f"overload, events, {rate:6.0f} Hz right after: answered "
                          f"{answered:7.2%}, node CPU {cpu:5.1%} of a core")
        finally:
            stop_node(node)


def flush(k: int, rounds: int) -> None:
    """``--flush``: the node's thread CPU per input message (module docstring)."""
    import tempfile
    from pathlib import Path

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray, Int8

    from strain_comp.core.calibration_file import save_calibration
    from strain_comp.ros.compensator import CompensatorNode

    os.sched_setaffinity(0, {1})  # one core, as the node process of the other parts
    tmp = Path(tempfile.mkdtemp(prefix="strain_comp_bench_"))
    names = [f"x{i}" for i in range(k)] if k > 1 else ["s1"]
    save_calibration(calibration(names, ["apl"]), tmp / "cal.yaml")
    name, kind, direction = (("hand", Float64MultiArray, Float64MultiArray) if k > 1
                             else ("s1", Float64, Int8))
    (tmp / "params.yaml").write_text(
        "/**/compensator:\n  ros__parameters:\n" + (
            f"    arrays: [hand]\n    hand: {{sensors: [{', '.join(names)}], "
            "calibration: cal.yaml}\n" if k > 1 else
            "    sensors: [s1]\n    s1: {calibration: cal.yaml}\n"))
    rclpy.init(args=["--ros-args", "--params-file", str(tmp / "params.yaml")])
    node = CompensatorNode("compensator", base_dir=tmp)
    probe = rclpy.create_node("bench_flush")
    executor = SingleThreadedExecutor()
    executor.add_node(probe)
    pub = probe.create_publisher(kind, f"/{name}/resistance", 200)
    subs = [probe.create_subscription(t, f"/{name}/{o}", lambda _m: None, 10) for o, t in
            (("strain", kind), ("direction", direction), ("strain_stamped", JointState))]
    while pub.get_subscription_count() == 0 or any(s.get_publisher_count() == 0 for s in subs):
        executor.spin_once(timeout_sec=0.05)
    time.sleep(0.5)
    r = resistance(np.arange(rounds * 10) / 1000.0, k)
    msgs = ([Float64(data=float(v)) for v in r[:, 0]] if k == 1
            else [Float64MultiArray(data=row.tolist()) for row in r])
    cpu = []
    for i in range(rounds):
        for msg in msgs[i * 10:(i + 1) * 10]:
            pub.publish(msg)
        time.sleep(0.004)  # delivered into the intake's history
        start = time.thread_time()
        node._flush()
        cpu.append(time.thread_time() - start)
        executor.spin_once(timeout_sec=0)
    per_input = np.array(cpu) / 10
    print(f"{k} sensor(s), apl, every output subscribed: the node's thread CPU per input "
          f"{per_input.mean() * 1e6:.0f} us (median batch {np.median(per_input) * 1e6:.0f} "
          f"us; {per_input.mean() * 1e5:.1f} % of a core at 1 kHz), {len(msgs)} inputs; "
          f"load average {os.getloadavg()[0]:.1f}")
    rclpy.try_shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rates", default="1000,2000")
    parser.add_argument("--overload", action="store_true")
    parser.add_argument("--arrays", default="256@1000,1024@250",
                        help="array sizes and rates, K@HZ,...")
    parser.add_argument("--arrays-only", action="store_true",
                        help="skip the single-topic and echo runs")
    parser.add_argument("--band", action="store_true",
                        help="calibrations with an uncertainty: the node computes every "
                             "estimate's standard deviation (compare with a run without)")
    parser.add_argument("--goals", action="store_true",
                        help="only the three rate goals, every output subscribed")
    parser.add_argument("--flush", help="K@ROUNDS: the node's thread CPU per input, "
                        "in this process")
    args = parser.parse_args()
    if args.flush:
        k, rounds = (int(v) for v in args.flush.split("@"))
        flush(k, rounds)
        return
    os.sched_setaffinity(0, {0})
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the "
          "start (other work on the machine lowers every figure)")
    print("uptime:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    if args.goals:
        goals(args)
    elif not args.arrays_only:
        single_topic(args)
    for spec in args.arrays.split(","):
        k, rate = (float(v) for v in spec.split("@"))
        names = [f"x{i}" for i in range(int(k))]
        start = time.perf_counter()
        node = start_node(calibration(names, ["apl"], band=args.band), array="hand", cpu=1)
        print(f"{int(k)}-sensor array node: ready {time.perf_counter() - start:.1f} s after "
              "spawn (calibration load, engine build, kernel cache)")
        try:
            every = ("every output", (("/hand/direction", Float64MultiArray),
                                      ("/hand/strain_stamped", JointState)))
            for what, extra in ((every,) if args.goals else (("strain", ()), every)):
                answered, cpu = drive("/hand/resistance", "/hand/strain", "array", int(k),
                                      rate, args.seconds, node.pid, extra=extra)
                print(f"{int(k)}-sensor Float64MultiArray, apl, {rate:.0f} Hz, {what:12s} "
                      f"subscribed: answered {answered:7.2%}, node CPU {cpu:5.1%} of a core   "
                      f"{verdict(answered, cpu, 0.995, 0.40)} (>= 99.5 %, <= 40 %)")
        finally:
            stop_node(node)
    print("uptime:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
