"""The node's per-tick outputs as serialised bytes (CDR), built around a prebuilt block.

A message built in Python and converted by rclpy costs tens of microseconds; for an array
most of it is the part that never changes: a sensor_msgs/msg/JointState for
``NAME/strain_stamped`` carrying 256 names took about 90 us per message (each name converted
every time), a tenth of a core at 1 kHz. These encoders build the constant part once; each
message is then the changing fields around it, published as bytes (``Publisher.publish``
accepts a serialised message).

The wire format is the bag writer's (``strain_comp.io.cdr``, byte-equal to rosbags'
serialiser): the constant blocks are cut from its ``joint_state_layout`` and
``float64_multiarray_head``. The tests decode the bytes with rclpy's own type support and
compare them with ``strain_comp.io.cdr.message_encoder``'s.
"""

from __future__ import annotations

import numpy as np

from strain_comp.io import cdr


def _doubles(values: np.ndarray, k: int) -> bytes:
    data = np.ascontiguousarray(values, dtype="<f8")
    if data.size != k:
        raise ValueError(f"expected {k} values, got {data.size}")
    return data.tobytes()


class StampedEncoder:
    """Serialised JointState messages for a fixed list of names, frame_id '', velocity and
    effort empty."""

    def __init__(self, names: list[str]) -> None:
        self.k = len(names)
        template, pos_at, _ = cdr.joint_state_layout("", names, velocity=False)
        self._middle = template[4 + cdr.STAMP.size:pos_at]  # frame_id .. position's head
        self._tail = template[pos_at + 8 * self.k:]  # velocity, effort

    def encode(self, stamp_ns: int, position: np.ndarray) -> bytes:
        """The message for a stamp [ns since the epoch] and ``k`` positions (strain)."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not -2**31 <= sec < 2**31:
            raise ValueError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time")
        return b"".join((cdr.ENCAPSULATION, cdr.STAMP.pack(sec, nanosec), self._middle,
                         _doubles(position, self.k), self._tail))


class ScalarEncoder:
    """Serialised messages of one number (std_msgs/msg/Float64: ``<f8``, Int8: ``i1``)."""

    def __init__(self, dtype: str) -> None:
        self.dtype = np.dtype(dtype)

    def encode(self, values: np.ndarray) -> list[bytes]:
        """One message per value."""
        data = np.ascontiguousarray(values, dtype=self.dtype).reshape(-1)
        rows = np.empty((data.size, len(cdr.ENCAPSULATION) + self.dtype.itemsize), np.uint8)
        rows[:, :len(cdr.ENCAPSULATION)] = np.frombuffer(cdr.ENCAPSULATION, np.uint8)
        rows[:, len(cdr.ENCAPSULATION):] = data.view(np.uint8).reshape(data.size, -1)
        return [row.tobytes() for row in rows]


class VectorEncoder:
    """Serialised Float64MultiArray messages of ``k`` values whose ``dim[0]`` is labelled with
    the sensor names (size = stride = k, data_offset 0), as the bag writer's
    ``write_float64_array``."""

    def __init__(self, names: list[str]) -> None:
        self.k = len(names)
        self._head = cdr.float64_multiarray_head([(",".join(names), self.k, self.k)], 0,
                                                 self.k)

    def encode(self, values: np.ndarray) -> bytes:
        """The message for ``k`` values."""
        return self._head + _doubles(values, self.k)
