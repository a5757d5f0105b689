"""Decoder budgets and type confusion in the bag reader, on hand-built MCAP files.

Each test builds the hostile file it needs (a decompression bomb, a chunk that lies about
its size, a topic on two channels of different types, a recovery that would copy the rest of
the file for every candidate byte) and checks the reader's answer against the messages that
were written.
"""

from __future__ import annotations

import math
import struct
import sys
import tracemalloc
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import zstandard
from conftest import cubic_cal, one_message
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Schema

from strain_comp.cli import main
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration
from strain_comp.io.bag import chunks, iter_bag, read_bag, reader
from strain_comp.io.bag.schemas import MAGIC, SCHEMAS
from strain_comp.ros import live_tare
from strain_comp.ros.live import LiveCompensator
from strain_comp.ros.params import parse_values

ROOT = Path(__file__).resolve().parent.parent
FLOAT64 = "std_msgs/msg/Float64"
TEMPERATURE = "sensor_msgs/msg/Temperature"


def _cdr_float64(x: float) -> bytes:
    return b"\x00\x01\x00\x00" + struct.pack("<d", x)


def _cdr_temperature(x: float) -> bytes:
    """sensor_msgs/Temperature: header (stamp, empty frame id), temperature, variance."""
    head = struct.pack("<iII", 0, 0, 1) + b"\x00"
    body = head + b"\x00" * (-len(head) % 8) + struct.pack("<dd", x, 0.0)
    return b"\x00\x01\x00\x00" + body


def _records(*records: object) -> bytes:
    builder = RecordBuilder()
    for record in records:
        record.write(builder)  # type: ignore[attr-defined]
    return builder.end()


def _chunk(records: bytes, *, claimed: int | None = None, payload: bytes | None = None,
           t0: int = 0) -> Chunk:
    """A zstd chunk of ``records``; ``claimed`` and ``payload`` forge its size and content."""
    data = records if payload is None else payload
    return Chunk(compression="zstd", data=zstandard.ZstdCompressor().compress(data),
                 message_start_time=t0, message_end_time=t0,
                 uncompressed_crc=zlib.crc32(data),
                 uncompressed_size=len(data) if claimed is None else claimed)


def _bag(path: Path, *body: object) -> Path:
    head = _records(Header(profile="ros2", library="test"))
    tail = _records(DataEnd(data_section_crc=0),
                    Footer(summary_start=0, summary_offset_start=0, summary_crc=0))
    path.write_bytes(MAGIC + head + b"".join(
        b if isinstance(b, bytes) else _records(b) for b in body) + tail + MAGIC)
    return path


def _schema(sid: int, kind: str) -> Schema:
    return Schema(id=sid, name=kind, encoding="ros2msg", data=SCHEMAS[kind].encode())


def _channel(cid: int, sid: int, topic: str) -> Channel:
    return Channel(id=cid, topic=topic, message_encoding="cdr", metadata={}, schema_id=sid)


def _messages(cid: int, values: list[float], encode: object, t0_ns: int) -> bytes:
    return _records(*(Message(channel_id=cid, log_time=t0_ns + i * 10**7,
                              publish_time=t0_ns + i * 10**7, sequence=i,
                              data=encode(v))  # type: ignore[operator]
                      for i, v in enumerate(values)))


def _good_chunk(values: list[float], t0_ns: int = 10**9) -> Chunk:
    records = (_records(_schema(1, FLOAT64), _channel(1, 1, "/s1/resistance"))
               + _messages(1, values, _cdr_float64, t0_ns))
    return _chunk(records, t0=t0_ns)


def _peak_mib(fn: object) -> float:
    tracemalloc.start()
    try:
        fn()  # type: ignore[operator]
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def test_a_decompression_bomb_is_skipped_within_the_chunk_budget(tmp_path: Path) -> None:
    """A chunk of zeros expanding to 80 MiB (over the 64 MiB budget) from 2 kB: honest
    about its size, or claiming 100 bytes. Both are skipped and named; the good chunk after
    them is read; the reader never holds the expanded bytes."""
    size = chunks.MAX_CHUNK_BYTES + 16 * 2**20
    zeros = bytes(size)
    honest = _chunk(b"", payload=zeros)
    liar = _chunk(b"", payload=zeros, claimed=100)
    path = _bag(tmp_path / "bomb.mcap", honest, liar, _good_chunk([10.0, 11.0, 12.0]))
    del zeros
    contents = read_bag(path)
    peak = _peak_mib(lambda: read_bag(path))
    np.testing.assert_array_equal(contents.series["/s1/resistance"].values, [10.0, 11.0, 12.0])
    text = " ".join(contents.problems)
    assert "over the budget of 67108864 bytes per chunk" in text
    assert "expands beyond the 100 bytes it claims" in text
    assert peak < 16, peak
    pieces = list(iter_bag(path))
    assert sum(p.series["/s1/resistance"].t.size for p in pieces
               if "/s1/resistance" in p.series) == 3
    from strain_comp.io.bag.reader import raw_messages  # play reads with the same budgets

    played, _ = raw_messages(path)
    assert [struct.unpack("<d", m.data[4:])[0] for m in played] == [10.0, 11.0, 12.0]


def test_held_message_bytes_cut_pieces_and_bound_the_whole_bag_reader(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks that all start at time 0 give ``iter_bag`` no time to cut at: past the held
    budget it delivers what it holds (every message once, in order per piece); ``read_bag``
    refuses past its own budget."""
    values = [[float(10 * c + i) for i in range(50)] for c in range(6)]
    written = [_chunk(_records(_schema(1, FLOAT64), _channel(1, 1, "/s1/resistance"))
                      + _messages(1, v, _cdr_float64, 10**9 + c * 10**9), t0=0)
               for c, v in enumerate(values)]
    path = _bag(tmp_path / "held.mcap", *written)
    monkeypatch.setattr(reader, "MAX_HELD_BYTES", 1000)  # 2 chunks of payload (600 B each)
    pieces = [p.series["/s1/resistance"].values for p in iter_bag(path, window=10**9)
              if "/s1/resistance" in p.series]
    assert len(pieces) >= 3
    np.testing.assert_array_equal(np.concatenate(pieces), np.concatenate(values))
    monkeypatch.setattr(reader, "MAX_BAG_BYTES", 1500)
    with pytest.raises(reader.BagError, match="more than 1500 bytes of messages"):
        read_bag(path)


def test_a_topic_on_two_channels_of_different_types_is_never_read_as_the_other(
        tmp_path: Path) -> None:
    """Temperatures (3), then the real Float64 resistances (20) on one topic: the topic is
    read as Float64 with all 20 values, the temperatures are counted, not read as ohm."""
    ohm = [10.0 + 0.1 * i for i in range(20)]
    records = (_records(_schema(1, TEMPERATURE), _channel(1, 1, "/s1/resistance"),
                        _schema(2, FLOAT64), _channel(2, 2, "/s1/resistance"))
               + _messages(1, [25.0, 26.0, 27.0], _cdr_temperature, 10**9)
               + _messages(2, ohm, _cdr_float64, 2 * 10**9))
    path = _bag(tmp_path / "two_types.mcap", _chunk(records, t0=10**9))
    contents = read_bag(path)
    assert contents.types["/s1/resistance"] == FLOAT64
    np.testing.assert_array_equal(contents.series["/s1/resistance"].values, ohm)
    assert any("3 sensor_msgs/msg/Temperature messages skipped" in p for p in contents.problems)


def test_recovery_checks_each_candidate_in_place(tmp_path: Path) -> None:
    """After a damaged record, 200 000 chunk opcodes each claiming the rest of the file: a
    candidate whose fixed fields disagree is rejected without copying (the old walk copied
    the rest of the file for each: 200 000 x 2 MB); the intact chunk after them is found."""
    n = 200_000
    stride = 10
    junk = bytearray(n * stride)
    for i in range(n):
        pos = i * stride
        junk[pos] = 0x06
        struct.pack_into("<Q", junk, pos + 1, len(junk) - pos - 9)
    damaged = b"\x05" + struct.pack("<Q", 1) + b"\x00"  # a Footer one byte long
    path = _bag(tmp_path / "resync.mcap", _good_chunk([1.0]), damaged, bytes(junk),
                _good_chunk([2.0, 3.0], t0_ns=5 * 10**9))
    seen = [0]
    plausible = chunks._plausible_chunk

    def counting(data: bytes, pos: int, budget: list[int]) -> bool:
        before = budget[0]
        ok = plausible(data, pos, budget)
        seen[0] += before != budget[0]
        return ok

    chunks._plausible_chunk = counting  # type: ignore[assignment]
    try:
        contents = read_bag(path)
    finally:
        chunks._plausible_chunk = plausible  # type: ignore[assignment]
    np.testing.assert_array_equal(contents.series["/s1/resistance"].values, [1.0, 2.0, 3.0])
    assert seen[0] <= 1  # only the intact chunk was copied and checked
    assert any("resumed at the next intact chunk" in p for p in contents.problems)


def _live(tmp_path: Path, tare: str = "calibration") -> LiveCompensator:
    save_calibration(Calibration({"s1": replace(cubic_cal("s1"), rest_resistance=150.0)}),
                     tmp_path / "c.yaml")
    return LiveCompensator(parse_values({"sensors": ["s1"], "s1.calibration": "c.yaml",
                                         "tare": tare}, base_dir=tmp_path))


def test_auto_tare_under_a_paused_clock_is_declined_within_its_budget(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every sample at one clock time (a paused sim clock): the start log stops at its
    budget and the automatic tare is declined with a log line; the calibration's zero
    stays (gain 1)."""
    monkeypatch.setattr(live_tare, "MAX_START_SAMPLES", 1024)
    node = _live(tmp_path, "auto")
    for _ in range(5000):
        one_message(node, "s1", 3.0, 150.0)
    assert not node.taring.pending and node.taring.recent["s1"].n <= live_tare.RING
    assert any("auto tare declined: 1024 samples" in line for line in node.taring.log)
    assert node.engine.input_gain("s1") == 1.0


def test_reload_keeps_the_health_and_refusal_counters(tmp_path: Path) -> None:
    node = _live(tmp_path)
    for i, r in enumerate([150.0, math.nan, 151.0, -1.0]):
        one_message(node, "s1", 1.0 + 0.1 * i, r)
    node.refuse("s1", "wrong type")
    before = node.health()["s1"]
    node = node.hand_over(node.successor(parse_values(
        {"sensors": ["s1"], "s1.calibration": "c.yaml"}, base_dir=tmp_path)))
    one_message(node, "s1", 2.0, 152.0)
    after = node.health()["s1"]
    assert (after.n_good, after.n_nan, after.n_non_positive) == (before.n_good + 1, 1, 1)
    assert node.refused["s1: wrong type"] == 1


def test_temperatures_outside_the_physical_range_are_missing_never_nan(tmp_path: Path) -> None:
    """A temperature term (coefficient 0.5 per K) read 1e308 deg C, inf or -300 deg C: the
    term holds the last valid temperature (25 deg C) instead, batch and step alike; the live
    node refuses and counts the reading. The truth: the same run with 25 deg C throughout."""
    from strain_comp.core.engine import Engine

    term = {"name": "t", "kind": "temperature", "params": {"form": "offset", "t_ref": 23.0},
            "coef": 0.5}
    cal = Calibration({"s1": replace(cubic_cal("s1"), effects=[term], rest_resistance=150.0)})
    t = np.arange(6) * 0.01 + 1.0
    r = np.array([150.0, 155.0, 160.0, 165.0, 160.0, 155.0])
    hostile = np.array([25.0, 1e308, np.inf, -300.0, -1e308, 25.0])
    truth = Engine(cal).run("s1", t, r, np.full(6, 25.0)).strain
    np.testing.assert_allclose(Engine(cal).run("s1", t, r, hostile).strain, truth, atol=1e-12)
    engine = Engine(cal)
    stepped = [engine.step("s1", ti, ri, ti_c).strain
               for ti, ri, ti_c in zip(t, r, hostile, strict=True)]
    np.testing.assert_allclose(stepped, truth, atol=1e-12)
    save_calibration(cal, tmp_path / "c.yaml")
    node = LiveCompensator(parse_values({"sensors": ["s1"], "s1.calibration": "c.yaml"},
                                        base_dir=tmp_path))
    out = []
    for ti, ri, ti_c in zip(t, r, hostile, strict=True):
        node.on_temperature("s1", ti_c)
        out.append(one_message(node, "s1", ti, ri).strain)
    np.testing.assert_allclose(out, truth, atol=1e-12)
    assert sum(node.refused.values()) == 4


def test_two_outputs_of_one_command_on_one_path_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``diagnose --out X --json X`` (the JSON would replace the calibration), also through
    a symbolic link; nothing is written."""
    x = tmp_path / "x.yaml"
    link = tmp_path / "link.yaml"
    link.symlink_to(x)
    for json_path in (x, link):
        code = main(["diagnose", str(ROOT / "bags" / "steps.mcap"), "--calibration",
                     str(ROOT / "config" / "demo_calibration.yaml"), "--out", str(x),
                     "--json", str(json_path)])
        err = capsys.readouterr().err
        assert code == 2 and "given for two outputs" in err, err
        assert not x.exists()


def _csv(tmp_path: Path, text: str, name: str = "in.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def test_csv_column_indices_cost_nothing_beyond_the_file(tmp_path: Path) -> None:
    """A column index past the widest row is refused at once (it used to allocate rows x
    index floats: 2.4 GB for 600000 on 500 rows); a non-ASCII digit is not an index."""
    from strain_comp.errors import InputError
    from strain_comp.io.csv_import import import_csv

    path = _csv(tmp_path, "".join(f"{i * 0.1},{100 + i},{i * 0.2}\n" for i in range(500)))
    for key, match in ((600_000, "the widest row has 3 fields"),
                       ("1000000000", "the widest row has 3 fields"),
                       ("²", "not found in the header"), ("-1", "counts from 0")):
        with pytest.raises(InputError, match=match):
            import_csv(path, fmt="generic", sensor="s1",
                       columns={"time": 0, "resistance": 1, "strain": key})
    peak = _peak_mib(lambda: import_csv(path, fmt="generic", sensor="s1",
                                        columns={"time": 0, "resistance": 1, "strain": 2}))
    assert peak < 8


def test_csv_text_hazards_lose_no_row(tmp_path: Path) -> None:
    """A UTF-8 byte-order mark on a headerless file, U+2028 inside a field, and epoch
    nanoseconds: every row is kept or the refusal says why in one line."""
    from strain_comp.errors import InputError
    from strain_comp.io.csv_import import import_csv

    rows = "".join(f"{i * 0.1:.1f},{100.0 + i}\n" for i in range(10))
    bom, _ = import_csv(_csv(tmp_path, "\ufeff" + rows), fmt="generic", sensor="s1",
                        columns={"time": 0, "resistance": 1})
    np.testing.assert_allclose(bom.r, 100.0 + np.arange(10))
    _, sep = import_csv(_csv(tmp_path, "time,resistance,note\n" + "".join(
        f"{i * 0.1:.1f},{100.0 + i},a\u2028b\n" for i in range(10))), fmt="generic",
        sensor="s1", columns={"time": "time", "resistance": "resistance"})
    assert sep.rows == 10 and sep.kept == 10
    epoch = "".join(f"{1_700_000_000_000_000_000 + i * 10**8},{100.0 + i}\n" for i in range(10))
    with pytest.raises(InputError, match=r"epoch milli- or nanoseconds\? .*--scales time=1e-9"):
        import_csv(_csv(tmp_path, epoch), fmt="generic", sensor="s1",
                   columns={"time": 0, "resistance": 1})
    _, scaled = import_csv(_csv(tmp_path, epoch), fmt="generic", sensor="s1",
                           columns={"time": 0, "resistance": 1}, scales={"time": 1e-9})
    assert scaled.kept == 10
    wide = _csv(tmp_path, "0.0," + "9" * 200_000 + "\n0.1,100\n")
    with pytest.raises(InputError, match="field larger than field limit"):
        import_csv(wide, fmt="generic", sensor="s1", columns={"time": 0, "resistance": 1})


def test_play_takes_message_types_from_its_fixed_registry_only(tmp_path: Path) -> None:
    """A bag naming ``tf2_msgs/msg/TFMessage`` (or a module that would run code on import)
    imports nothing: such messages are not played; a bag holding only them is refused in
    one line before anything is published."""
    from strain_comp.errors import BagError
    from strain_comp.ros.player import PLAYABLE, message_class, play

    for name in ("tf2_msgs/msg/TFMessage", "no_such_pkg/msg/X", "os/msg/system"):
        assert message_class(name) is None
        assert name.split("/")[0] not in sys.modules or name.startswith("os/")
    assert all(message_class(kind).__name__ == kind.rsplit("/", 1)[1] for kind in PLAYABLE)
    schema = Schema(id=1, name="no_such_pkg/msg/X", encoding="ros2msg", data=b"float64 x")
    records = (_records(schema, _channel(1, 1, "/x")) + _messages(1, [1.0], _cdr_float64, 10**9))
    path = _bag(tmp_path / "foreign.mcap", _chunk(records, t0=10**9))
    with pytest.raises(BagError, match="no message of a type play publishes"):
        play(path, wait_s=0.1)
    assert "no_such_pkg" not in sys.modules
