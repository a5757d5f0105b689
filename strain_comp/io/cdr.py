"""CDR encoding of the fixed message types strain_comp writes: those a bag holds
(``strain_comp.io.bag.schemas.SCHEMAS``) and the node's outputs (``strain_comp.ros.cdr``
prebuilds its constant blocks from the layouts here), so the wire format is defined once.

ROS 2 serialises messages as OMG CDR (XCDR1, plain little endian, rmw's encapsulation
``00 01 00 00``): each primitive is aligned to its own size counted from the end of the
4-byte encapsulation header, a string is a uint32 length (the terminating NUL included),
its UTF-8 bytes and a NUL, a sequence is a uint32 count followed by its elements (an empty
sequence of 8-byte values is not padded, as Fast-CDR does). One dedicated encoder per type,
so a message costs a few ``struct.pack`` calls instead of a walk over a parsed schema;
``test_cdr`` checks every one byte for byte against ``rosbags``' serialiser.

``message_encoder(kind)`` gives a ``dict -> bytes`` encoder of the standard field names (the
shape rosbags and the ROS message classes use); the writer calls the typed functions below
directly.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR little endian, no options."""

_U32 = struct.Struct("<I")
STAMP = struct.Struct("<iI")
"""builtin_interfaces/Time: int32 sec, uint32 nanosec (4-aligned)."""
_PAD = [b"\0" * k for k in range(8)]
_STRING_CACHE = 4096
_CACHED_LENGTH = 256
_STRINGS: dict[str, bytes] = {}
"""Encoded strings (length, UTF-8, NUL) by text, those of at most ``_CACHED_LENGTH`` bytes:
diagnostics repeat their names and keys in every message. Emptied when it reaches
``_STRING_CACHE`` entries."""


class CdrBuffer:
    """A CDR payload being written: the encapsulation header, then aligned fields."""

    __slots__ = ("data",)

    def __init__(self) -> None:
        self.data = bytearray(ENCAPSULATION)

    def align(self, size: int) -> None:
        """Pad to a multiple of ``size`` bytes, counted after the encapsulation header."""
        self.data += _PAD[-(len(self.data) - 4) % size]

    def u32(self, value: int) -> None:
        """Append a uint32, 4-aligned."""
        self.align(4)
        self.data += _U32.pack(value)

    def stamp(self, sec: int, nanosec: int) -> None:
        """Append a builtin_interfaces/Time (``STAMP``)."""
        self.align(4)
        self.data += STAMP.pack(sec, nanosec)

    def f64(self, *values: float) -> None:
        """Append consecutive float64 fields, 8-aligned."""
        self.align(8)
        self.data += struct.pack(f"<{len(values)}d", *values)

    def string(self, text: str) -> None:
        """Append a string: uint32 length with the NUL, UTF-8 bytes, NUL."""
        data = self.data
        data += _PAD[-len(data) % 4]  # the 4-byte encapsulation keeps 4-alignment
        data += _STRINGS.get(text) or _encoded(text)

    def strings(self, texts: Sequence[str]) -> None:
        """Append a string sequence: uint32 count, then each string."""
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def f64_seq(self, values: npt.ArrayLike) -> None:
        """Append a float64 sequence: uint32 count, then the values 8-aligned (no padding
        when empty)."""
        v = np.asarray(values, dtype="<f8").reshape(-1)
        self.u32(v.size)
        if v.size:
            self.align(8)
            self.data += v.tobytes()

    def header(self, sec: int, nanosec: int, frame_id: str) -> None:
        """Append a std_msgs/Header: stamp, frame_id."""
        self.stamp(sec, nanosec)
        self.string(frame_id)

    def payload(self) -> bytes:
        """The message as written so far."""
        return bytes(self.data)


def _encoded(text: str) -> bytes:
    """``text`` as a CDR string (length with the NUL, UTF-8, NUL); short ones are kept in
    ``_STRINGS``."""
    raw = text.encode()
    encoded = _U32.pack(len(raw) + 1) + raw + b"\0"
    if len(raw) <= _CACHED_LENGTH:
        if len(_STRINGS) >= _STRING_CACHE:
            _STRINGS.clear()
        _STRINGS[text] = encoded
    return encoded


def stamp_of(t_ns: int) -> tuple[int, int]:
    """Split a time into a ROS stamp."""
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def float64(value: float) -> bytes:
    """Encode a std_msgs/msg/Float64."""
    return ENCAPSULATION + struct.pack("<d", value)


def float32(value: float) -> bytes:
    """Encode a std_msgs/msg/Float32."""
    return ENCAPSULATION + struct.pack("<f", value)


def int8(value: int) -> bytes:
    """Encode a std_msgs/msg/Int8."""
    return ENCAPSULATION + struct.pack("<b", value)


def float64_multiarray(dims: Sequence[tuple[str, int, int]], data_offset: int,
                       data: npt.ArrayLike) -> bytes:
    """Encode a std_msgs/msg/Float64MultiArray."""
    buf = CdrBuffer()
    buf.u32(len(dims))
    for label, size, stride in dims:
        buf.string(label)
        buf.u32(size)
        buf.u32(stride)
    buf.u32(data_offset)
    buf.f64_seq(data)
    return buf.payload()


def float64_multiarray_head(dims: Sequence[tuple[str, int, int]], data_offset: int,
                            n: int) -> bytes:
    """The bytes of a ``float64_multiarray`` message of ``n`` values before its first value."""
    payload = float64_multiarray(dims, data_offset, np.zeros(n))
    return payload[:len(payload) - 8 * n]


def temperature(sec: int, nanosec: int, frame_id: str, value: float,
                variance: float) -> bytes:
    """Encode a sensor_msgs/msg/Temperature."""
    buf = CdrBuffer()
    buf.header(sec, nanosec, frame_id)
    buf.f64(value, variance)
    return buf.payload()


def diagnostic_array(sec: int, nanosec: int, frame_id: str,
                     statuses: Sequence[tuple[str, int, str, str, Sequence[tuple[str, str]]]]
                     ) -> bytes:
    """Encode a diagnostic_msgs/msg/DiagnosticArray."""
    buf = CdrBuffer()
    buf.header(sec, nanosec, frame_id)
    buf.u32(len(statuses))
    data = buf.data
    cached = _STRINGS.get
    for name, level, message, hardware_id, values in statuses:  # inlined: ~1 us a string
        data.append(level)  # byte level (uint8: no alignment)
        for text in (name, message, hardware_id):
            data += _PAD[-len(data) % 4]
            data += cached(text) or _encoded(text)
        data += _PAD[-len(data) % 4]
        data += _U32.pack(len(values))
        for key, value in values:
            data += _PAD[-len(data) % 4]
            data += cached(key) or _encoded(key)
            data += _PAD[-len(data) % 4]
            data += cached(value) or _encoded(value)
    return buf.payload()


def joint_state(sec: int, nanosec: int, frame_id: str, names: Sequence[str],
                position: npt.ArrayLike, velocity: npt.ArrayLike = (),
                effort: npt.ArrayLike = ()) -> bytes:
    """Encode a sensor_msgs/msg/JointState."""
    buf = CdrBuffer()
    buf.header(sec, nanosec, frame_id)
    buf.strings(names)
    buf.f64_seq(position)
    buf.f64_seq(velocity)
    buf.f64_seq(effort)
    return buf.payload()


def joint_state_layout(frame_id: str, names: Sequence[str], *, velocity: bool
                       ) -> tuple[bytes, int, int | None]:
    """The template of every JointState message for fixed names."""
    n = len(names)
    buf = CdrBuffer()
    buf.header(0, 0, frame_id)
    buf.strings(names)
    buf.f64_seq(np.zeros(n))
    pos_at = len(buf.data) - 8 * n
    buf.f64_seq(np.zeros(n if velocity else 0))
    vel_at = len(buf.data) - 8 * n if velocity else None
    buf.f64_seq(())  # effort
    return buf.payload(), pos_at, vel_at


# ------------------------------------------------------------ dict messages (standard names)


def _header(msg: Mapping[str, Any]) -> tuple[int, int, str]:
    header = msg["header"]
    return int(header["stamp"]["sec"]), int(header["stamp"]["nanosec"]), header["frame_id"]


_DICT_ENCODERS: dict[str, Callable[[Mapping[str, Any]], bytes]] = {
    "std_msgs/msg/Float64": lambda m: float64(m["data"]),
    "std_msgs/msg/Float32": lambda m: float32(m["data"]),
    "std_msgs/msg/Int8": lambda m: int8(m["data"]),
    "std_msgs/msg/Float64MultiArray": lambda m: float64_multiarray(
        [(d["label"], d["size"], d["stride"]) for d in m["layout"]["dim"]],
        m["layout"]["data_offset"], m["data"]),
    "sensor_msgs/msg/Temperature": lambda m: temperature(
        *_header(m), m["temperature"], m["variance"]),
    "diagnostic_msgs/msg/DiagnosticArray": lambda m: diagnostic_array(
        *_header(m), [(s["name"], s["level"], s["message"], s["hardware_id"],
                       [(kv["key"], kv["value"]) for kv in s["values"]])
                      for s in m["status"]]),
    "sensor_msgs/msg/JointState": lambda m: joint_state(
        *_header(m), m["name"], m["position"], m["velocity"], m["effort"]),
}


def message_encoder(kind: str) -> Callable[[Mapping[str, Any]], bytes]:
    """The encoder of a message type for messages given as nested dicts."""
    return _DICT_ENCODERS[kind]
