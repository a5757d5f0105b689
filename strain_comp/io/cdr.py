"""CDR payloads of the types strain_comp writes: fixed layouts as a template ``mcap_ros2``'s
encoder serialises once (``RowEncoder``, for bags and the node); DiagnosticArrays of many
messages at once, the layout compiled into operations a numba loop (``_place``) walks."""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from mcap_ros2._dynamic import serialize_dynamic

from strain_comp._numba import njit
from strain_comp.io.bag.schemas import SCHEMAS

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR little endian, no options."""

_HEADER = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
_PROBE = struct.unpack("<d", bytes(range(1, 9)))[0]
"""A float64 none of whose bytes is zero: the first byte that differs where it replaces a 0."""


@functools.cache
def message_encoder(kind: str) -> Callable[[Mapping[str, Any]], bytes]:
    """The encoder of a message type for messages given as nested dicts."""
    encoder: Callable[[Mapping[str, Any]], bytes] = serialize_dynamic(kind, SCHEMAS[kind])[kind]
    return encoder


def _layout(kind: str, message: Callable[[float], dict[str, Any]]) -> tuple[bytes, int]:
    """A fixed-layout message's template (values 0) and its first value's byte offset."""
    encode = message_encoder(kind)
    template, probed = encode(message(0.0)), encode(message(_PROBE))
    at = next((i for i, (x, y) in enumerate(zip(template, probed, strict=True)) if x != y),
              len(template))  # the first byte a second serialisation changes; none: no values
    return template, at


class RowEncoder:
    """One message per row: ``template`` with k values at ``at`` (stamped: bytes 4..12)."""

    def __init__(self, template: bytes, at: int, k: int, dtype: str = "<f8", *,
                 stamped: bool = False) -> None:
        self.template = np.frombuffer(template, np.uint8)
        self.at, self.k, self.dtype, self.stamped = at, k, np.dtype(dtype), stamped

    @classmethod
    def scalar(cls, dtype: str) -> RowEncoder:
        """std_msgs/msg/Float64 (``<f8``) or Int8 (``i1``)."""
        return cls(ENCAPSULATION + bytes(np.dtype(dtype).itemsize), 4, 1, dtype)

    @classmethod
    def vector(cls, names: Sequence[str]) -> RowEncoder:
        """std_msgs/msg/Float64MultiArray, ``dim[0]`` labelled with the names, offset 0."""
        k = len(names)
        payload = message_encoder("std_msgs/msg/Float64MultiArray")({
            "layout": {"dim": [{"label": ",".join(names), "size": k, "stride": k}],
                       "data_offset": 0}, "data": [0.0] * k})
        return cls(payload, len(payload) - 8 * k, k)

    @classmethod
    def joint_state(cls, names: Sequence[str]) -> RowEncoder:
        """sensor_msgs/msg/JointState of the names (frame_id '', velocity and effort empty)."""
        template, at = _layout("sensor_msgs/msg/JointState", lambda value: {
            "header": _HEADER, "name": list(names), "position": [value] * len(names),
            "velocity": [], "effort": []})
        return cls(template, at, len(names), stamped=True)

    @classmethod
    def temperature(cls) -> RowEncoder:
        """sensor_msgs/msg/Temperature (frame_id '', variance 0)."""
        template, at = _layout("sensor_msgs/msg/Temperature", lambda value: {
            "header": _HEADER, "temperature": value, "variance": 0.0})
        return cls(template, at, 1, stamped=True)

    def rows(self, values: np.ndarray, stamps_ns: np.ndarray | None = None) -> np.ndarray:
        """One uint8 row per message of ``values`` (n x k) and stamps [ns since the epoch]."""
        n = len(values)
        values = np.ascontiguousarray(values, dtype=self.dtype).reshape(n, self.k)
        out = np.empty((n, self.template.size), np.uint8)
        out[:] = self.template
        width = values.itemsize * self.k
        out[:, self.at:self.at + width] = values.view(np.uint8).reshape(n, width)
        if self.stamped:
            sec, nanosec = np.divmod(np.asarray(stamps_ns, dtype=np.int64), 1_000_000_000)
            if n and not (-2**31 <= sec.min() and sec.max() < 2**31):
                raise ValueError("a stamp does not fit builtin_interfaces/Time")
            out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
            out[:, 8:12] = nanosec.astype("<u4").view(np.uint8).reshape(n, 4)
        return out

    def encode(self, values: np.ndarray, stamps_ns: np.ndarray | None = None) -> list[bytes]:
        """``rows`` as one bytes object per message."""
        return [row.tobytes() for row in self.rows(values, stamps_ns)]


Text = str | np.ndarray
"""One text for every message, or a column per message (UTF-8 ``np.bytes_``, or integers)."""
Status = tuple[np.ndarray, str, Text, str, Sequence[tuple[str, Text]]]
"""(levels (uint8 per message), name, message, hardware_id, [(key, value), ...])."""
_CONST, _CONST_ALIGNED, _TEXT, _BYTE, _STAMP, _INT = range(6)
"""``_place`` operations: constant bytes (4-aligned or not), a column's text, byte, integer."""
_U32 = struct.Struct("<I")


@njit
def _digits(value: int, digits: np.ndarray) -> int:
    """``str(value)``'s ASCII digits into ``digits``, last first; their count."""
    negative = value < 0
    value = -value if negative else value
    n = 0
    while True:
        digits[n] = 48 + value % 10
        value //= 10
        n += 1
        if value == 0:
            break
    if negative:
        digits[n] = 45
        n += 1
    return n


@njit
def _place(ops: np.ndarray, pool: np.ndarray, texts: np.ndarray, text_len: np.ndarray,
           byte_cols: np.ndarray, int_cols: np.ndarray, t_ns: np.ndarray,
           out: np.ndarray, lengths: np.ndarray) -> None:
    """Walk ``ops`` per message: the lengths while ``out`` is empty, else the payloads."""
    write = out.size > 0
    at = 0
    digits = np.zeros((int_cols.shape[0], 24), np.uint8)  # each integer column's latest
    n_digits = np.zeros(int_cols.shape[0], np.int64)
    for k in range(t_ns.size):
        begin = at
        for j in range(ops.shape[0]):
            kind, a, b = ops[j, 0], ops[j, 1], ops[j, 2]
            if kind != _CONST and kind != _BYTE:
                at += (4 - (at - begin) % 4) % 4
            if kind == _CONST or kind == _CONST_ALIGNED:
                if write:
                    out[at:at + b - a] = pool[a:b]
                at += b - a
            elif kind == _BYTE:
                if write:
                    out[at] = byte_cols[a, k]
                at += 1
            elif kind == _STAMP:
                if write:
                    sec, nanosec = t_ns[k] // 1_000_000_000, t_ns[k] % 1_000_000_000
                    for i in range(4):
                        out[at + i] = (sec >> (8 * i)) & 0xFF
                        out[at + 4 + i] = (nanosec >> (8 * i)) & 0xFF
                at += 8
            else:
                if kind == _TEXT:
                    n = text_len[a, k]
                elif k == 0 or int_cols[a, k] != int_cols[a, k - 1]:  # counters seldom move
                    n = n_digits[a] = _digits(int_cols[a, k], digits[a])
                else:
                    n = n_digits[a]
                if write:
                    for i in range(4):
                        out[at + i] = ((n + 1) >> (8 * i)) & 0xFF
                    if kind == _TEXT:
                        out[at + 4:at + 4 + n] = texts[a, k, :n]
                    else:
                        for i in range(n):
                            out[at + 4 + i] = digits[a, n - 1 - i]
                    out[at + 4 + n] = 0
                at += n + 5
        lengths[k] = at - begin


def diagnostic_arrays(t_ns: np.ndarray, frame_id: str, statuses: Sequence[Status]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """DiagnosticArray payloads (message k: each column's k-th entry) joined; their lengths."""
    k = t_ns.size
    ops: list[tuple[int, int, int]] = []
    pool = bytearray()
    texts: list[np.ndarray] = []
    ints: list[np.ndarray] = []
    levels: list[np.ndarray] = []

    def const(data: bytes, kind: int) -> None:
        ops.append((kind, len(pool), len(pool) + len(data)))
        pool.extend(data)

    def text(value: Text) -> None:
        if isinstance(value, str):
            raw = value.encode()
            const(_U32.pack(len(raw) + 1) + raw + b"\0", _CONST_ALIGNED)
        elif value.dtype.kind in "iu":
            ops.append((_INT, len(ints), 0))
            ints.append(value)
        else:
            ops.append((_TEXT, len(texts), 0))
            texts.append(value)

    const(ENCAPSULATION, _CONST)
    ops.append((_STAMP, 0, 0))
    text(frame_id)
    const(_U32.pack(len(statuses)), _CONST_ALIGNED)
    for level, name, message, hardware_id, values in statuses:
        ops.append((_BYTE, len(levels), 0))
        levels.append(level)
        for value in (name, message, hardware_id):
            text(value)
        const(_U32.pack(len(values)), _CONST_ALIGNED)
        for key, value in values:
            text(key)
            text(value)
    args = (np.array(ops, np.int64), np.frombuffer(bytes(pool), np.uint8), *_columns(texts, k),
            np.array(levels, np.uint8).reshape(len(levels), k),
            np.array(ints, np.int64).reshape(len(ints), k), np.asarray(t_ns, np.int64))
    lengths = np.zeros(k, np.int64)
    _place(*args, np.zeros(0, np.uint8), lengths)
    blob = np.zeros(int(lengths.sum()), np.uint8)
    _place(*args, blob, lengths)
    return blob, lengths


def _columns(texts: list[np.ndarray], k: int) -> tuple[np.ndarray, np.ndarray]:
    """Byte-string columns as one (columns, k, width) uint8 array, and each entry's length."""
    width = max([t.dtype.itemsize for t in texts], default=1)
    rows = np.zeros((len(texts), k, width), np.uint8)
    for i, column in enumerate(texts):
        size = column.dtype.itemsize
        rows[i, :, :size] = np.ascontiguousarray(column).view(np.uint8).reshape(k, size)
    lengths = (np.array([np.char.str_len(c) for c in texts], np.int64) if texts
               else np.zeros((0, k), np.int64))
    return rows, lengths
