"""Reading a bag: ``iter_bag`` (pieces in log-time order), ``read_bag`` (them joined),
``raw_messages`` (not decoded); each file walked from its start, never through its summary
(docs/reliability.md, "Bags")."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from strain_comp.errors import BagError
from strain_comp.io.bag.decode import channel_messages, decode
from strain_comp.io.bag.layout import bag_storage
from strain_comp.io.bag.records import Collector
from strain_comp.io.bag.schemas import BagContents, Series
from strain_comp.io.bag.walk import storage_file

WINDOW = 200_000
"""Messages ``iter_bag`` lets wait before it cuts a piece."""
MAX_HELD_BYTES = 256 * 2**20
"""Message bytes ``iter_bag`` holds undecoded [bytes]: it cuts a piece there."""
MAX_BAG_BYTES = 2**30
"""Message bytes ``read_bag`` and ``raw_messages`` read from one bag [bytes]."""


def read_bag(path: str | os.PathLike[str], *, budget: bool = True) -> BagContents:
    """A whole bag: ``iter_bag``'s pieces joined; ``budget``: refuse past ``MAX_BAG_BYTES``."""
    merged = BagContents()
    parts: dict[str, list[Series]] = {}
    for piece in iter_bag(path, budget=MAX_BAG_BYTES if budget else None):
        for topic, series in piece.series.items():
            parts.setdefault(topic, []).append(series)
        for topic, labels in piece.labels.items():
            merged.labels.setdefault(topic, labels)
        merged.problems += piece.problems
        merged.diagnostics += piece.diagnostics
        merged.types.update(piece.types)
    for topic, pieces in parts.items():
        width = pieces[0].values.shape[1:]
        same = [p for p in pieces if p.values.shape[1:] == width]
        if len(same) < len(pieces):  # as ``decode`` keeps one width per array topic
            n = sum(p.t.size for p in pieces if p.values.shape[1:] != width)
            merged.problems += located(path, [f"{topic}: {n} messages of another array "
                                              "width than the first ones skipped"])
        series = same[0] if len(same) == 1 else Series(
            np.concatenate([p.t for p in same]), np.concatenate([p.values for p in same]))
        pieces.clear()
        if series.t.size > 1 and bool(np.any(np.diff(series.t) < 0)):
            order = np.argsort(series.t, kind="stable")
            series = Series(series.t[order], series.values[order])
        merged.series[topic] = series
    return merged


def _check_budget(col: Collector, file: Path, budget: int) -> None:
    if col.collected > budget:
        raise BagError(f"{file}: more than {budget} bytes of messages "
                       "(the whole-bag reader's budget)")


def _walk(path: Path, col: Collector) -> Iterator[Path]:
    """Collect every storage file of the bag into ``col``; the file after each record."""
    files, compressed = bag_storage(path)
    for index, file in enumerate(files):
        col.file_index = index
        for _ in storage_file(col, file, compressed):
            yield file


class RawMessage(NamedTuple):
    """A message as the bag stores it (CDR), not decoded."""

    topic: str
    type_name: str
    log_time_ns: int
    data: bytes


def raw_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None
                 ) -> tuple[list[RawMessage], list[str]]:
    """Every CDR message of a bag, not decoded, in log-time order; the problems."""
    path = Path(path)
    col = Collector(set(topics) if topics is not None else None)
    for file in _walk(path, col):  # every message located, within ``MAX_BAG_BYTES``
        _check_budget(col, file, MAX_BAG_BYTES)
    out: list[RawMessage] = []
    if col.msg_time:
        blob, start, length, log_ns, groups = channel_messages(col, col.problems)
        group = np.full(log_ns.size, -1)
        for g, (_, _, idx) in enumerate(groups):
            group[idx] = g
        kept = np.flatnonzero(group >= 0)
        for i in kept[np.argsort(log_ns[kept], kind="stable")].tolist():
            topic, schema, _ = groups[group[i]]
            out.append(RawMessage(topic, schema.name, int(log_ns[i]),
                                  blob[start[i]:start[i] + length[i]].tobytes()))
    return out, located(path, col.problems)


def iter_bag(path: str | os.PathLike[str], *, window: int = WINDOW,
             budget: int | None = None) -> Iterator[BagContents]:
    """A bag piece by piece in log-time order, about ``window`` messages each."""
    path = Path(path)
    col = Collector(None)
    cut: int | None = None
    for file in _walk(path, col):
        if budget is not None:
            _check_budget(col, file, budget)
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


def _take(col: Collector, upto: int | None, cut: int | None
          ) -> tuple[BagContents | None, int | None]:
    """The messages before ``upto`` [ns] (None: all) taken from ``col``, decoded; the new cut."""
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
    sub = Collector(col.topics)
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
    return decode(sub), new_cut if cut is None else max(cut, new_cut)


def located(path: str | os.PathLike[str], problems: Iterable[str]) -> list[str]:
    """Problem lines that all name the bag."""
    prefix = str(path)
    return [p if p.startswith(prefix) else f"{prefix}: {p}" for p in problems]
