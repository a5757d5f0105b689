"""ROS 2 environment for tests that start ROS: discovery on this machine only, and a domain
per test module and process, so parallel runs do not see each other's nodes."""

from __future__ import annotations

import os

DOMAINS = 100
"""Domain ids 1..100 (Fast DDS ports stay valid up to 232)."""


def ros_env(slot: int) -> dict[str, str]:
    """Environment variables for one test module (``slot``: a small number per module)."""
    domain = 1 + (os.getpid() * 7 + slot * 31) % DOMAINS
    return {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": str(domain)}


def use_ros_env(slot: int) -> dict[str, str]:
    """Put ``ros_env(slot)`` into this process's environment (before ``rclpy.init``)."""
    env = ros_env(slot)
    os.environ.update(env)
    return env
