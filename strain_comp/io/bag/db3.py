"""rosbag2's sqlite3 storage (``.db3``, the default of Humble and Iron), read with rosbags.

``db3_messages`` gives a ``.db3`` file's messages in time order, in blocks, as (topic, type
name, time [ns], CDR payload); ``strain_comp.io.bag.reader`` decodes them exactly as it
decodes an MCAP's messages, so a bag evaluates the same in either storage. The database is
opened read-only and immutable (rosbags' ``Sqlite3Reader``); whatever it or sqlite raise on
a damaged or hostile file becomes one ``BagError`` line. Payloads compressed per message
(zstd, ``compression_mode: message``) are decompressed within ``MAX_MESSAGE_BYTES``; a file
compressed whole (``compression_mode: file``, ``.db3.zstd``) is refused with how to
decompress it.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import zstandard

from strain_comp.errors import BagError

MAX_MESSAGE_BYTES = 64 * 2**20
"""Largest message kept [bytes], stored or decompressed (a Float64 message is 12 bytes): a
larger one is skipped and counted."""
BLOCK = 4096
"""Messages per block ``db3_messages`` yields."""

DECOMPRESS_HINT = ("decompress it first: rosbags-convert --src BAG --dst PLAIN_BAG "
                   "--dst-storage mcap (pip install rosbags), or ros2 bag convert with "
                   "compression_mode none")

Message = tuple[str, str, int, bytes]


def refuse_compressed_file(path: Path) -> None:
    """Refuse a storage file compressed whole (``x.db3.zstd``, ``x.mcap.zstd``).

    Args:
        path: The storage file.

    Raises:
        BagError: Always, with the way to decompress it.

    """
    raise BagError(f"{path}: compressed per file ({path.suffix.lstrip('.')}); "
                   + DECOMPRESS_HINT)


def db3_messages(path: Path, problems: list[str], *, compressed: bool = False
                 ) -> Iterator[list[Message]]:
    """The messages of one ``.db3`` file, in time order.

    Args:
        path: The rosbag2 sqlite3 database.
        problems: Lines for what was skipped are appended here (topics not in CDR,
            oversized or undecompressable messages, a damaged database after its readable
            messages).
        compressed: The payloads are zstd frames (a bag directory's
            ``compression_mode: message``).

    Yields:
        Blocks of at most ``BLOCK`` messages, each (topic, type name, time [ns], payload).

    Raises:
        BagError: The file is not a readable rosbag2 database (one line).

    """
    import apsw
    from rosbags.rosbag2 import ReaderError
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    reader = Sqlite3Reader(path)
    errors = (apsw.Error, ReaderError, ValueError, TypeError, KeyError, IndexError,
              OverflowError, UnicodeDecodeError)
    try:
        reader.open()
    except errors as exc:
        raise BagError(f"{path}: not a readable rosbag2 sqlite3 database "
                       f"({' '.join(str(exc).split())})") from None
    large = bad = 0
    try:
        connections = list(reader.connections)
        formats = {c.id: getattr(c.ext, "serialization_format", "cdr") for c in connections}
        for conn in connections:
            if formats[conn.id] != "cdr":
                problems.append(f"{path}: {conn.topic}: serialization format "
                                f"{formats[conn.id]!r}, not cdr; skipped")
        wanted = [c for c in connections if formats[c.id] == "cdr"]
        block: list[Message] = []
        for conn, stamp, data in reader.messages(wanted) if wanted else ():
            if len(data) > MAX_MESSAGE_BYTES:
                large += 1
                continue
            if compressed:
                try:
                    data = _decompress(data)
                except (zstandard.ZstdError, BagError):
                    bad += 1
                    continue
            block.append((conn.topic, conn.msgtype, int(stamp), bytes(data)))
            if len(block) >= BLOCK:
                yield block
                block = []
        if block:
            yield block
    except errors as exc:
        problems.append(f"{path}: database damaged ({' '.join(str(exc).split())}); the "
                        "messages before it are kept")
    finally:
        reader.close()
    if large:
        problems.append(f"{path}: {large} messages larger than {MAX_MESSAGE_BYTES} bytes "
                        "skipped")
    if bad:
        problems.append(f"{path}: {bad} messages whose zstd compression cannot be undone "
                        "skipped")


def _decompress(data: bytes) -> bytes:
    """One zstd frame, within ``MAX_MESSAGE_BYTES``."""
    reader = zstandard.ZstdDecompressor().stream_reader(data)
    out = reader.read(MAX_MESSAGE_BYTES + 1)
    if len(out) > MAX_MESSAGE_BYTES:
        raise BagError("decompresses beyond the message budget")
    return out
