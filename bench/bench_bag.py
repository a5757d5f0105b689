#!/usr/bin/env python3
"""Bag I/O: today's MCAP writer and reader against the ``mcap`` library's, in one run, on
the same bags, through ``replay`` (write) and ``evaluate`` (read) and ``read_bag``.

    python bench/bench_bag.py [--seconds 10000] [--rate 10] [--array-seconds 10] [--repeat 3]

Two bags (``bench/_common.py`` calibrations and resistances, written by ``BagWriter``): a
1-sensor long bag (``--seconds`` of std_msgs/Float64 at ``--rate``, resistance and strain
reference) and a 256-sensor array bag (``--array-seconds`` of std_msgs/Float64MultiArray of
256 values at 1 kHz, resistance and reference), each with a recorded ``/diagnostics`` at
1 Hz (a status of 8 values per sensor, as the node's), which ``replay`` copies through.

The library path is what strain_comp would run if MCAP framing went through ``mcap``:

* write: ``mcap.writer.Writer`` (zstd chunks of the same size, CRCs, every index), one
  ``add_message`` per message (the library has no bulk call), in place of
  ``io.bag.writer.Stream`` under ``BagWriter`` (same payloads, same log-time merge);
* read: ``mcap.stream_reader.StreamReader`` (chunks decompressed and split by the library,
  one ``Message`` per message), the payloads of each block of messages joined and handed to
  the same bulk numpy decoder (``io.bag.decode``: a Float64 value is ``np.frombuffer`` at
  byte 4), in place of ``io.bag.walk.storage_file`` under ``read_bag`` / ``iter_bag``.
  The candidate does no damage recovery (that would only add to its time);
* the top-level walk alone (``(top)``): ``StreamReader(emit_chunks=True)`` walks the file's
  records (it parses every MessageIndex entry) and each chunk goes to today's ``add_chunk``
  (bounded decompression, CRC, records located in bulk).

Each pair (today, library) is timed alternately ``--repeat`` times in this process, kernels
and caches warm; the median of each is printed with the ratio library / today. Outputs of
the two paths are compared (the same values read; the bags written read back equal).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import calibration, resistance, row

import strain_comp.io.bag.reader as reader_module
import strain_comp.io.bag.writer as writer_module
from strain_comp.core.calibration import Calibration
from strain_comp.errors import BagError
from strain_comp.io.atomic import AtomicFile
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.bag.chunks import MAX_CHUNK_BYTES, add_chunk
from strain_comp.io.bag.records import Collector, add_loose
from strain_comp.io.bag.schemas import LIBRARY, OFFERED_QOS, PROFILE, SCHEMAS
from strain_comp.io.bag.walk import LOOSE_BLOCK, storage_file
from strain_comp.io.bag.writer import Pending, Topic
from strain_comp.offline.evaluate import evaluate_bag
from strain_comp.offline.replay import replay_bag


class LibraryStream:
    """``io.bag.writer.Stream``'s interface through ``mcap.writer.Writer``."""

    def __init__(self, path: Path, inputs: Sequence[str | os.PathLike[str]],
                 chunk_size: int) -> None:
        self.path = path
        self._output = AtomicFile(path, inputs=inputs)
        self._writer = Writer(self._output.handle, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}

    def write_messages(self, topics: Mapping[str, Topic], p: Pending, *, final: bool,
                       before: int | None = None) -> Pending | None:
        """Every buffered message before ``before`` (all when final), one add_message each."""
        for topic, entry in topics.items():
            if entry.id in self._channels:
                continue
            if entry.type not in self._schemas:
                self._schemas[entry.type] = self._writer.register_schema(
                    entry.type, "ros2msg", SCHEMAS[entry.type].encode())
            self._channels[entry.id] = self._writer.register_channel(
                topic, "cdr", self._schemas[entry.type],
                {"offered_qos_profiles": OFFERED_QOS})
        t_ns, chan, seq, poff, plen = p.merged()
        blob = np.concatenate(p.payloads).tobytes()
        n = t_ns.size if before is None or final else int(np.searchsorted(t_ns, before))
        add, channels = self._writer.add_message, self._channels
        for c, t, s, o, k in zip(chan[:n].tolist(), t_ns[:n].tolist(), seq[:n].tolist(),
                                 poff[:n].tolist(), plen[:n].tolist(), strict=True):
            add(channels[c], t, blob[o:o + k], t, s)
        if n == t_ns.size:
            return None
        rest = Pending([t_ns[n:]], [chan[n:]], [seq[n:]], [plen[n:].copy()],
                       [np.frombuffer(b"".join(blob[o:o + k] for o, k in
                                               zip(poff[n:].tolist(), plen[n:].tolist(),
                                                   strict=True)), np.uint8)])
        return rest

    def finish(self) -> None:
        """Summary and footer (the library's), then the atomic rename."""
        self._writer.finish()
        self._output.commit()

    def abort(self) -> None:
        """Drop the temporary file."""
        self._output.discard()


def library_storage_file(col: Collector, file: Path, compressed: bool) -> Iterator[int]:
    """``io.bag.walk.storage_file`` through ``mcap.stream_reader.StreamReader``."""
    if file.suffix == ".db3":
        yield from storage_file(col, file, compressed)
        return
    with file.open("rb") as handle:
        msgs: list[Message] = []
        for record in StreamReader(handle, record_size_limit=2 * MAX_CHUNK_BYTES).records:
            if isinstance(record, Message):
                msgs.append(record)
                if len(msgs) >= LOOSE_BLOCK:
                    _add_messages(col, msgs)
                    msgs = []
                    yield handle.tell()
            elif isinstance(record, Schema):
                col.schemas[(col.file_index, record.id)] = record
            elif isinstance(record, Channel):
                col.channels[(col.file_index, record.id)] = record
        if msgs:
            _add_messages(col, msgs)


def framing_storage_file(col: Collector, file: Path, compressed: bool) -> Iterator[int]:
    """``io.bag.walk.storage_file`` with the top-level records walked by
    ``StreamReader(emit_chunks=True)`` and each chunk handed to today's ``add_chunk``
    (bounded decompression, CRC, the records of the chunk located in bulk)."""
    if file.suffix == ".db3":
        yield from storage_file(col, file, compressed)
        return
    with file.open("rb") as handle:
        loose: list[Message] = []
        for record in StreamReader(handle, emit_chunks=True,
                                   record_size_limit=2 * MAX_CHUNK_BYTES).records:
            if isinstance(record, Chunk):
                col.chunk_start = max(col.chunk_start, record.message_start_time)
                add_chunk(col, record, str(file))
                yield handle.tell()
            elif isinstance(record, Message):
                loose.append(record)
            elif isinstance(record, Schema):
                col.schemas[(col.file_index, record.id)] = record
            elif isinstance(record, Channel):
                col.channels[(col.file_index, record.id)] = record
        if loose:
            add_loose(col, loose, str(file))


def _add_messages(col: Collector, msgs: list[Message]) -> None:
    """The messages' channels, times and payloads (joined) as one block of ``col``."""
    n = len(msgs)
    channel = np.fromiter((m.channel_id for m in msgs), np.int32, n)
    log_ns = np.fromiter((m.log_time for m in msgs), np.int64, n)
    data = [m.data for m in msgs]
    length = np.fromiter(map(len, data), np.int64, n)
    payload = np.frombuffer(b"".join(data), np.uint8)
    col.chunk_start = max(col.chunk_start, int(log_ns.max()))
    col.blocks.append(payload)
    col.held += payload.size
    col.block_file.append(col.file_index)
    col.msg_block.append(np.full(n, len(col.blocks) - 1, np.int32))
    col.msg_channel.append(channel)
    col.msg_time.append(log_ns)
    col.msg_start.append(np.concatenate(([0], np.cumsum(length)[:-1])).astype(np.int64))
    col.msg_len.append(length)


STREAM = writer_module.Stream


def use_library(read: bool = False, write: bool = False, framing: bool = False) -> None:
    """Route the bag reader (``read``; ``framing``: its top-level walk alone) and
    ``BagWriter`` (``write``) through the library or today's code."""
    reader_module.storage_file = (library_storage_file if read else framing_storage_file
                                  if framing else storage_file)
    writer_module.Stream = LibraryStream if write else STREAM  # type: ignore[assignment,misc]


def statuses(names: Sequence[str]) -> list[tuple[str, int, str, dict[str, str]]]:
    """One recorded /diagnostics message: a status per sensor with 8 values, as the node's."""
    keys = ("strain", "resistance", "n_nan", "n_non_positive", "n_open", "n_short",
            "n_out_of_range", "rate_hz")
    return [(f"strain_comp: {name}", 0, "ok", {k: f"{i * 0.125 + j:.4f}"
                                                for j, k in enumerate(keys)})
            for i, name in enumerate(names)]


def make_bags(tmp: Path, seconds: float, rate: int, array_seconds: float
              ) -> list[tuple[str, Path, Calibration]]:
    """The 1-sensor long bag and the 256-sensor array bag, each with its calibration."""
    out = []
    for what, k, secs, hz in (("1 sensor", 1, seconds, rate),
                              ("256-sensor array", 256, array_seconds, 1000)):
        names = [f"s{i}" for i in range(k)]
        cal = calibration(names, ["apl"])
        t = np.arange(round(secs * hz)) / hz
        r = resistance(t, k, seed=1)
        lo, hi = cal.sensors[names[0]].valid_range.r_lo, cal.sensors[names[0]].valid_range.r_hi
        s = 50.0 * (r - lo) / (hi - lo)  # a stand-in reference strain
        path = tmp / f"bag_{k}.mcap"
        with BagWriter(path) as writer:
            ticks = t[::hz]  # a recorded /diagnostics: 1 Hz
            writer.write_diagnostics(ticks, [statuses(names)] * ticks.size)
            if k == 1:
                writer.write_float64("/s0/resistance", t, r[:, 0])
                writer.write_float64("/s0/strain_reference", t, s[:, 0])
            else:
                writer.write_float64_array("/arr/resistance", t, r, names)
                writer.write_float64_array("/arr/strain_reference", t, s, names)
        out.append((f"{what}, {secs:g} s, {t.size:,} x 2 + {ticks.size:,}", path, cal))
    return out


def median_pair(fn: Callable[[], object], repeat: int, **library: bool
                ) -> tuple[float, float]:
    """Median wall times [s] of ``fn`` on today's path and on the library's (``library``:
    ``use_library``'s switches), run alternately."""
    times: tuple[list[float], list[float]] = ([], [])
    for _ in range(repeat):
        for on in (False, True):
            use_library(**library) if on else use_library()
            start = time.perf_counter()
            fn()
            times[on].append(time.perf_counter() - start)
    use_library()
    return statistics.median(times[0]), statistics.median(times[1])


def same_contents(a: Path, b: Path) -> bool:
    """Do two bags read (today's reader) to the same series?"""
    ca, cb = read_bag(a), read_bag(b)
    return ca.series.keys() == cb.series.keys() and all(
        np.array_equal(ca.series[k].t, cb.series[k].t)
        and np.array_equal(ca.series[k].values, cb.series[k].values, equal_nan=True)
        for k in ca.series)


def close(a: object, b: object) -> bool:
    """Equal JSON, numbers to 1e-12 relative (pieces cut elsewhere sum in another order)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k]) for k in a)
    if isinstance(a, float) and isinstance(b, float):
        return bool(np.isclose(a, b, rtol=1e-12, atol=0.0))
    return a == b


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10000.0)
    parser.add_argument("--rate", type=int, default=10)
    parser.add_argument("--array-seconds", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; median of "
          f"{args.repeat}, today and library alternately")
    print("read_bag, evaluate: the mcap library's reader; (top): its StreamReader for the "
          "top-level records only, chunks read as today; replay: its writer")
    print(f"{'bag':<44}{'what':<14}{'today s':>9}{'library s':>11}{'library/today':>15}")
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        for what, bag, cal in make_bags(tmp, args.seconds, args.rate,
                                            args.array_seconds):
            out_today, out_lib = tmp / "today.mcap", tmp / "library.mcap"
            for on in (False, True):  # warm-up: every kernel compiled, both paths checked
                use_library(read=on, write=on)
                replay_bag(bag, cal, out_lib if on else out_today)
                result = evaluate_bag(bag, cal)[0].to_json()
                if not on:
                    reference = result
            use_library(framing=True)
            framed = evaluate_bag(bag, cal)[0].to_json()
            use_library()
            assert same_contents(out_today, out_lib), "the two writers' bags differ"
            assert result["sensors"] and close(result, reference), "the evaluations differ"
            assert close(framed, reference), "the evaluations differ"
            n_out = sum(s.t.size for s in read_bag(out_today).series.values())
            pairs = {
                "read_bag": median_pair(lambda b=bag: read_bag(b), args.repeat, read=True),
                "evaluate": median_pair(lambda b=bag, c=cal: evaluate_bag(b, c), args.repeat,
                                        read=True),
                "read_bag (top)": median_pair(lambda b=bag: read_bag(b), args.repeat,
                                              framing=True),
                "evaluate (top)": median_pair(lambda b=bag, c=cal: evaluate_bag(b, c),
                                              args.repeat, framing=True),
                "replay": median_pair(lambda b=bag, c=cal, o=out_today: replay_bag(b, c, o),
                                      args.repeat, write=True),
            }
            for name, (t_today, t_lib) in pairs.items():
                print(f"{what:<44}{name:<14}{t_today:>9.3f}{t_lib:>11.3f}"
                      f"{t_lib / t_today:>14.2f}x", flush=True)
                part = {"replay": "MCAP writer",
                        "read_bag (top)": "top-level MCAP walk",
                        "evaluate (top)": "top-level MCAP walk"}.get(name, "MCAP reader")
                row(f"{name}, {what}, the library's {part} in place of today's "
                    "(`bench_bag.py`)",
                    f"{t_lib:.2f} s", f"today's path: {t_today:.2f} s",
                    f"{t_lib / t_today:.2f}x slower")
            print(f"  (replay writes {n_out:,} numeric messages back)")


if __name__ == "__main__":
    try:
        main()
    except BagError as exc:
        sys.exit(f"bench_bag: {exc}")
