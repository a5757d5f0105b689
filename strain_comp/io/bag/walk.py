"""The walk of one storage file, record by record from its start, past damage."""

from __future__ import annotations

import io
import mmap
import os
import struct
from collections.abc import Iterator
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Schema

from strain_comp.errors import BagError
from strain_comp.io.bag.chunks import RESYNC_BYTES, add_chunk, resync
from strain_comp.io.bag.db3 import db3_messages
from strain_comp.io.bag.records import MAX_LOG_NS, PARSE_ERRORS, Collector, add_loose
from strain_comp.io.bag.schemas import MAGIC

LOOSE_BLOCK = 4096
"""Messages outside chunks (an unchunked MCAP) are packed into blocks of this many."""

_OPCODES = {int(op) for op in Opcode}


def _read_file(col: Collector, data: bytes | mmap.mmap, name: str) -> Iterator[int]:
    """Collect every complete record of one mapped MCAP file; yields each record's end."""
    if len(data) < len(MAGIC) or data[:len(MAGIC)] != MAGIC:
        raise BagError(f"{name}: not an MCAP file (bad magic)")
    pos = len(MAGIC)
    loose_msgs: list[Message] = []
    budget = [RESYNC_BYTES]
    while pos < len(data):
        problem = None
        if pos + 9 > len(data):
            problem = f"truncated at byte {pos} of {len(data)} (partial record header)"
        else:
            opcode, length = struct.unpack_from("<BQ", data, pos)
            end = pos + 9 + length
            if opcode not in _OPCODES and opcode < 0x80:
                problem = f"corrupt record at byte {pos} (unknown opcode {opcode:#04x})"
            elif end > len(data):
                problem = (f"truncated at byte {pos} of {len(data)}: "
                           f"{Opcode(opcode).name if opcode in _OPCODES else opcode} record "
                           f"claims {length} bytes, {len(data) - pos - 9} remain")
            else:
                try:
                    if _read_top_record(col, opcode, data[pos + 9:end], f"{name}@{pos}",
                                        loose_msgs):
                        if data[end:] != MAGIC:
                            col.problems.append(f"{name}: closing magic missing or damaged")
                        break  # footer
                except PARSE_ERRORS as exc:
                    problem = f"corrupt record at byte {pos} ({type(exc).__name__}: {exc})"
        if problem is None:
            if len(loose_msgs) >= LOOSE_BLOCK:
                add_loose(col, loose_msgs, name)
                loose_msgs.clear()
            pos = end
            yield pos
            continue
        col.problems.append(f"{name}: {problem}; messages before it are kept")
        nxt = resync(data, pos + 1, budget)
        if nxt is None:
            if budget[0] <= 0:
                col.problems.append(f"{name}: recovery budget ({RESYNC_BYTES} bytes of "
                                    "candidate chunks) spent; the rest of the file is skipped")
            break
        col.problems.append(f"{name}: resumed at the next intact chunk, byte {nxt}")
        pos = nxt
    if loose_msgs:
        add_loose(col, loose_msgs, name)


def _read_top_record(col: Collector, opcode: int, content: bytes, where: str,
                     loose_msgs: list[Message]) -> bool:
    """Handle one top-level record; True at the footer."""
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(content)))
        col.chunk_start = max(col.chunk_start, chunk.message_start_time)
        add_chunk(col, chunk, where)
    elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
        col.add_small_record(opcode, content, where)
    elif opcode == Opcode.MESSAGE:
        loose_msgs.append(Message.read(ReadDataStream(io.BytesIO(content)), len(content)))
    return opcode == Opcode.FOOTER


def storage_file(col: Collector, file: Path, compressed: bool) -> Iterator[int]:
    """Collect the messages of one storage file of a bag (``compressed``: zstd frames, .db3)."""
    if file.suffix == ".db3":
        yield from _read_db3(col, file, compressed)
        return
    try:
        with file.open("rb") as handle:
            if os.fstat(handle.fileno()).st_size < len(MAGIC):
                raise BagError(f"{file}: not an MCAP file (bad magic)")
            data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise BagError(f"{file}: cannot read ({exc.strerror})") from exc
    with data:
        released = 0
        for pos in _read_file(col, data, str(file)):
            page = pos - pos % mmap.PAGESIZE
            if page > released:
                data.madvise(mmap.MADV_DONTNEED, released, page - released)
                released = page
            yield pos


def _read_db3(col: Collector, file: Path, compressed: bool) -> Iterator[int]:
    """A ``.db3`` file collected as an unchunked MCAP, one channel per topic and type."""
    channels: dict[tuple[str, str], int] = {}
    skipped = 0
    for n, block in enumerate(db3_messages(file, col.problems, compressed=compressed)):
        messages = []
        for topic, kind, stamp, data in block:
            if not 0 <= stamp <= MAX_LOG_NS:
                skipped += 1
                continue
            cid = channels.setdefault((topic, kind), len(channels) + 1)
            if (col.file_index, cid) not in col.channels:
                col.schemas[(col.file_index, cid)] = Schema(id=cid, name=kind,
                                                            encoding="ros2msg", data=b"")
                col.channels[(col.file_index, cid)] = Channel(
                    id=cid, topic=topic, message_encoding="cdr", metadata={}, schema_id=cid)
            messages.append(Message(channel_id=cid, log_time=stamp, data=data,
                                    publish_time=stamp, sequence=0))
        if messages:
            add_loose(col, messages, str(file))
        yield n
    if skipped:
        col.problems.append(f"{file}: {skipped} messages with a time stamp beyond 2^31 s "
                            "(2038-01-19) or before 1970 skipped")
