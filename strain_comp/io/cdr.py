"""CDR payloads of the message types strain_comp writes, serialised by ``mcap_ros2``'s
encoder from ``SCHEMAS``. A fixed-layout message (Float64MultiArray, JointState,
Temperature) is a template the library serialises once; where its values sit is where a
second serialisation with other values differs from it."""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from mcap_ros2._dynamic import serialize_dynamic

from strain_comp.io.bag.schemas import SCHEMAS

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR little endian, no options."""

STAMP = struct.Struct("<iI")
"""builtin_interfaces/Time: int32 sec, uint32 nanosec (4-aligned, bytes 4..12 of a message
that starts with a header)."""
_PROBE = struct.unpack("<d", bytes(range(1, 9)))[0]
"""A float64 none of whose bytes is zero: where it replaces a zero value, the first byte
that differs is the value's first byte."""


@functools.cache
def message_encoder(kind: str) -> Callable[[Mapping[str, Any]], bytes]:
    """The encoder of a message type for messages given as nested dicts."""
    encoder: Callable[[Mapping[str, Any]], bytes] = serialize_dynamic(kind, SCHEMAS[kind])[kind]
    return encoder


def stamp_of(t_ns: int) -> tuple[int, int]:
    """Split a time into a ROS stamp."""
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def _header(sec: int, nanosec: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id}


def _offset(a: bytes, b: bytes) -> int:
    """The first byte where two serialisations of one layout differ."""
    return next(i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)


def diagnostic_array(sec: int, nanosec: int, frame_id: str,
                     statuses: Sequence[tuple[str, int, str, str, Sequence[tuple[str, str]]]]
                     ) -> bytes:
    """Encode a diagnostic_msgs/msg/DiagnosticArray."""
    return message_encoder("diagnostic_msgs/msg/DiagnosticArray")({
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "status": [{"level": level, "name": name, "message": message,
                    "hardware_id": hardware_id,
                    "values": [{"key": k, "value": v} for k, v in values]}
                   for name, level, message, hardware_id, values in statuses]})


def float64_multiarray_head(dims: Sequence[tuple[str, int, int]], data_offset: int,
                            n: int) -> bytes:
    """The bytes of a std_msgs/msg/Float64MultiArray message of ``n`` values before its
    first value: every such message is this head and the values (little-endian float64)."""
    payload = message_encoder("std_msgs/msg/Float64MultiArray")({
        "layout": {"dim": [{"label": label, "size": size, "stride": stride}
                           for label, size, stride in dims], "data_offset": data_offset},
        "data": [0.0] * n})
    return payload[:len(payload) - 8 * n]


def joint_state_layout(frame_id: str, names: Sequence[str], *, velocity: bool
                       ) -> tuple[bytes, int, int | None]:
    """The template of every sensor_msgs/msg/JointState message for fixed names."""
    encode = message_encoder("sensor_msgs/msg/JointState")
    n = len(names)

    def message(position: float, speed: float) -> bytes:
        return encode({"header": _header(0, 0, frame_id), "name": list(names),
                       "position": [position] * n, "velocity":
                       [speed] * n if velocity else [], "effort": []})

    template = message(0.0, 0.0)
    if not n:  # no values: position's count is followed by velocity's and effort's
        return template, len(template) - 8, len(template) - 4 if velocity else None
    pos_at = _offset(template, message(_PROBE, 0.0))
    return template, pos_at, _offset(template, message(0.0, _PROBE)) if velocity else None


def temperature_layout(frame_id: str, variance: float) -> tuple[bytes, int]:
    """The template of every sensor_msgs/msg/Temperature message of one frame and variance:
    only the stamp (bytes 4..12) and the temperature differ."""
    encode = message_encoder("sensor_msgs/msg/Temperature")

    def message(value: float) -> bytes:
        return encode({"header": _header(0, 0, frame_id), "temperature": value,
                       "variance": variance})

    template = message(0.0)
    return template, _offset(template, message(_PROBE))
