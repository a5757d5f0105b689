"""MCAP bag writing: ``BagWriter`` buffers messages (``cdr.RowEncoder`` rows); ``Stream``
writes them in log-time order into chunks assembled in bulk (zstd, CRC, message indexes),
then the summary and the footer: one fully indexed ros2-profile file."""

from __future__ import annotations

import itertools
import os
import struct
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
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
from strain_comp.io import cdr
from strain_comp.io.atomic import AtomicFile, check_output
from strain_comp.io.bag.records import compact
from strain_comp.io.bag.schemas import (
    CHUNK_SIZE,
    LIBRARY,
    MAGIC,
    MAX_TIME_S,
    OFFERED_QOS,
    PROFILE,
    SCHEMAS,
    Status,
)


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

    def merged(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """In log-time order: times, channels, sequences, payload offsets and lengths."""
        t_ns = np.concatenate(self.t_ns)
        order = np.argsort(t_ns, kind="stable")
        plen = np.concatenate(self.lengths)
        poff = np.concatenate(([0], np.cumsum(plen)[:-1])).astype(np.int64)
        return (t_ns[order], np.concatenate(self.chan)[order], np.concatenate(self.seq)[order],
                poff[order], plen[order])


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
        """``p`` as chunks; unless ``final``, return the rest (a partial chunk, ``before`` on)."""
        self._declare(topics)
        t_ns, chan, seq, poff, plen = p.merged()
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
        """Data end, summary (schemas, channels, statistics, chunk indexes), footer, rename."""
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
        self._output.commit()

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
    """Message i's record header and payload to ``raw[start[i]:]`` (numpy: 3-5x slower)."""
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


def _ns(t: npt.ArrayLike) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if not np.isfinite(t).all() or (t < 0).any():
        raise BagError("message times must be finite and >= 0 s")
    if (t > MAX_TIME_S).any():
        raise BagError(f"message times beyond {MAX_TIME_S} s (2038-01-19) cannot be stored "
                       f"(got {t.max():.6g} s; epoch milli- or nanoseconds?)")
    return np.round(t * 1e9).astype(np.int64)


class BagWriter:
    """Write a ros2-profile MCAP bag; use as a context manager."""

    def __init__(self, path: str | Path, *, chunk_size: int = CHUNK_SIZE,
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
        """A writer for ``path``; nothing is written before the first ``flush`` or the exit."""
        self.path = Path(path)
        self.chunk_size = chunk_size
        self.inputs = list(inputs)
        check_output(self.path, self.inputs)  # refused before anything is computed
        self._topics: dict[str, Topic] = {}
        self._pending = Pending()
        self._closed = False
        self._out: Stream | None = None

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Give up: delete the temporary file, leave ``path`` as it was."""
        self._closed = True
        if self._out is not None:
            self._out.abort()

    def _add(self, topic: str, kind: str, t_ns: np.ndarray,
             rows: np.ndarray | tuple[np.ndarray, np.ndarray]) -> None:
        if self._closed:
            raise BagError(f"{self.path}: writer already closed")
        if not topic.startswith("/"):
            raise BagError(f"topic {topic!r} must start with '/'")
        entry = self._topics.setdefault(topic, Topic(len(self._topics) + 1, kind))
        if entry.type != kind:
            raise BagError(f"topic {topic} already holds {entry.type}, not {kind}")
        if isinstance(rows, tuple):
            blob, lengths = rows
        else:
            lengths = np.full(rows.shape[0], rows.shape[1], np.int64)
            blob = rows.reshape(-1)
        if lengths.size != t_ns.size:
            raise BagError(f"{topic}: {t_ns.size} times but {lengths.size} values")
        p = self._pending
        p.t_ns.append(t_ns)
        p.chan.append(np.full(t_ns.size, entry.id, np.uint16))
        p.seq.append(np.arange(entry.n + 1, entry.n + 1 + t_ns.size, dtype=np.uint32))
        p.lengths.append(lengths)
        p.payloads.append(blob)
        entry.n += t_ns.size

    def write_float64(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        v = np.asarray(values, dtype="<f8").reshape(-1)
        self._add(topic, "std_msgs/msg/Float64", _ns(t), cdr.RowEncoder.scalar("<f8").rows(v))

    def write_int8(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        v = np.asarray(values)
        if v.size and (np.abs(v) > 128).any():
            raise BagError(f"{topic}: Int8 values out of range")
        v = v.astype(np.int8).reshape(-1)
        self._add(topic, "std_msgs/msg/Int8", _ns(t), cdr.RowEncoder.scalar("i1").rows(v))

    def write_float64_array(self, topic: str, t: npt.ArrayLike, values2d: npt.ArrayLike,
                            labels: Sequence[str]) -> None:
        """Add std_msgs/msg/Float64MultiArray messages, one per row."""
        v = np.asarray(values2d, dtype="<f8")
        if v.ndim != 2 or v.shape[1] != len(labels):
            raise BagError(f"{topic}: values must be (n, {len(labels)}) for {len(labels)} labels")
        if any("," in x for x in labels):
            raise BagError(f"{topic}: sensor labels must not contain commas")
        self._add(topic, "std_msgs/msg/Float64MultiArray", _ns(t),
                  cdr.RowEncoder.vector(labels).rows(v))

    def write_joint_state(self, topic: str, t: npt.ArrayLike, names: Sequence[str],
                          position: npt.ArrayLike) -> None:
        """Add sensor_msgs/msg/JointState messages, one per row, stamped with the log time."""
        t_ns = _ns(t)  # refuses stamps past int32 seconds
        p = np.asarray(position, dtype="<f8").reshape(t_ns.size, len(names))
        self._add(topic, "sensor_msgs/msg/JointState", t_ns,
                  cdr.RowEncoder.joint_state(names).rows(p, t_ns))

    def write_temperature(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        """Add sensor_msgs/msg/Temperature messages, header stamp = log time."""
        t_ns = _ns(t)
        v = np.asarray(values, dtype="<f8").reshape(-1)
        if v.size != t_ns.size:
            raise BagError(f"{topic}: {t_ns.size} times but {v.size} values")
        self._add(topic, "sensor_msgs/msg/Temperature", t_ns,
                  cdr.RowEncoder.temperature().rows(v, t_ns))

    def write_diagnostics(self, t: npt.ArrayLike, statuses: Sequence[Sequence[Status]], *,
                          topic: str = "/diagnostics") -> None:
        """Add diagnostic_msgs/msg/DiagnosticArray messages, one per time."""
        t_ns = _ns(t)
        rows = []
        for i, st in zip(range(t_ns.size), statuses, strict=False):
            blob, _ = cdr.diagnostic_arrays(t_ns[i:i + 1], "", [
                (np.array([level], np.uint8), name, message, "",
                 [(str(a), str(b)) for a, b in values.items()])
                for name, level, message, values in st])
            rows.append(blob)
        self._add(topic, "diagnostic_msgs/msg/DiagnosticArray", t_ns,
                  (np.concatenate([np.zeros(0, np.uint8), *rows]),
                   np.array([row.size for row in rows], np.int64)))

    def write_diagnostic_payloads(self, t: npt.ArrayLike, blob: np.ndarray,
                                  lengths: np.ndarray, *, topic: str = "/diagnostics") -> None:
        """Add DiagnosticArray messages already encoded (``diagnostic_arrays``)."""
        self._add(topic, "diagnostic_msgs/msg/DiagnosticArray", _ns(t), (blob, lengths))

    def flush(self, *, before: float | None = None) -> None:
        """Write the buffered messages as complete chunks; the rest stays buffered."""
        if self._closed:
            raise BagError(f"{self.path}: writer already closed")
        self._write_pending(final=False, before=None if before is None else
                            round(before * 1e9))

    def close(self) -> None:
        """Write the rest, the summary and the footer (once); on a failure, ``abort``."""
        if self._closed:
            return
        try:
            self._write_pending(final=True)
            assert self._out is not None
            self._out.finish()
        except BaseException:
            self.abort()
            raise
        self._closed = True

    def _write_pending(self, *, final: bool, before: int | None = None) -> None:
        if self._out is None:
            self._out = Stream(self.path, self.inputs, self.chunk_size)
        p = self._pending
        self._pending = Pending()
        if not p.t_ns:
            return
        rest = self._out.write_messages(self._topics, p, final=final, before=before)
        if rest is not None:
            self._pending = rest
