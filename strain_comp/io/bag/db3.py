"""rosbag2's sqlite3 storage (``.db3``) read with apsw, read-only and immutable: a value's
type and size asked of sqlite before it is fetched; damage ends the file, what came before
kept (docs/reliability.md, "Bags")."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import apsw
import zstandard

from strain_comp.errors import BagError

MAX_MESSAGE_BYTES = 64 * 2**20
"""Largest message kept [bytes], stored or decompressed: a larger one is skipped, counted."""
MAX_TOPICS = 65535
"""Topic rows read from one file (an MCAP channel id has 16 bits); the rest are skipped."""
MAX_NAME_BYTES = 4096
"""Longest topic name, type name or serialization format read [bytes]; longer: skipped."""
BLOCK = 4096
"""Messages per block ``db3_messages`` yields (fewer once it holds ``MAX_MESSAGE_BYTES``)."""

DECOMPRESS_HINT = ("decompress it first: rosbags-convert --src BAG --dst PLAIN_BAG "
                   "--dst-storage mcap (pip install rosbags), or ros2 bag convert with "
                   "compression_mode none")

Message = tuple[str, str, int, bytes]

_FIT = " AND ".join(["typeof(id) = 'integer'"] + [
    f"typeof({c}) = 'text' AND octet_length({c}) <= {MAX_NAME_BYTES}"
    for c in ("name", "type", "serialization_format")])
"""A topic row whose values are read (sqlite checks the types and sizes on the header)."""
_TOPICS = (f"SELECT id, name, type, serialization_format FROM topics WHERE {_FIT} "
           f"ORDER BY id LIMIT {MAX_TOPICS}")
_MESSAGES = ("SELECT topic_id, timestamp, typeof(data) = 'blob', "
             "CASE WHEN typeof(data) = 'blob' AND octet_length(data) <= ? THEN data END "
             "FROM messages ORDER BY timestamp, id")
"""Every message in time order; its data only when it is a blob within the budget."""


def refuse_compressed_file(path: Path) -> None:
    """Refuse a storage file compressed whole (``x.db3.zstd``, ``x.mcap.zstd``)."""
    raise BagError(f"{path}: compressed per file ({path.suffix.lstrip('.')}); "
                   + DECOMPRESS_HINT)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _topics(db: apsw.Connection, path: Path, problems: list[str]) -> dict[int, tuple[str, str]]:
    """The CDR topics of the database, id -> (name, type); what is skipped is a problem."""
    tables = db.execute("SELECT count(*) FROM sqlite_master WHERE type = 'table' "
                        "AND name IN ('messages', 'topics')").fetchall()
    if tables != [(2,)]:
        raise BagError(f"{path}: not a rosbag2 sqlite3 database (no messages and topics "
                       "tables)")
    (total, fit), = db.execute(f"SELECT count(*), CAST(total({_FIT}) AS INTEGER) "
                               "FROM topics").fetchall()
    assert isinstance(total, int) and isinstance(fit, int)  # count and a cast total
    topics: dict[int, tuple[str, str]] = {}
    for cid, name, kind, encoding in db.execute(_TOPICS):
        if encoding == "cdr":
            topics[cid] = (name, kind)
        else:
            problems.append(f"{path}: {name!r}: serialization format {encoding!r}, not "
                            "cdr; skipped")
    skipped = total - min(fit, MAX_TOPICS)
    if skipped:
        problems.append(f"{path}: {skipped} topics skipped (a "
                        "name, type or serialization format that is not text of at most "
                        f"{MAX_NAME_BYTES} bytes, or past the first {MAX_TOPICS})")
    return topics


def db3_messages(path: Path, problems: list[str], *, compressed: bool = False
                 ) -> Iterator[list[Message]]:
    """The messages of one ``.db3`` file, in time order."""
    try:
        db = apsw.Connection(f"{path.resolve().as_uri()}?immutable=1",
                             flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI)
    except (apsw.Error, OSError) as exc:
        raise BagError(f"{path}: cannot open as a sqlite3 database ({_one_line(exc)})"
                       ) from None
    try:
        try:
            topics = _topics(db, path, problems)
            rows = db.execute(_MESSAGES, (MAX_MESSAGE_BYTES,))
        except apsw.Error as exc:
            raise BagError(f"{path}: not a readable rosbag2 sqlite3 database "
                           f"({_one_line(exc)})") from None
        yield from _blocks(rows, topics, path, problems, compressed)
    finally:
        db.close()


def _blocks(rows: apsw.Cursor, topics: dict[int, tuple[str, str]], path: Path,
            problems: list[str], compressed: bool) -> Iterator[list[Message]]:
    """The message rows in blocks of ``BLOCK``; the rows skipped counted by reason."""
    counts = {"large": 0, "bad": 0, "zstd": 0, "topic": 0}
    block: list[Message] = []
    held = 0
    try:
        for cid, stamp, is_blob, data in rows:
            if not is_blob or type(stamp) is not int:
                counts["bad"] += 1
                continue
            if data is None:
                counts["large"] += 1
                continue
            topic = topics.get(cid) if type(cid) is int else None
            if topic is None:
                counts["topic"] += 1
                continue
            if compressed:
                try:
                    data = _decompress(data)
                except (zstandard.ZstdError, BagError):
                    counts["zstd"] += 1
                    continue
            block.append((topic[0], topic[1], stamp, data))
            held += len(data)
            if len(block) >= BLOCK or held >= MAX_MESSAGE_BYTES:
                yield block
                block, held = [], 0
    except (apsw.Error, MemoryError) as exc:
        problems.append(f"{path}: database damaged ({_one_line(exc)}); the messages before "
                        "it are kept")
    if block:
        yield block
    lines = {"large": f"larger than {MAX_MESSAGE_BYTES} bytes",
             "bad": "whose time or data has the wrong type (a damaged row)",
             "topic": "on a topic not read (not listed, not cdr, or skipped)",
             "zstd": "whose zstd compression cannot be undone"}
    problems.extend(f"{path}: {counts[k]} messages {line} skipped"
                    for k, line in lines.items() if counts[k])


def _decompress(data: bytes) -> bytes:
    """One zstd frame, within ``MAX_MESSAGE_BYTES``."""
    reader = zstandard.ZstdDecompressor().stream_reader(data)
    out = reader.read(MAX_MESSAGE_BYTES + 1)
    if len(out) > MAX_MESSAGE_BYTES:
        raise BagError("decompresses beyond the message budget")
    return out
