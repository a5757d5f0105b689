"""MCAP records of a bag being written: ``BagWriter``'s buffered messages merged in log-time
order into chunks assembled in bulk (zstd, CRC, message indexes); then the summary and the
footer."""

from __future__ import annotations

import itertools
import os
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Schema,
    Statistics,
    SummaryOffset,
)

from strain_comp._numba import njit
from strain_comp.errors import BagError
from strain_comp.io.atomic import AtomicFile
from strain_comp.io.bag.records import compact
from strain_comp.io.bag.schemas import LIBRARY, MAGIC, OFFERED_QOS, PROFILE, SCHEMAS


@dataclass
class Topic:
    """A topic of the bag: its channel id, message type and messages so far."""

    id: int
    type: str
    n: int = 0
    """Messages written so far (the next sequence number is n + 1)."""


@dataclass
class Pending:
    """Messages buffered since the last flush: times [ns], channels, sequences, payloads."""

    t_ns: list[np.ndarray] = field(default_factory=list)
    chan: list[np.ndarray] = field(default_factory=list)
    seq: list[np.ndarray] = field(default_factory=list)
    lengths: list[np.ndarray] = field(default_factory=list)
    payloads: list[np.ndarray] = field(default_factory=list)
    nbytes: int = 0


def _record(record: Any) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    end: Callable[[], bytes] = builder.end  # mcap leaves it unannotated; it returns the bytes
    return end()


_MSG_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("channel", "<u2"), ("seq", "<u4"),
                        ("log", "<u8"), ("pub", "<u8")])  # packed: 31 bytes


class Stream:
    """The output file: records written as they come, the summary kept for the end."""

    def __init__(self, path: Path, inputs: Sequence[str | os.PathLike[str]],
                 chunk_size: int) -> None:
        self.path = path
        self.chunk_size = chunk_size
        try:
            self._output = AtomicFile(path, inputs=inputs)
        except OSError as exc:
            raise BagError(f"{path}: cannot write ({exc.strerror})") from exc
        self.file = self._output.handle
        self.schemas: dict[str, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.counts: dict[int, int] = {}
        self.n_total = 0
        self.t0: int | None = None
        self.t1 = 0
        self.pos = 0
        self._write(MAGIC + _record(Header(profile=PROFILE, library=LIBRARY)))

    def _write(self, data: bytes) -> None:
        try:
            self.file.write(data)
        except OSError as exc:  # a full disk, ``ulimit -f``: the message names the file
            raise BagError(f"{self.path}: cannot write ({exc.strerror})") from None
        self.pos += len(data)

    def _declare(self, topics: Mapping[str, Topic]) -> None:
        """Schema and Channel records of topics not written yet (before their messages)."""
        for topic, entry in topics.items():
            if entry.id in self.channels:
                continue
            if entry.type not in self.schemas:
                schema = Schema(id=len(self.schemas) + 1, name=entry.type, encoding="ros2msg",
                                data=SCHEMAS[entry.type].encode())
                self.schemas[entry.type] = schema
                self._write(_record(schema))
            channel = Channel(id=entry.id, schema_id=self.schemas[entry.type].id, topic=topic,
                              message_encoding="cdr",
                              metadata={"offered_qos_profiles": OFFERED_QOS})
            self.channels[entry.id] = channel
            self.counts[entry.id] = 0
            self._write(_record(channel))

    def write_messages(self, topics: Mapping[str, Topic], p: Pending, *, final: bool,
                       before: int | None = None) -> Pending | None:
        """Write ``p`` merged in log-time order as chunks; unless ``final``, the last partial
        chunk and the messages at or after ``before`` [ns] are returned (sorted) instead."""
        self._declare(topics)
        t_ns = np.concatenate(p.t_ns)
        order = np.argsort(t_ns, kind="stable")
        t_ns = t_ns[order]
        chan = np.concatenate(p.chan)[order]
        seq = np.concatenate(p.seq)[order]
        plen = np.concatenate(p.lengths)
        poff = (np.concatenate(([0], np.cumsum(plen)[:-1])).astype(np.int64))[order]
        plen = plen[order]
        blob = _joined(p.payloads)
        n = t_ns.size if before is None or final else int(np.searchsorted(t_ns, before))
        rec_end = np.cumsum(31 + plen[:n])
        cuts = [0]
        while cuts[-1] < n:
            base = rec_end[cuts[-1] - 1] if cuts[-1] else 0
            nxt = int(np.searchsorted(rec_end, base + self.chunk_size, side="right"))
            cuts.append(min(max(nxt, cuts[-1] + 1), n))
        keep = None
        if not final:
            if len(cuts) > 1 and rec_end[-1] - (rec_end[cuts[-2] - 1] if cuts[-2] else 0) \
                    < self.chunk_size:  # a partial last chunk: keep it
                cuts.pop()
            a = cuts[-1]
            if a < t_ns.size:
                keep = Pending([t_ns[a:]], [chan[a:]], [seq[a:]], [plen[a:].copy()],
                               [compact(blob, poff[a:], plen[a:])[0]])
                keep.nbytes = keep.payloads[0].size
        for a, b in itertools.pairwise(cuts):
            if b == a:
                continue
            pieces, index = _chunk(t_ns[a:b], chan[a:b], seq[a:b], poff[a:b], plen[a:b], blob,
                                   self.pos)
            self.chunk_indexes.append(index)
            for piece in pieces:
                self._write(piece)
            for c, k in zip(*np.unique(chan[a:b], return_counts=True), strict=True):
                self.counts[int(c)] += int(k)
            self.n_total += b - a
            self.t0 = int(t_ns[a]) if self.t0 is None else min(self.t0, int(t_ns[a]))
            self.t1 = max(self.t1, int(t_ns[b - 1]))
        return keep

    def finish(self) -> None:
        """Data end, summary (schemas, channels, statistics, chunk indexes), footer; then
        the atomic rename."""
        with self._output.discarded_on_error():
            self._finish()
        self._output.commit()

    def _finish(self) -> None:
        self._write(_record(DataEnd(data_section_crc=0)))
        summary_start = self.pos
        pos = self.pos
        summary: list[bytes] = []
        offsets: list[SummaryOffset] = []
        stats = Statistics(message_count=self.n_total, schema_count=len(self.schemas),
                           channel_count=len(self.channels), attachment_count=0,
                           metadata_count=0, chunk_count=len(self.chunk_indexes),
                           message_start_time=self.t0 or 0, message_end_time=self.t1,
                           channel_message_counts=self.counts)
        for opcode, group in ((Opcode.SCHEMA, list(self.schemas.values())),
                              (Opcode.CHANNEL, list(self.channels.values())),
                              (Opcode.STATISTICS, [stats]),
                              (Opcode.CHUNK_INDEX, self.chunk_indexes)):
            data = b"".join(_record(r) for r in group)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=pos,
                                         group_length=len(data)))
            summary.append(data)
            pos += len(data)
        summary_offset_start = pos
        summary += [_record(o) for o in offsets]
        summary_data = b"".join(summary)
        crc = zlib.crc32(summary_data)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start,
                                     summary_offset_start), crc)
        self._write(summary_data + _record(Footer(summary_start=summary_start,
                                                  summary_offset_start=summary_offset_start,
                                                  summary_crc=crc)) + MAGIC)

    def abort(self) -> None:
        """Drop the temporary file (nothing replaces the target)."""
        self._output.discard()


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """``parts`` joined, each let go once copied (``parts`` emptied): a peak of one copy."""
    if len(parts) == 1:
        return parts.pop()
    out = np.empty(sum(part.size for part in parts), np.uint8)
    at = 0
    parts.reverse()
    while parts:
        part = parts.pop()
        out[at:at + part.size] = part
        at += part.size
    return out


@njit
def _fill_records(raw: np.ndarray, head: np.ndarray, start: np.ndarray, poff: np.ndarray,
                  plen: np.ndarray, blob: np.ndarray) -> None:
    """Message i's record header and payload to ``raw[start[i]:]`` (a numpy fancy-index
    scatter was 3-5x slower)."""
    width = head.shape[1]
    for i in range(start.size):
        s = start[i]
        for j in range(width):
            raw[s + j] = head[i, j]
        s += width
        o, n = poff[i], plen[i]
        if n > 64:  # a long payload (a DiagnosticArray) as one block copy
            raw[s:s + n] = blob[o:o + n]
        else:
            for j in range(n):
                raw[s + j] = blob[o + j]


def _chunk(t_ns: np.ndarray, chan: np.ndarray, seq: np.ndarray, poff: np.ndarray,
           plen: np.ndarray, blob: np.ndarray, pos: int) -> tuple[list[bytes], ChunkIndex]:
    """One Chunk record plus its MessageIndex records, assembled with numpy."""
    n = t_ns.size
    rec_len = 31 + plen
    start = np.concatenate(([0], np.cumsum(rec_len)[:-1])).astype(np.int64)
    raw = np.empty(int(rec_len.sum()), np.uint8)
    head = np.empty(n, _MSG_HEADER)
    head["op"] = Opcode.MESSAGE
    head["len"] = 22 + plen
    head["channel"] = chan
    head["seq"] = seq
    head["log"] = t_ns
    head["pub"] = t_ns
    _fill_records(raw, head.view(np.uint8).reshape(n, 31), start, poff, plen, blob)
    data = raw.data  # the records as they are (a memoryview), not a copy
    compressed = zstandard.ZstdCompressor(level=3).compress(data)
    chunk = Chunk(message_start_time=int(t_ns[0]), message_end_time=int(t_ns[-1]),
                  uncompressed_size=raw.size, uncompressed_crc=zlib.crc32(data),
                  compression="zstd", data=compressed)
    pieces = [_record(chunk)]
    index_pos = pos + len(pieces[0])
    index_offsets: dict[int, int] = {}
    for c in np.unique(chan):
        sel = chan == c
        entries = np.empty((int(sel.sum()), 2), "<u8")
        entries[:, 0] = t_ns[sel]
        entries[:, 1] = start[sel]
        body = entries.tobytes()
        index_offsets[int(c)] = index_pos
        piece = (struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + len(body), int(c), len(body))
                 + body)
        pieces.append(piece)
        index_pos += len(piece)
    index = ChunkIndex(message_start_time=chunk.message_start_time,
                       message_end_time=chunk.message_end_time, chunk_start_offset=pos,
                       chunk_length=len(pieces[0]), message_index_offsets=index_offsets,
                       message_index_length=index_pos - pos - len(pieces[0]),
                       compression="zstd", compressed_size=len(compressed),
                       uncompressed_size=raw.size)
    return pieces, index


