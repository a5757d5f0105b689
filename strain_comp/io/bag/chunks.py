"""MCAP chunks: decompressed within their budget, checked by CRC, and the recovery that
finds the next intact chunk after damage (docs/reliability.md, "Budgets")."""

from __future__ import annotations

import io
import mmap
import struct
import zlib

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Chunk

from strain_comp.errors import BagError
from strain_comp.io.bag.records import PARSE_ERRORS, Collector, scan_records

# what decompression raises on damaged chunk data
_DECOMPRESS_ERRORS = (zstandard.ZstdError, RuntimeError, BagError, ValueError)

MAX_CHUNK_BYTES = 64 * 2**20
"""Decompressed size budget of one chunk [bytes] (rosbag2's default chunk is 4 MiB)."""


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


def add_chunk(col: Collector, chunk: Chunk, where: str) -> None:
    """Add the records of ``chunk`` to ``col``; damage skipped, named in ``col.problems``."""
    try:
        data = _chunk_payload(chunk)
    except _DECOMPRESS_ERRORS as exc:
        col.problems.append(f"{where}: chunk skipped, cannot decompress ({exc})")
        return
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        col.problems.append(f"{where}: chunk skipped, CRC mismatch (corrupt data)")
        return
    buf = np.frombuffer(data, dtype=np.uint8)
    ops, starts, lens, end = scan_records(buf)
    if end != buf.shape[0]:
        col.problems.append(f"{where}: chunk records damaged after byte {end}; kept {len(ops)}")
    col.add_block(buf, ops, starts, lens, where)


def _plausible_chunk(data: bytes | mmap.mmap, pos: int, budget: list[int]) -> bool:
    """Does a valid Chunk start at ``pos``? Fixed fields first, then a copy paid from budget."""
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
        # mcap leaves Chunk.read's return unannotated
        chunk: Chunk = Chunk.read(ReadDataStream(io.BytesIO(data[pos + 9:pos + 9 + length])))
        if chunk.compression not in ("", "zstd", "lz4") or chunk.uncompressed_crc == 0:
            return False
        return zlib.crc32(_chunk_payload(chunk)) == chunk.uncompressed_crc
    except PARSE_ERRORS + _DECOMPRESS_ERRORS:
        return False


RESYNC_BYTES = 4 * MAX_CHUNK_BYTES
"""Bytes of candidate chunks one file's recovery may copy and check [bytes]."""


def resync(data: bytes | mmap.mmap, pos: int, budget: list[int]) -> int | None:
    """Offset of the next valid chunk record after ``pos``."""
    marker = bytes([Opcode.CHUNK])
    cand = data.find(marker, pos)
    while cand >= 0 and budget[0] > 0:
        if _plausible_chunk(data, cand, budget):
            return cand
        cand = data.find(marker, cand + 1)
    return None
