"""``NAME/strain_stamped`` as serialised bytes: sensor_msgs/msg/JointState in CDR.

A JointState carrying the names of a 256-sensor array costs rclpy about 90 us to convert and
serialise (each name is converted on every message); at 1 kHz that is a tenth of a core. The
names never change, so this encoder builds everything after the stamp up to the positions
once, and each message is the stamp, that block, the positions and two empty sequences,
published as bytes (``Publisher.publish`` accepts a serialised message).

Layout (OMG CDR, little endian, as rmw_fastrtps writes it): the 4-byte encapsulation header
``00 01 00 00``, then, aligned relative to the byte after it: header.stamp (int32 sec, uint32
nanosec), header.frame_id (uint32 length with the NUL, the bytes, NUL), name (uint32 count,
each a string as above, 4-aligned), position (uint32 count, 8-aligned float64s), velocity
and effort (uint32 count 0). The test decodes the bytes with rclpy's own type support.
"""

from __future__ import annotations

import struct

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR, little endian."""


def _pad(size: int, alignment: int) -> bytes:
    return b"\x00" * (-size % alignment)


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
        body += _pad(len(body), 4) + struct.pack("<I", self.k)
        body += _pad(len(body), 8) if self.k else b""
        self._middle = bytes(body[8:])
        self._tail = struct.pack("<II", 0, 0)  # velocity, effort: empty

    def encode(self, stamp_ns: int, position: np.ndarray) -> bytes:
        """The message for a stamp [ns since the epoch] and ``k`` positions (strain)."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        values = np.ascontiguousarray(position, dtype="<f8")
        if values.size != self.k:
            raise ValueError(f"expected {self.k} positions, got {values.size}")
        if not -2**31 <= sec < 2**31:
            raise ValueError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time")
        return b"".join((ENCAPSULATION, struct.pack("<iI", sec, nanosec), self._middle,
                         values.tobytes(), self._tail))
