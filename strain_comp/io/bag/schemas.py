"""What a strain_comp bag holds: the ros2msg schema texts, and the decoded contents (times:
the log time in s, float64; written bags store integer ns)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros2"
LIBRARY = "strain_comp.io.bag"
CHUNK_SIZE = 1 << 20  # uncompressed bytes per chunk
MAX_TIME_S = 2**31 - 1
"""The latest message time a bag holds [s] (2038-01-19: a header stamp's int32 seconds)."""

_SEP = "=" * 80 + "\n"
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
#: ros2msg schema texts (concatenated with their dependencies, as rosbag2 stores them).
SCHEMAS: dict[str, str] = {
    "std_msgs/msg/Float64": "float64 data\n",
    "std_msgs/msg/Float32": "float32 data\n",
    "std_msgs/msg/Int8": "int8 data\n",
    "std_msgs/msg/Float64MultiArray": (
        "MultiArrayLayout layout\nfloat64[] data\n" + _SEP
        + "MSG: std_msgs/MultiArrayLayout\nMultiArrayDimension[] dim\nuint32 data_offset\n"
        + _SEP + "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"
    ),
    "sensor_msgs/msg/Temperature": (
        "std_msgs/Header header\nfloat64 temperature\nfloat64 variance\n"
        + _SEP + _HEADER + _SEP + _TIME
    ),
    "diagnostic_msgs/msg/DiagnosticArray": (
        "std_msgs/Header header\nDiagnosticStatus[] status\n" + _SEP + _HEADER + _SEP + _TIME
        + _SEP + "MSG: diagnostic_msgs/DiagnosticStatus\nbyte OK=0\nbyte WARN=1\nbyte ERROR=2\n"
        "byte STALE=3\nbyte level\nstring name\nstring message\nstring hardware_id\n"
        "KeyValue[] values\n" + _SEP + "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n"
    ),
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n" + _SEP + _HEADER + _SEP + _TIME
    ),
}
#: One diagnostic status: (name, level, message, {key: value}).
Status = tuple[str, int, str, dict[str, str]]


@dataclass(frozen=True)
class Series:
    """One topic's samples: log times [s] and float64 values, shape (n,) or (n, k)."""

    t: np.ndarray
    values: np.ndarray


@dataclass
class BagContents:
    """What ``read_bag`` found."""

    series: dict[str, Series] = field(default_factory=dict)
    labels: dict[str, list[str]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    diagnostics: list[tuple[float, list[Status]]] = field(default_factory=list)
    types: dict[str, str] = field(default_factory=dict)


def norm_type(name: str) -> str:
    """A message type name in its ``pkg/msg/Type`` spelling (both occur in the wild)."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


OFFERED_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false")
"""The QoS rosbag2 records for a topic it offers (channel metadata ``offered_qos_profiles``)."""
