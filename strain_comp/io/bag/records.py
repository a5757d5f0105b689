"""MCAP records located in bulk, and the collector of schemas, channels and message spans
that the walk fills and the decoder reads."""

from __future__ import annotations

import io
import struct
from collections.abc import Callable

import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema

from strain_comp._numba import njit
from strain_comp.io.bag.schemas import MAX_TIME_S

PARSE_ERRORS = (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError,
                MemoryError, IndexError, KeyError)
"""What the mcap record parsers raise on damaged content."""

MAX_LOG_NS = MAX_TIME_S * 10**9
"""The latest log time kept [ns]: a later (or negative) one is skipped and counted."""


@njit
def scan_records(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.int64]:
    """Walk the MCAP records of a decompressed chunk."""
    n = buf.shape[0]
    cap = n // 9 + 1
    ops = np.empty(cap, np.uint8)
    starts = np.empty(cap, np.int64)
    lens = np.empty(cap, np.int64)
    pos = np.int64(0)
    count = 0
    while pos + 9 <= n:
        length = np.int64(0)
        for b in range(8):
            length |= np.int64(buf[pos + 1 + b]) << (8 * b)
        if length < 0 or pos + 9 + length > n:
            break
        ops[count] = buf[pos]
        starts[count] = pos + 9
        lens[count] = length
        count += 1
        pos += 9 + length
    return ops[:count], starts[:count], lens[:count], pos


@njit
def compact(buf: np.ndarray, starts: np.ndarray, lens: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """The spans ``buf[starts[i]:starts[i] + lens[i]]`` in one new buffer; their starts."""
    out = np.empty(lens.sum(), np.uint8)
    new = np.empty(starts.shape[0], np.int64)
    pos = 0
    for i in range(starts.shape[0]):
        new[i] = pos
        out[pos:pos + lens[i]] = buf[starts[i]:starts[i] + lens[i]]
        pos += lens[i]
    return out, new


def gather(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """Bytes ``buf[starts[i] : starts[i] + width]`` side by side."""
    return buf[starts[:, None] + np.arange(width)]


class Collector:
    """Accumulates schemas, channels and message locations from one or more files."""

    def __init__(self, topics: set[str] | None) -> None:
        self.topics = topics
        self.schemas: dict[tuple[int, int], Schema] = {}
        self.channels: dict[tuple[int, int], Channel] = {}
        self.blocks: list[np.ndarray] = []
        self.block_file: list[int] = []
        self.msg_block: list[np.ndarray] = []
        self.msg_channel: list[np.ndarray] = []
        self.msg_time: list[np.ndarray] = []
        self.msg_start: list[np.ndarray] = []
        self.msg_len: list[np.ndarray] = []
        self.problems: list[str] = []
        self.held = 0  # message bytes held undecoded in ``blocks``
        self.collected = 0  # message bytes collected since the start (the whole-bag budget)
        self.file_index = 0
        self.chunk_start = 0  # the latest chunk start read [ns]: earlier messages are all in

    def add_block(self, buf: np.ndarray, ops: np.ndarray, starts: np.ndarray,
                  lens: np.ndarray, where: str) -> None:
        """Register the records of one decompressed chunk (or of loose top-level messages)."""
        for i in np.flatnonzero((ops == Opcode.SCHEMA) | (ops == Opcode.CHANNEL)):
            self.add_small_record(int(ops[i]), buf[starts[i]:starts[i] + lens[i]].tobytes(),
                                  where)
        is_msg = (ops == Opcode.MESSAGE) & (lens >= 22)
        if not is_msg.any():
            return
        s = starts[is_msg]
        head = gather(buf, s, 22)
        channel = head[:, 0:2].copy().view("<u2")[:, 0].astype(np.int32)
        wanted = np.array([self._wanted(int(c)) for c in np.unique(channel)], bool)
        keep = wanted[np.searchsorted(np.unique(channel), channel)]
        if not keep.any():
            return
        # only the wanted payloads are kept: the decompressed chunk is released
        payload, start = compact(buf, s[keep] + 22, lens[is_msg][keep] - 22)
        block = len(self.blocks)
        self.blocks.append(payload)
        self.held += payload.size
        self.collected += payload.size
        self.block_file.append(self.file_index)
        self.msg_block.append(np.full(start.shape, block, np.int32))
        self.msg_channel.append(channel[keep])
        self.msg_time.append(head[keep, 6:14].copy().view("<u8")[:, 0].astype(np.int64))
        self.msg_start.append(start)
        self.msg_len.append(lens[is_msg][keep] - 22)

    def _wanted(self, channel_id: int) -> bool:
        """Keep the messages of ``channel_id``? Those of a channel not yet seen too."""
        channel = self.channels.get((self.file_index, channel_id))
        return self.topics is None or channel is None or channel.topic in self.topics

    def add_small_record(self, opcode: int, content: bytes, where: str) -> None:
        """Register a Schema or Channel record; an unreadable one is a line in ``problems``."""
        try:
            stream = ReadDataStream(io.BytesIO(content))
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(stream)
                self.schemas[(self.file_index, schema.id)] = schema
            else:
                channel = Channel.read(stream)
                self.channels[(self.file_index, channel.id)] = channel
        except PARSE_ERRORS as exc:
            self.problems.append(f"{where}: unreadable {Opcode(opcode).name} record ({exc})")


def add_loose(col: Collector, msgs: list[Message], name: str) -> None:
    """Messages stored outside chunks (in log-time order), packed into one block."""
    builder = RecordBuilder()
    for m in msgs:
        m.write(builder)
    col.chunk_start = max(col.chunk_start, max(m.log_time for m in msgs))
    end: Callable[[], bytes] = builder.end  # mcap leaves it unannotated; it returns the bytes
    buf = np.frombuffer(end(), dtype=np.uint8)
    ops, starts, lens, _ = scan_records(buf)
    col.add_block(buf, ops, starts, lens, name)
