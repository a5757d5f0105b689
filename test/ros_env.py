"""ROS 2 environment for tests that start ROS: discovery on this machine only, and a domain
per test module, run and pytest-xdist worker, so parallel runs do not see each other's
nodes; the package's sources for a colcon workspace (``strain_comp.ros.player.spin_until``
spins an executor until a condition holds). Imports no ROS module (a test module sets its
environment before importing rclpy)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

DOMAINS = 100
"""Domain ids 1..100 (Fast DDS ports stay valid up to 232)."""


def ros_env(slot: int) -> dict[str, str]:
    """Environment variables for one test module (``slot``: a small number per module).

    The domain is ``slot``'s, offset per pytest run (its process id, or under pytest-xdist
    the run's id, which every worker shares); the workers of one run interleave their
    slots (``slot * workers + worker``), so no two of them share a domain."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    base = int(run[:8], 16) if run else os.getpid()
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:])
    key = slot * workers + worker
    if key >= DOMAINS:
        raise ValueError(f"ROS test slot {slot} with {workers} pytest-xdist workers exceeds "
                         f"the {DOMAINS} domains: run with fewer workers (-n)")
    domain = 1 + (base * 7 + key * 31) % DOMAINS
    return {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": str(domain)}


def use_ros_env(slot: int) -> dict[str, str]:
    """Put ``ros_env(slot)`` into this process's environment (before ``rclpy.init``)."""
    env = ros_env(slot)
    os.environ.update(env)
    return env


ROOT = Path(__file__).resolve().parent.parent
PACKAGE_FILES = ("setup.py", "setup.cfg", "package.xml", "resource", "strain_comp", "config",
                 "launch")
"""What ``colcon build`` of the package needs."""


def copy_package(src: Path) -> None:
    """The package's ``PACKAGE_FILES`` into ``src`` (created), caches left out."""
    src.mkdir(parents=True)
    for name in PACKAGE_FILES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(path, src / name)


def wait_for(log: Path, text: str, proc: subprocess.Popen[str], timeout: float = 90.0) -> str:
    """Until ``text`` is in the process's ``log`` (which is returned); fails with the log
    when the process ends first or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while text not in log.read_text():
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, f"no {text!r} within {timeout} s: {log.read_text()}"
        time.sleep(0.05)
    return log.read_text()
