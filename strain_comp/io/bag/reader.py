"""MCAP bag reading: ros2-profile bags with ros2msg schemas, decoded in bulk.

``read_bag`` walks the file record by record from the start and never needs the summary
section, so a truncated or damaged file still yields every complete message before the
damage; what was skipped is listed in ``BagContents.problems``. The top-level walk is ours
and exact; each record is parsed by the ``mcap`` record classes with failures caught per
record (after a damaged record the walk resynchronises on the next chunk whose CRC checks).
Chunks are decompressed and their records located by one numba scan; fixed-layout payloads
(``std_msgs/msg/Float64``, ``Int8``, ``Float32``, and ``Float64MultiArray`` topics whose
layout never changes) are then decoded in bulk with numpy, honouring the CDR little/big-endian
flag. Float64MultiArray (when the layout varies), Temperature and DiagnosticArray go message
by message through ``mcap_ros2``'s public ``DecoderFactory``, built on the standard ROS 2
definitions of those types (``schemas.SCHEMAS``), not on the schema text found in the bag:
these are fixed message types, so a damaged schema text in a bag costs nothing. A rosbag2
directory (``metadata.yaml`` + ``.mcap`` files) reads as one bag. rosbag2's sqlite3 storage
(``.db3`` files, bare or in a directory; Humble's and Iron's default) reads through
``strain_comp.io.bag.db3``: its messages become MCAP message records, decoded as above.
"""

from __future__ import annotations

import io
import mmap
import os
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    Message,
    Schema,
)
from mcap_ros2.decoder import DecoderFactory

from strain_comp._numba import njit
from strain_comp.errors import BagError, InputError
from strain_comp.io.bag.db3 import DECOMPRESS_HINT, db3_messages, refuse_compressed_file
from strain_comp.io.bag.schemas import (
    MAGIC,
    MAX_TIME_S,
    SCHEMAS,
    BagContents,
    Series,
    norm_type,
)
from strain_comp.io.multiarray import array_values, label_names
from strain_comp.io.safe_yaml import LimitError, load_limited

_FIXED_SCALAR = {  # type -> (payload byte offset, numpy little-endian dtype)
    "std_msgs/msg/Float64": (4, "<f8"),
    "std_msgs/msg/Float32": (4, "<f4"),
    "std_msgs/msg/Int8": (4, "i1"),
}

WINDOW = 200_000
"""Messages ``iter_bag`` lets wait before it cuts a piece."""
LOOSE_BLOCK = 4096
"""Messages outside chunks (an unchunked MCAP) are packed into blocks of this many."""

# what the mcap record parsers raise on damaged content
_PARSE_ERRORS = (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError,
                 MemoryError, IndexError, KeyError)
# what decompression raises on damaged chunk data
_DECOMPRESS_ERRORS = (zstandard.ZstdError, RuntimeError, BagError, ValueError)
# what the CDR decoder raises on a damaged payload (short reads, bad lengths, bad UTF-8)
_PAYLOAD_ERRORS = (struct.error, ValueError, IndexError, OverflowError, MemoryError)
#: types decoded message by message with their standard definitions
_DECODED_TYPES = ("std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/Temperature",
                  "diagnostic_msgs/msg/DiagnosticArray")
_DECODERS = DecoderFactory()


def _decoder(kind: str) -> Callable[[bytes], Any]:
    """CDR decoder of the standard ROS 2 message ``kind`` (one of ``_DECODED_TYPES``)."""
    schema = Schema(id=_DECODED_TYPES.index(kind) + 1, name=kind, encoding="ros2msg",
                    data=SCHEMAS[kind].encode())
    decoder = _DECODERS.decoder_for("cdr", schema)
    if decoder is None:
        raise BagError(f"no CDR decoder for {kind}")
    return decoder

# --------------------------------------------------------------------------- reading


@njit
def _scan_records(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.int64]:
    """Walk MCAP records in a chunk: opcode, content start, content length; end offset."""
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
def _compact(buf: np.ndarray, starts: np.ndarray, lens: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Copy the spans buf[starts[i] : starts[i] + lens[i]] into one new buffer; their new
    starts. The source (a whole decompressed chunk) can then be released."""
    out = np.empty(lens.sum(), np.uint8)
    new = np.empty(starts.shape[0], np.int64)
    pos = 0
    for i in range(starts.shape[0]):
        new[i] = pos
        out[pos:pos + lens[i]] = buf[starts[i]:starts[i] + lens[i]]
        pos += lens[i]
    return out, new


def _gather(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """Bytes buf[starts[i] : starts[i] + width] as an (n, width) uint8 array."""
    return buf[starts[:, None] + np.arange(width)]


class _Collector:
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
        self.held = 0
        """Message bytes held undecoded in ``blocks``."""
        self.file_index = 0
        self.chunk_start = 0
        """Largest message start time [ns] of the chunks read so far (or log time of the
        messages read outside chunks): earlier messages are all read."""

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
        head = _gather(buf, s, 22)
        channel = head[:, 0:2].copy().view("<u2")[:, 0].astype(np.int32)
        wanted = np.array([self._wanted(int(c)) for c in np.unique(channel)], bool)
        keep = wanted[np.searchsorted(np.unique(channel), channel)]
        if not keep.any():
            return
        # only the wanted payloads are kept: the decompressed chunk is released
        payload, start = _compact(buf, s[keep] + 22, lens[is_msg][keep] - 22)
        block = len(self.blocks)
        self.blocks.append(payload)
        self.held += payload.size
        self.block_file.append(self.file_index)
        self.msg_block.append(np.full(start.shape, block, np.int32))
        self.msg_channel.append(channel[keep])
        self.msg_time.append(head[keep, 6:14].copy().view("<u8")[:, 0].astype(np.int64))
        self.msg_start.append(start)
        self.msg_len.append(lens[is_msg][keep] - 22)

    def _wanted(self, channel_id: int) -> bool:
        """Are the messages of ``channel_id`` (of the current file) to be kept? All when no
        topics were asked for, and those of a channel not yet seen (reported later)."""
        channel = self.channels.get((self.file_index, channel_id))
        return self.topics is None or channel is None or channel.topic in self.topics

    def add_small_record(self, opcode: int, content: bytes, where: str) -> None:
        try:
            stream = ReadDataStream(io.BytesIO(content))
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(stream)
                self.schemas[(self.file_index, schema.id)] = schema
            else:
                channel = Channel.read(stream)
                self.channels[(self.file_index, channel.id)] = channel
        except _PARSE_ERRORS as exc:
            self.problems.append(f"{where}: unreadable {Opcode(opcode).name} record ({exc})")


MAX_CHUNK_BYTES = 64 * 2**20
"""Decompressed size budget of one chunk [bytes]: a chunk that claims more, or whose data
expands beyond the size it claims, is skipped and named in ``problems`` (a writer's chunk
is a few MiB; rosbag2's default is 4 MiB)."""
MAX_HELD_BYTES = 256 * 2**20
"""Message bytes held undecoded at once [bytes]. ``iter_bag`` cuts a piece when the held
messages reach it (at the latest chunk's start, else all held: later messages may then
come late, counted), so it holds at most this plus one chunk; ``read_bag`` (the whole bag in
memory) refuses a bag holding more than ``MAX_BAG_BYTES``."""
MAX_BAG_BYTES = 2**30
"""Message bytes ``read_bag`` holds for one whole bag [bytes]; past it: BagError."""


def _chunk_payload(chunk: Chunk) -> bytes:
    """The chunk's records, decompressed within ``MAX_CHUNK_BYTES`` and its claimed size."""
    if chunk.compression == "":
        return chunk.data
    claimed = chunk.uncompressed_size
    if claimed > MAX_CHUNK_BYTES:
        raise BagError(f"claims {claimed} bytes decompressed, over the budget of "
                       f"{MAX_CHUNK_BYTES} bytes per chunk")
    if chunk.compression == "zstd":
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data))
        data = reader.read(claimed + 1)
    elif chunk.compression == "lz4":
        import lz4.frame
        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=claimed + 1)
    else:
        raise BagError(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) > claimed:
        raise BagError(f"expands beyond the {claimed} bytes it claims")
    return data


def _add_chunk(col: _Collector, chunk: Chunk, where: str) -> None:
    try:
        data = _chunk_payload(chunk)
    except _DECOMPRESS_ERRORS as exc:
        col.problems.append(f"{where}: chunk skipped, cannot decompress ({exc})")
        return
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        col.problems.append(f"{where}: chunk skipped, CRC mismatch (corrupt data)")
        return
    buf = np.frombuffer(data, dtype=np.uint8)
    ops, starts, lens, end = _scan_records(buf)
    if end != buf.shape[0]:
        col.problems.append(f"{where}: chunk records damaged after byte {end}; kept {len(ops)}")
    col.add_block(buf, ops, starts, lens, where)


def _plausible_chunk(data: bytes | mmap.mmap, pos: int, budget: list[int]) -> bool:
    """Does a valid Chunk record start at ``pos`` (structure, compression, CRC)? The fixed
    fields are checked in place first, so a candidate costs O(1) unless its lengths agree;
    then its bytes are copied and checked and taken from ``budget[0]``."""
    if pos + 9 + 40 > len(data) or data[pos] != Opcode.CHUNK:
        return False
    (length,) = struct.unpack_from("<Q", data, pos + 1)
    if pos + 9 + length > len(data):
        return False
    (n_compression,) = struct.unpack_from("<I", data, pos + 9 + 28)
    if n_compression > 4 or 40 + n_compression > length:
        return False
    (n_records,) = struct.unpack_from("<Q", data, pos + 9 + 32 + n_compression)
    if 40 + n_compression + n_records != length or length > 2 * MAX_CHUNK_BYTES:
        return False
    budget[0] -= length
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(data[pos + 9:pos + 9 + length])))
        if chunk.compression not in ("", "zstd", "lz4") or chunk.uncompressed_crc == 0:
            return False
        return zlib.crc32(_chunk_payload(chunk)) == chunk.uncompressed_crc
    except _PARSE_ERRORS + _DECOMPRESS_ERRORS:
        return False


RESYNC_BYTES = 4 * MAX_CHUNK_BYTES
"""Bytes of candidate chunks one file's recovery may copy and check [bytes] (candidates
whose fixed fields disagree cost nothing); past it the rest of the file is skipped."""


def _resync(data: bytes | mmap.mmap, pos: int, budget: list[int]) -> int | None:
    """Offset of the next valid chunk record after ``pos``, or None; ``budget[0]``: the
    candidate bytes still allowed (``RESYNC_BYTES`` per file), spent here."""
    marker = bytes([Opcode.CHUNK])
    cand = data.find(marker, pos)
    while cand >= 0 and budget[0] > 0:
        if _plausible_chunk(data, cand, budget):
            return cand
        cand = data.find(marker, cand + 1)
    return None


_OPCODES = {int(op) for op in Opcode}


def _read_file(col: _Collector, data: bytes | mmap.mmap, name: str) -> Iterator[int]:
    """Collect every complete record of one MCAP file held in memory (or mapped); yields
    the end offset after each top-level record, so a caller may take what was collected.

    The top-level walk is ours (so positions are exact and the summary is never needed);
    each record's content is parsed by the ``mcap`` record classes and any failure is
    caught per record: it is reported and the walk resynchronises on the next intact chunk.
    """
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
                except _PARSE_ERRORS as exc:
                    problem = f"corrupt record at byte {pos} ({type(exc).__name__}: {exc})"
        if problem is None:
            if len(loose_msgs) >= LOOSE_BLOCK:
                _add_loose(col, loose_msgs, name)
                loose_msgs.clear()
            pos = end
            yield pos
            continue
        col.problems.append(f"{name}: {problem}; messages before it are kept")
        nxt = _resync(data, pos + 1, budget)
        if nxt is None:
            if budget[0] <= 0:
                col.problems.append(f"{name}: recovery budget ({RESYNC_BYTES} bytes of "
                                    "candidate chunks) spent; the rest of the file is skipped")
            break
        col.problems.append(f"{name}: resumed at the next intact chunk, byte {nxt}")
        pos = nxt
    if loose_msgs:
        _add_loose(col, loose_msgs, name)


def _read_top_record(col: _Collector, opcode: int, content: bytes, where: str,
                     loose_msgs: list[Message]) -> bool:
    """Handle one top-level record; True at the footer."""
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(content)))
        col.chunk_start = max(col.chunk_start, chunk.message_start_time)
        _add_chunk(col, chunk, where)
    elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
        col.add_small_record(opcode, content, where)
    elif opcode == Opcode.MESSAGE:
        loose_msgs.append(Message.read(ReadDataStream(io.BytesIO(content)), len(content)))
    return opcode == Opcode.FOOTER


def _add_loose(col: _Collector, msgs: list[Message], name: str) -> None:
    """Messages stored outside chunks: pack them into one block of message records. They
    are in file order, which is log-time order: those before the latest log time are
    complete, as a chunk's start time says for chunked messages."""
    builder = RecordBuilder()
    for m in msgs:
        m.write(builder)
    col.chunk_start = max(col.chunk_start, max(m.log_time for m in msgs))
    buf = np.frombuffer(builder.end(), dtype=np.uint8)
    ops, starts, lens, _ = _scan_records(buf)
    col.add_block(buf, ops, starts, lens, name)


MAX_METADATA_BYTES = 2**20
"""rosbag2 metadata.yaml larger than this is refused (a real one is a few kB)."""


def _inside(path: Path, file: Path) -> bool:
    """``file`` is a regular file that resolves (symbolic links followed) into ``path``."""
    try:
        return file.resolve().is_relative_to(path.resolve()) and file.is_file()
    except (OSError, RuntimeError):  # a symbolic link loop
        return False


def _metadata(meta: Path) -> dict[str, Any]:
    """rosbag2's metadata.yaml within ``MAX_METADATA_BYTES``; BagError (one line) when it is
    unreadable or ``rosbag2_bagfile_information`` is not a mapping."""
    try:
        with meta.open("rb") as handle:
            data = handle.read(MAX_METADATA_BYTES + 1)
        if len(data) > MAX_METADATA_BYTES:
            raise BagError(f"{meta}: rosbag2 metadata larger than {MAX_METADATA_BYTES} bytes")
        info = load_limited(data.decode("utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, LimitError) as exc:
        detail = " ".join(str(exc).split())
        raise BagError(f"{meta}: unreadable rosbag2 metadata ({detail})") from None
    where = "rosbag2_bagfile_information"
    if not isinstance(info, dict) or not isinstance(info.get(where, {}), dict):
        raise BagError(f"{meta}: {where} must be a mapping")
    return info


def _metadata_files(path: Path, meta: Path) -> list[Path]:
    """The files ``metadata.yaml`` lists (``rosbag2_bagfile_information.
    relative_file_paths``) that exist; BagError (one line) for unreadable metadata, a field
    of the wrong type, or a path that is absolute, holds ``..`` or leads out of ``path``."""
    info = _metadata(meta)
    where = "rosbag2_bagfile_information"
    rel = info.get(where, {}).get("relative_file_paths", [])
    if not isinstance(rel, list) or not all(isinstance(p, str) for p in rel):
        raise BagError(f"{meta}: {where}.relative_file_paths must be a list of strings")
    for p in rel:
        if Path(p).is_absolute() or ".." in Path(p).parts:
            raise BagError(f"{meta}: relative_file_paths: {p!r} leaves the bag directory")
    files = [path / p for p in rel if (path / p).exists()]
    for file in files:
        if not _inside(path, file):
            raise BagError(f"{meta}: relative_file_paths: {file.name!r} is not a regular "
                           "file inside the bag directory")
    return files


def _bag_files(path: Path) -> list[Path]:
    """The .mcap (or .db3) files of a rosbag2 directory, in metadata.yaml order when it
    lists them; only regular files inside the directory (a symbolic link out of it is not
    read). Files compressed whole (``.zstd``) are refused, with how to decompress them."""
    meta = path / "metadata.yaml"
    files = _metadata_files(path, meta) if _inside(path, meta) else []
    if not files:
        files = [f for pattern in ("*.mcap", "*.db3", "*.mcap.zstd", "*.db3.zstd")
                 for f in sorted(path.glob(pattern)) if _inside(path, f)]
    if not files:
        raise BagError(f"{path}: directory holds no .mcap or .db3 file")
    for file in files:
        if file.suffix == ".zstd":
            refuse_compressed_file(file)
    return files


def _bag_paths(path: Path) -> list[Path]:
    """The storage files (MCAP, sqlite3) of a bare ``.mcap`` or ``.db3`` or a rosbag2
    directory; BagError before anything is opened for a missing path or one that is
    neither (a FIFO would block)."""
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if not (path.is_dir() or path.is_file()):
        raise BagError(f"{path}: not a regular file or a rosbag2 directory")
    if path.is_file() and path.suffix == ".zstd":
        refuse_compressed_file(path)
    return _bag_files(path) if path.is_dir() else [path]


def _per_message_zstd(path: Path, file: Path) -> bool:
    """Are the messages of ``file`` (of the bag at ``path``) compressed one by one? A
    rosbag2 directory says so in metadata.yaml (``compression_mode: message``); only zstd
    is read, and only for .db3 files."""
    meta = path / "metadata.yaml"
    if not (path.is_dir() and _inside(path, meta)):
        return False
    info = _metadata(meta).get("rosbag2_bagfile_information", {})
    mode = str(info.get("compression_mode") or "").lower()
    if mode in ("", "none"):
        return False
    kind = str(info.get("compression_format") or "")
    if mode != "message" or kind != "zstd" or file.suffix != ".db3":
        raise BagError(f"{meta}: compression {kind or '?'} per {mode} is not read here; "
                       + DECOMPRESS_HINT)
    return True


def _storage_file(col: _Collector, path: Path, file: Path) -> Iterator[int]:
    """Collect the messages of one storage file of the bag at ``path``; yields after each
    record (MCAP, the file mapped and the pages walked released) or block (sqlite3)."""
    if file.suffix == ".db3":
        yield from _read_db3(col, file, _per_message_zstd(path, file))
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


def _read_db3(col: _Collector, file: Path, compressed: bool) -> Iterator[int]:
    """The messages of a ``.db3`` file (``db3.db3_messages``) collected as MCAP records of
    one channel per topic and type, as an unchunked MCAP's are: decoded alike after."""
    channels: dict[tuple[str, str], int] = {}
    skipped = crowded = 0
    for n, block in enumerate(db3_messages(file, col.problems, compressed=compressed)):
        messages = []
        for topic, kind, stamp, data in block:
            if not 0 <= stamp <= MAX_LOG_NS:
                skipped += 1
                continue
            if (topic, kind) not in channels and len(channels) >= MAX_DB3_CHANNELS:
                crowded += 1
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
            _add_loose(col, messages, str(file))
        yield n
    if skipped:
        col.problems.append(f"{file}: {skipped} messages with a time stamp beyond 2^31 s "
                            "(2038-01-19) or before 1970 skipped")
    if crowded:
        col.problems.append(f"{file}: {crowded} messages on topics past the first "
                            f"{MAX_DB3_CHANNELS} skipped")


MAX_DB3_CHANNELS = 65535
"""Topics (with their type) read from one .db3 file: an MCAP channel id has 16 bits."""


def read_bag(path: str | os.PathLike[str], topics: Iterable[str] | None = None) -> BagContents:
    """Read a whole bag: a bare ``.mcap`` or ``.db3`` file or a rosbag2 directory.

    Args:
        path: The bag file or directory (``metadata.yaml`` and its storage files).
        topics: Decode only these topics (None: all).

    Returns:
        The decoded series per topic; every fault short of an unreadable bag is a line in
        ``problems``, naming the bag.

    Raises:
        BagError: The path is missing, is not a bag, nothing at all can be read, or the
            messages exceed the whole-bag reader's memory budget.

    """
    path = Path(path)
    contents = _decode(_collect(path, topics))
    contents.problems[:] = located(path, contents.problems)
    return contents


def _collect(path: Path, topics: Iterable[str] | None) -> _Collector:
    """Every message of the bag at ``path`` located, within ``MAX_BAG_BYTES``."""
    col = _Collector(set(topics) if topics is not None else None)
    for index, file in enumerate(_bag_paths(path)):
        col.file_index = index
        for _ in _storage_file(col, path, file):
            if col.held > MAX_BAG_BYTES:
                raise BagError(f"{file}: more than {MAX_BAG_BYTES} bytes of messages to hold "
                               "at once (the whole-bag reader's budget)")
    return col


def raw_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None
                 ) -> tuple[list[tuple[str, str, int, bytes]], list[str]]:
    """Every CDR message of a bag, not decoded, in log-time order.

    Read with ``read_bag``'s walk and budgets.

    Args:
        path: The bag file or directory.
        topics: Keep only these topics (None: all).

    Returns:
        The messages as (topic, type name, log time [ns], payload), and the problem lines.

    Raises:
        BagError: As ``read_bag``.

    """
    path = Path(path)
    col = _collect(path, topics)
    out: list[tuple[str, str, int, bytes]] = []
    if col.msg_time:
        block = np.concatenate(col.msg_block)
        start, length = np.concatenate(col.msg_start), np.concatenate(col.msg_len)
        log_ns, channel_id = np.concatenate(col.msg_time), np.concatenate(col.msg_channel)
        files = np.array(col.block_file, dtype=np.int64)[block]
        skipped = 0
        for i in np.argsort(log_ns, kind="stable").tolist():
            channel = col.channels.get((int(files[i]), int(channel_id[i])))
            schema = None if channel is None else col.schemas.get((int(files[i]),
                                                                   channel.schema_id))
            if (channel is None or schema is None or channel.message_encoding != "cdr"
                    or not 0 <= log_ns[i] <= MAX_LOG_NS):
                skipped += 1
                continue
            if col.topics is None or channel.topic in col.topics:
                payload = col.blocks[block[i]][start[i]:start[i] + length[i]].tobytes()
                out.append((channel.topic, schema.name, int(log_ns[i]), payload))
        if skipped:
            col.problems.append(f"{skipped} messages without a known CDR channel or with a "
                                "log time beyond 2^31 s skipped")
    return out, located(path, col.problems)


def iter_bag(path: str | os.PathLike[str], topics: Iterable[str] | None = None, *,
             window: int = WINDOW) -> Iterator[BagContents]:
    """``read_bag`` piece by piece in log-time order, in memory bounded by ``window``.

    Each piece holds the messages of a log-time interval [t_a, t_b) (per topic sorted as
    ``read_bag`` sorts them), and the pieces follow each other in time. Files are mapped,
    not read, and the pages already walked are released. A piece is cut once ``window``
    messages are waiting, at the start time of the latest chunk read: chunks that overlap
    in time are merged as long as no later chunk starts before an earlier one's cut. If
    one does, its messages before the cut come in the next piece (late) and a problem line
    counts them. Messages stored outside chunks (an unchunked MCAP) are taken in blocks of
    ``LOOSE_BLOCK`` in file order and cut the same way, at the latest log time read (an
    earlier one after it is delivered late, with the problem line).

    Args:
        path: The bag file or directory.
        topics: Decode only these topics (None: all).
        window: Messages that may wait before a piece is cut.

    Yields:
        The pieces in log-time order; the last one carries the remaining problem lines
        (there is always at least one piece).

    Raises:
        BagError: The path is missing or is not a bag.

    """
    path = Path(path)
    col = _Collector(set(topics) if topics is not None else None)
    cut: int | None = None
    for index, file in enumerate(_bag_paths(path)):
        col.file_index = index
        for _ in _storage_file(col, path, file):
            if sum(m.size for m in col.msg_time) >= window or col.held >= MAX_HELD_BYTES:
                piece, cut = _take(col, col.chunk_start, cut)
                if piece is None and col.held >= MAX_HELD_BYTES:  # no cut frees memory
                    piece, cut = _take(col, None, cut)
                if piece is not None:
                    piece.problems[:] = located(path, piece.problems)
                    yield piece
    piece, _ = _take(col, None, cut)
    if piece is None:
        piece = BagContents(problems=col.problems)
    piece.problems[:] = located(path, piece.problems)
    yield piece


def _take(col: _Collector, upto: int | None, cut: int | None
          ) -> tuple[BagContents | None, int | None]:
    """Decode and remove from ``col`` the messages before ``upto`` [ns] (all if None);
    ``cut``: the previous piece's end. Returns the piece and the new cut."""
    if not col.msg_time:
        return None, cut
    time = np.concatenate(col.msg_time)
    block = np.concatenate(col.msg_block)
    channel = np.concatenate(col.msg_channel)
    start = np.concatenate(col.msg_start)
    length = np.concatenate(col.msg_len)
    take = np.ones(time.size, bool) if upto is None else time < upto
    if not take.any():
        return None, cut
    sub = _Collector(col.topics)
    sub.schemas, sub.channels = col.schemas, col.channels
    sub.blocks, sub.block_file = col.blocks, col.block_file
    sub.msg_time, sub.msg_block, sub.msg_channel = [time[take]], [block[take]], [channel[take]]
    sub.msg_start, sub.msg_len = [start[take]], [length[take]]
    sub.problems, col.problems = col.problems, []
    if cut is not None:
        late = int(np.count_nonzero(time[take] < cut))
        if late:
            sub.problems.append(f"{late} messages in chunks that start before an earlier "
                                "chunk's end: delivered late, after later messages")
    keep = ~take
    used = np.unique(block[keep])
    remap = np.full(len(col.blocks), -1, np.int32)
    remap[used] = np.arange(used.size, dtype=np.int32)
    col.blocks = [col.blocks[b] for b in used]
    col.held = sum(b.size for b in col.blocks)
    col.block_file = [col.block_file[b] for b in used]
    col.msg_time, col.msg_block, col.msg_channel = [time[keep]], [remap[block[keep]]], \
        [channel[keep]]
    col.msg_start, col.msg_len = [start[keep]], [length[keep]]
    new_cut = int(time[take].max()) + 1 if upto is None else upto
    return _decode(sub), new_cut if cut is None else max(cut, new_cut)


def located(path: str | os.PathLike[str], problems: Iterable[str]) -> list[str]:
    """Problem lines that all name the bag.

    Args:
        path: The bag.
        problems: Problem lines.

    Returns:
        The lines as ``path: ...`` (a line that already starts with the path is kept).

    """
    prefix = str(path)
    return [p if p.startswith(prefix) else f"{prefix}: {p}" for p in problems]


MAX_LOG_NS = MAX_TIME_S * 10**9
"""The latest log time kept [ns] (``MAX_TIME_S``). A later (or negative) log time is a
damaged record: its message is skipped and counted in ``problems``."""


def _decode(col: _Collector) -> BagContents:
    out = BagContents(problems=col.problems)
    if not col.msg_channel:
        return out
    sizes = np.array([b.shape[0] for b in col.blocks], dtype=np.int64)
    blob = np.concatenate(col.blocks) if len(col.blocks) > 1 else col.blocks[0]
    base = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
    block = np.concatenate(col.msg_block)
    start = np.concatenate(col.msg_start) + base[block]
    length = np.concatenate(col.msg_len)
    log_ns = np.concatenate(col.msg_time)
    late = (log_ns < 0) | (log_ns > MAX_LOG_NS)
    if late.any():
        out.problems.append(f"{int(np.count_nonzero(late))} messages with a log time beyond "
                            "2^31 s (2038-01-19) skipped")
    # channel ids are per file: key messages by (file, channel id)
    key = np.array(col.block_file, dtype=np.int64)[block] * 65536 + np.concatenate(col.msg_channel)
    per_type: dict[tuple[str, str], tuple[Schema, list[np.ndarray]]] = {}
    valid = np.flatnonzero(~late)
    order = valid[np.argsort(key[valid], kind="stable")]  # grouped by channel in one sort
    keys, first = np.unique(key[order], return_index=True)
    groups = np.split(order, first[1:]) if keys.size else []
    for k, idx in zip(keys.tolist(), groups, strict=True):
        f, cid = divmod(k, 65536)
        channel = col.channels.get((f, cid))
        if channel is None:
            out.problems.append(f"{idx.size} messages on unknown channel id {cid} skipped")
            continue
        if col.topics is not None and channel.topic not in col.topics:
            continue
        schema = col.schemas.get((f, channel.schema_id))
        if schema is None or schema.encoding != "ros2msg" or channel.message_encoding != "cdr":
            out.problems.append(f"{channel.topic}: no ros2msg schema / cdr encoding; "
                                f"{idx.size} messages skipped")
            continue
        per_type.setdefault((channel.topic, norm_type(schema.name)), (schema, []))[1].append(idx)
    for topic, kind, schema, parts in _one_type_per_topic(out, per_type):
        out.types[topic] = kind
        idx = np.concatenate(parts)
        idx = idx[np.argsort(log_ns[idx], kind="stable")]
        _decode_topic(out, topic, schema, blob, start[idx], length[idx],
                      log_ns[idx].astype(np.float64) * 1e-9)
    return out


def _one_type_per_topic(out: BagContents,
                        per_type: dict[tuple[str, str], tuple[Schema, list[np.ndarray]]]
                        ) -> list[tuple[str, str, Schema, list[np.ndarray]]]:
    """(topic, type, schema, message indices) with one type per topic: a topic recorded on
    channels of different types keeps the type with the most messages (the first seen on a
    tie); the others are never read as it: they are skipped, counted in ``problems``."""
    kept: dict[str, tuple[str, Schema, list[np.ndarray]]] = {}
    for (topic, kind), (schema, parts) in per_type.items():
        n = sum(p.size for p in parts)
        other = kept.get(topic)
        if other is None or n > sum(p.size for p in other[2]):
            kept[topic] = (kind, schema, parts)
    for (topic, kind), (_, parts) in per_type.items():
        if kept[topic][0] != kind:
            out.problems.append(f"{topic}: recorded with two message types; its "
                                f"{sum(p.size for p in parts)} {kind} messages skipped "
                                f"(the topic is read as {kept[topic][0]})")
    return [(topic, kind, schema, parts) for topic, (kind, schema, parts) in kept.items()]


def _decode_topic(out: BagContents, topic: str, schema: Schema, blob: np.ndarray,
                  start: np.ndarray, length: np.ndarray, t: np.ndarray) -> None:
    kind = norm_type(schema.name)
    if kind in _FIXED_SCALAR:
        offset, dtype = _FIXED_SCALAR[kind]
        width = np.dtype(dtype).itemsize
        ok = length >= offset + width
        if not ok.all():
            out.problems.append(f"{topic}: {int((~ok).sum())} malformed {kind} messages skipped")
        start, t = start[ok], t[ok]
        raw = _gather(blob, start + offset, width)
        little = (blob[start + 1] & 1) == 1
        values = np.empty(start.shape, np.float64)
        values[little] = raw[little].copy().view(dtype)[:, 0]
        if not little.all():
            values[~little] = raw[~little].copy().view(np.dtype(dtype).newbyteorder(">"))[:, 0]
        out.series[topic] = Series(t, values)
        return
    if kind == "sensor_msgs/msg/JointState":
        return  # the stamped copy of a strain output (``types`` lists it): nothing to read
    if kind not in _DECODED_TYPES:
        out.problems.append(f"{topic}: unsupported message type {schema.name}; "
                            f"{start.size} messages skipped")
        return
    decoder = _decoder(kind)
    if kind == "std_msgs/msg/Float64MultiArray":
        _decode_array(out, topic, decoder, blob, start, length, t)
        return
    temperature = kind == "sensor_msgs/msg/Temperature"
    times: list[float] = []
    items: list[Any] = []
    bad = 0
    for s, n, ti in zip(start.tolist(), length.tolist(), t.tolist(), strict=True):
        try:
            msg = decoder(blob[s:s + n].tobytes())
            items.append(float(msg.temperature) if temperature else
                         [(str(x.name), int(x.level), str(x.message),
                           {str(kv.key): str(kv.value) for kv in x.values})
                          for x in msg.status])
            times.append(ti)
        except _PAYLOAD_ERRORS:  # malformed payload: count it, keep going
            bad += 1
    if bad:
        out.problems.append(f"{topic}: {bad} malformed {kind} messages skipped")
    if temperature:
        out.series[topic] = Series(np.array(times, np.float64), np.array(items, np.float64))
    else:
        out.diagnostics.extend(zip(times, items, strict=True))
        out.diagnostics.sort(key=lambda d: d[0])


def _decode_array(out: BagContents, topic: str, decoder: Any, blob: np.ndarray,
                  start: np.ndarray, length: np.ndarray, t: np.ndarray) -> None:
    """Float64MultiArray, read as the node reads it (``array_values``: the layout's offset and
    size honoured, values matched by label wherever a label is given). The first message
    with a well-formed layout fixes the number of values k; the first label naming k
    distinct sensors names the topic's columns; a message whose label names other sensors
    is skipped and counted. Bulk path: the messages byte-identical to the first up to their
    values, when the first is a plain array (offset 0, k values) read by position."""
    first = None
    for i in range(start.size):
        try:  # the first message that decodes into a well-formed array fixes the layout
            msg = decoder(blob[start[i]:start[i] + length[i]].tobytes())
            sizes = [int(d.size) for d in msg.layout.dim]
            offset = int(msg.layout.data_offset)
            k = sizes[0] if sizes else len(msg.data) - offset
            if k <= 0:  # an empty array cannot fix the layout
                continue
            array_values(msg.data, offset, sizes, k)
            first = (msg, k, offset)
            break
        except (*_PAYLOAD_ERRORS, InputError):  # find the first decodable message
            continue
    if first is None:
        out.problems.append(f"{topic}: no decodable Float64MultiArray message; skipped")
        return
    msg, k, offset = first
    n0 = int(length[i])
    prefix_len = n0 - 8 * k
    ref = blob[start[i]:start[i] + prefix_len]
    same = length == n0
    if same.any() and prefix_len > 0:
        same[same] = (_gather(blob, start[same], prefix_len) == ref).all(axis=1)
    label0 = label_names(str(msg.layout.dim[0].label) if msg.layout.dim else "")
    names = label0 if len(set(label0)) == len(label0) == k else _first_names(
        decoder, blob, start[~same], length[~same], k)
    if names is not None:
        out.labels[topic] = names
    values = np.full((start.size, k), np.nan)
    if offset == 0 and len(msg.data) == k and (not label0 or label0 == names):
        raw = _gather(blob, start[same] + prefix_len, 8 * k).reshape(-1, k, 8)
        dtype = "<f8" if ref[1] & 1 else ">f8"
        values[same] = raw.copy().view(dtype)[..., 0]
    else:
        same[:] = False
    keep = same.copy()
    bad = mismatched = 0
    for j in np.flatnonzero(~same):
        try:
            msg = decoder(blob[start[j]:start[j] + length[j]].tobytes())
            label = str(msg.layout.dim[0].label) if msg.layout.dim else ""
            given = label_names(label)
            if given and sorted(given) != sorted(names or []):
                mismatched += 1
                continue
            values[j] = array_values(msg.data, int(msg.layout.data_offset),
                                     [int(d.size) for d in msg.layout.dim], k, label, names)
        except (*_PAYLOAD_ERRORS, InputError):  # malformed payload: count it, keep going
            bad += 1
            continue
        keep[j] = True
    if bad:
        out.problems.append(f"{topic}: {bad} malformed or wrong-size arrays skipped")
    if mismatched:
        out.problems.append(f"{topic}: {mismatched} arrays whose dim[0].label does not name "
                            + (f"the sensors {','.join(names)}" if names else
                               f"one sensor for each of the {k} values") + " skipped")
    out.series[topic] = Series(t[keep], values[keep])


def _first_names(decoder: Any, blob: np.ndarray, start: np.ndarray, length: np.ndarray,
                 k: int) -> list[str] | None:
    """The first ``dim[0].label`` among these messages that names k distinct sensors."""
    for s, n in zip(start.tolist(), length.tolist(), strict=True):
        try:
            msg = decoder(blob[s:s + n].tobytes())
            names = label_names(str(msg.layout.dim[0].label) if msg.layout.dim else "")
        except _PAYLOAD_ERRORS:
            continue
        if len(set(names)) == len(names) == k:
            return names
    return None
