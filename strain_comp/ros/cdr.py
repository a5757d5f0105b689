"""The node's messages as serialised bytes (CDR), a batch at a time with numpy: the outputs
built around a prebuilt block (a message built in Python and converted by rclpy costs tens of
microseconds, mostly the part that never changes), the inputs read in bulk. The wire format
is the bag writer's (``strain_comp.io.cdr``); docs/results.md, "The node's CPU"."""

from __future__ import annotations

import numpy as np

from strain_comp.io import cdr


class RowEncoder:
    """Messages of one ``template`` but for ``k`` values at byte ``at`` (and the stamp)."""

    def __init__(self, template: bytes, at: int, k: int, dtype: str = "<f8", *,
                 stamped: bool = False) -> None:
        self.template = np.frombuffer(template, np.uint8)
        self.at, self.k, self.dtype, self.stamped = at, k, np.dtype(dtype), stamped

    @classmethod
    def scalar(cls, dtype: str) -> RowEncoder:
        """std_msgs/msg/Float64 (``<f8``) or Int8 (``i1``)."""
        return cls(cdr.ENCAPSULATION + bytes(np.dtype(dtype).itemsize), 4, 1, dtype)

    @classmethod
    def vector(cls, names: list[str]) -> RowEncoder:
        """std_msgs/msg/Float64MultiArray labelled as the bag writer's."""
        k = len(names)
        head = cdr.float64_multiarray_head([(",".join(names), k, k)], 0, k)
        return cls(head + bytes(8 * k), len(head), k)

    @classmethod
    def joint_state(cls, names: list[str]) -> RowEncoder:
        """sensor_msgs/msg/JointState of the names (frame_id '', velocity and effort empty)."""
        template, pos_at = cdr.joint_state_layout("", names)
        return cls(template, pos_at, len(names), stamped=True)

    def encode(self, rows: np.ndarray, stamps_ns: np.ndarray | None = None) -> list[bytes]:
        """The messages of ``rows`` (n x k values) and of their stamps [ns since the epoch]."""
        n = len(rows)
        values = np.ascontiguousarray(rows, dtype=self.dtype).reshape(n, self.k)
        out = np.empty((n, self.template.size), np.uint8)
        out[:] = self.template
        out[:, self.at:self.at + values.itemsize * self.k] = values.view(np.uint8).reshape(n, -1)
        if self.stamped:
            sec, nanosec = np.divmod(np.asarray(stamps_ns, dtype=np.int64), 1_000_000_000)
            if n and not (-2**31 <= sec.min() and sec.max() < 2**31):
                raise ValueError("a stamp does not fit builtin_interfaces/Time")
            out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
            out[:, 8:12] = nanosec.astype("<u4").view(np.uint8).reshape(n, 4)
        return [row.tobytes() for row in out]


class RowDecoder:
    """The sensors' values of serialised messages of the layout ``learn`` checked, in bulk."""

    def __init__(self) -> None:
        self._head = b""
        self._size = -1
        self._columns = np.zeros(0, np.intp)

    def learn(self, raw: bytes, n_values: int, columns: np.ndarray, values: np.ndarray
              ) -> None:
        """Learn ``raw``'s layout unless its ``values`` do not read back (big-endian, padded)."""
        if raw[:2] == cdr.ENCAPSULATION[:2] and len(raw) >= 8 * n_values:
            self._head, self._size = raw[:len(raw) - 8 * n_values], len(raw)
            self._columns = columns
            if not np.array_equal(self.rows([raw])[0], values, equal_nan=True):
                self._size = -1  # fits nothing

    def fits(self, raw: bytes) -> bool:
        return len(raw) == self._size and raw.startswith(self._head)

    def rows(self, raws: list[bytes]) -> np.ndarray:
        """The values of messages that fit, one row per message."""
        values = np.ndarray((len(raws), (self._size - len(self._head)) // 8), "<f8",
                            b"".join(raws), len(self._head), (self._size, 8))
        rows: np.ndarray = values[:, self._columns]
        return rows
