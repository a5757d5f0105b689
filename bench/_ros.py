"""Shared set-up of the ROS benchmarks: the compensator node in a child process.

Discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a domain of its
own; the node is ``strain_comp.ros.node``'s main (what ``ros2 run`` starts; ``args`` follow
``--ros-args``), with a params file
for a calibration written to a temporary folder; ``cpu`` pins it to one core (taskset).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration

ROOT = Path(__file__).resolve().parent.parent
os.environ.update({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
                   "ROS_DOMAIN_ID": str(150 + os.getpid() % 50)})


def start_node(calibration: Calibration, *args: str, array: str | None = None,
               cpu: int | None = None) -> subprocess.Popen[bytes]:
    """The node on ``calibration`` (one Float64 input per sensor, or one array input named
    ``array`` holding every sensor), once its 'ready' line is out."""
    tmp = Path(tempfile.mkdtemp(prefix="strain_comp_bench_"))
    save_calibration(calibration, tmp / "cal.yaml")
    names = list(calibration.sensors)
    body = ("/**/compensator:\n  ros__parameters:\n"
            + (f"    arrays: [{array}]\n    {array}: {{sensors: [{', '.join(names)}], "
               "calibration: cal.yaml}\n" if array else
               f"    sensors: [{', '.join(names)}]\n"
               + "".join(f"    {n}: {{calibration: cal.yaml}}\n" for n in names)))
    (tmp / "params.yaml").write_text(body)
    cmd = [sys.executable, "-m", "strain_comp.ros.node", "--ros-args", "--params-file",
           str(tmp / "params.yaml"), *args]
    if cpu is not None:
        cmd = ["taskset", "-c", str(cpu), *cmd]
    log = open(tmp / "node.log", "w+b")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    node = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 120
    while b"ready:" not in (tmp / "node.log").read_bytes():
        if node.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError((tmp / "node.log").read_text())
        time.sleep(0.05)
    return node


def cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def stop_node(node: subprocess.Popen[bytes]) -> None:
    node.terminate()
    node.wait(timeout=10)
