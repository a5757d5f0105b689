"""The node's per-tick outputs as serialised bytes (CDR), built around a prebuilt block.

A message built in Python and converted by rclpy costs tens of microseconds; for an array
most of it is the part that never changes: a sensor_msgs/msg/JointState for
``NAME/strain_stamped`` carrying 256 names took about 90 us per message (each name converted
every time), a tenth of a core at 1 kHz. These encoders build the constant part once; each
message is then the changing fields around it, published as bytes (``Publisher.publish``
accepts a serialised message).

Layout (OMG CDR, little endian, as rmw_fastrtps writes it): the 4-byte encapsulation header
``00 01 00 00``, then the fields in order, each aligned to its size relative to the byte
after that header; a string is a uint32 length counting its NUL, the bytes and the NUL; a
sequence is a uint32 count and its elements.
- JointState: header.stamp (int32 sec, uint32 nanosec), header.frame_id, name, position
  (8-aligned float64s), velocity, effort.
- std_msgs/msg/Float64MultiArray: layout.dim (one MultiArrayDimension: label, uint32 size,
  uint32 stride), layout.data_offset (uint32), data (8-aligned float64s).
The tests decode the bytes with rclpy's own type support.
"""

from __future__ import annotations

import struct

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR, little endian."""


def _pad(size: int, alignment: int) -> bytes:
    return b"\x00" * (-size % alignment)


def _sequence_head(body: bytearray, count: int) -> None:
    """A sequence's count, then the padding before 8-byte elements."""
    body += _pad(len(body), 4) + struct.pack("<I", count)
    body += _pad(len(body), 8) if count else b""


def _doubles(values: np.ndarray, k: int) -> bytes:
    data = np.ascontiguousarray(values, dtype="<f8")
    if data.size != k:
        raise ValueError(f"expected {k} values, got {data.size}")
    return data.tobytes()


def _string(body: bytearray, text: str) -> None:
    data = text.encode("utf-8") + b"\x00"
    body += _pad(len(body), 4) + struct.pack("<I", len(data)) + data


class StampedEncoder:
    """Serialised JointState messages for a fixed list of names, frame_id ''."""

    def __init__(self, names: list[str]) -> None:
        self.k = len(names)
        body = bytearray(8)  # the stamp's place
        _string(body, "")  # frame_id
        body += _pad(len(body), 4) + struct.pack("<I", self.k)
        for name in names:
            _string(body, name)
        _sequence_head(body, self.k)
        self._middle = bytes(body[8:])
        self._tail = struct.pack("<II", 0, 0)  # velocity, effort: empty

    def encode(self, stamp_ns: int, position: np.ndarray) -> bytes:
        """The message for a stamp [ns since the epoch] and ``k`` positions (strain)."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not -2**31 <= sec < 2**31:
            raise ValueError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time")
        return b"".join((ENCAPSULATION, struct.pack("<iI", sec, nanosec), self._middle,
                         _doubles(position, self.k), self._tail))


class VectorEncoder:
    """Serialised Float64MultiArray messages of ``k`` values whose ``dim[0]`` is labelled with
    the sensor names (size = stride = k, data_offset 0)."""

    def __init__(self, names: list[str]) -> None:
        self.k = len(names)
        body = bytearray(struct.pack("<I", 1))
        _string(body, ",".join(names))
        body += _pad(len(body), 4) + struct.pack("<III", self.k, self.k, 0)
        _sequence_head(body, self.k)
        self._head = ENCAPSULATION + bytes(body)

    def encode(self, values: np.ndarray) -> bytes:
        """The message for ``k`` values."""
        return self._head + _doubles(values, self.k)
