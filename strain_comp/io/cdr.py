"""CDR payloads of the message types strain_comp writes, serialised by ``mcap_ros2``'s
encoder from ``SCHEMAS``. A fixed-layout message (Float64MultiArray, JointState,
Temperature) is a template the library serialises once; where its values sit is where a
second serialisation with other values differs from it. DiagnosticArrays of many messages
at once: the layout compiled into operations a compiled loop (``_place``) walks."""

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

STAMP = struct.Struct("<iI")
"""builtin_interfaces/Time (bytes 4..12 of a message that starts with a header)."""
_PROBE = struct.unpack("<d", bytes(range(1, 9)))[0]
"""A float64 none of whose bytes is zero: the first byte that differs where it replaces a 0."""


@functools.cache
def message_encoder(kind: str) -> Callable[[Mapping[str, Any]], bytes]:
    """The encoder of a message type for messages given as nested dicts."""
    encoder: Callable[[Mapping[str, Any]], bytes] = serialize_dynamic(kind, SCHEMAS[kind])[kind]
    return encoder


def _header(sec: int, nanosec: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id}


def _offset(a: bytes, b: bytes) -> int:
    """The first byte where two serialisations of one layout differ."""
    return next(i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)


def float64_multiarray_head(dims: Sequence[tuple[str, int, int]], data_offset: int,
                            n: int) -> bytes:
    """The bytes of a Float64MultiArray of ``n`` values before its first value."""
    payload = message_encoder("std_msgs/msg/Float64MultiArray")({
        "layout": {"dim": [{"label": label, "size": size, "stride": stride}
                           for label, size, stride in dims], "data_offset": data_offset},
        "data": [0.0] * n})
    return payload[:len(payload) - 8 * n]


def joint_state_layout(frame_id: str, names: Sequence[str]) -> tuple[bytes, int]:
    """The template of every sensor_msgs/msg/JointState message for fixed names (velocity and
    effort empty), and where its first position sits."""
    encode = message_encoder("sensor_msgs/msg/JointState")
    n = len(names)

    def message(position: float) -> bytes:
        return encode({"header": _header(0, 0, frame_id), "name": list(names),
                       "position": [position] * n, "velocity": [], "effort": []})

    template = message(0.0)
    if not n:  # no values: position's count is followed by velocity's and effort's
        return template, len(template) - 8
    return template, _offset(template, message(_PROBE))


def temperature_layout(frame_id: str, variance: float) -> tuple[bytes, int]:
    """The template of every sensor_msgs/msg/Temperature message of one frame and variance."""
    encode = message_encoder("sensor_msgs/msg/Temperature")

    def message(value: float) -> bytes:
        return encode({"header": _header(0, 0, frame_id), "temperature": value,
                       "variance": variance})

    template = message(0.0)
    return template, _offset(template, message(_PROBE))


Text = str | np.ndarray
"""A text of ``diagnostic_arrays``: one for every message, or a column of one per message:
byte strings (``np.bytes_``, UTF-8) or integers (written as ``str(n)``)."""
Status = tuple[np.ndarray, str, Text, str, Sequence[tuple[str, Text]]]
"""(levels (uint8 per message), name, message, hardware_id, [(key, value), ...])."""
_CONST, _CONST_ALIGNED, _TEXT, _BYTE, _STAMP, _INT = range(6)
"""``_place`` operations: constant bytes (as they are, or 4-aligned), a column's text, byte
or integer (as text), the stamp."""
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
    """Walk ``ops`` (kind, a, b) for every message: the lengths while ``out`` is empty, else
    the payloads into ``out``."""
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
    """DiagnosticArray payloads: message k stamped ``t_ns[k]`` (integer ns, >= 0) holds
    ``statuses`` with each column's k-th entry; the payloads joined (uint8), their lengths."""
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
