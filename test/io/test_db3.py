"""rosbag2's sqlite3 storage (.db3, Humble's and Iron's default) reads as MCAP does: a .db3
bag written by rosbags from the messages of a bundled MCAP evaluates, replays, fits and
diagnoses digit for digit like the MCAP; compressed bags read (zstd per message) or are
refused in one line saying how to decompress; a hostile .db3 is one line, exit 2."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import zstandard
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
from rosbags.typesys import Stores, get_typestore

import strain_comp as sc
from strain_comp.cli import main
from strain_comp.io.bag import read_bag
from strain_comp.io.bag.reader import raw_messages

ROOT = Path(__file__).resolve().parents[2]
MCAP = ROOT / "bags" / "demo_rates.mcap"
ARRAY = ROOT / "bags" / "array.mcap"
CAL = str(ROOT / "config" / "demo_calibration.yaml")
TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)


def write_db3(source: Path, target: Path, *, compression: CompressionMode | None = None
              ) -> Path:
    """A rosbag2 sqlite3 bag (a directory) with every message of ``source``, by rosbags."""
    messages, problems = raw_messages(source)
    assert not problems
    writer = Writer(target, version=8)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, kind, stamp, payload in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=TYPESTORE)
            writer.write(connections[topic], stamp, payload)
    return target


@pytest.fixture(scope="module")
def db3_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_db3(MCAP, tmp_path_factory.mktemp("db3") / "demo_rates")


def test_the_db3_bag_is_a_humble_bag(db3_bag: Path) -> None:
    files = list(db3_bag.glob("*.db3"))
    assert len(files) == 1
    with sqlite3.connect(files[0]) as db:
        assert db.execute("SELECT count(*) FROM messages").fetchone()[0] > 14451
    assert "storage_identifier: sqlite3" in (db3_bag / "metadata.yaml").read_text()


def test_db3_reads_as_the_mcap(db3_bag: Path) -> None:
    mcap, db3 = read_bag(MCAP), read_bag(db3_bag)
    assert db3.problems == []
    assert set(db3.series) == set(mcap.series)
    for topic, series in mcap.series.items():
        np.testing.assert_array_equal(db3.series[topic].t, series.t)
        np.testing.assert_array_equal(db3.series[topic].values, series.values)
    bare = next(db3_bag.glob("*.db3"))  # a bare .db3 file reads the same
    np.testing.assert_array_equal(read_bag(bare).series["/s1/resistance"].values,
                                  mcap.series["/s1/resistance"].values)


def test_db3_evaluates_digit_for_digit(db3_bag: Path, tmp_path: Path) -> None:
    for name, bag in (("mcap", MCAP), ("db3", db3_bag)):
        assert main(["evaluate", str(bag), "--calibration", CAL, "--json",
                     str(tmp_path / f"{name}.json"), "--csv", str(tmp_path / f"{name}.csv"),
                     "-q"]) == 0
    by_mcap = json.loads((tmp_path / "mcap.json").read_text())
    assert json.loads((tmp_path / "db3.json").read_text()) == by_mcap
    assert by_mcap["sensors"]["s1"]["n"] == 14451
    strip = [line.split(",", 1)[1] for line in  # the bag column names the file
             (tmp_path / "mcap.csv").read_text().splitlines()]
    assert [line.split(",", 1)[1] for line in
            (tmp_path / "db3.csv").read_text().splitlines()] == strip


def test_db3_replays_fits_and_diagnoses_like_the_mcap(db3_bag: Path, tmp_path: Path) -> None:
    for name, bag in (("mcap", MCAP), ("db3", db3_bag)):
        assert main(["replay", str(bag), "--calibration", CAL, "--out",
                     str(tmp_path / f"{name}_out.mcap"), "-q"]) == 0
        assert main(["fit", str(bag), "--model", "cubic", "--sensor", "s1", "--out",
                     str(tmp_path / f"{name}.yaml"), "-q"]) == 0
    out_mcap, out_db3 = read_bag(tmp_path / "mcap_out.mcap"), read_bag(tmp_path / "db3_out.mcap")
    np.testing.assert_array_equal(out_db3.series["/s1/strain"].values,
                                  out_mcap.series["/s1/strain"].values)
    assert sc.load_calibration(tmp_path / "db3.yaml").sensors["s1"].params == \
        sc.load_calibration(tmp_path / "mcap.yaml").sensors["s1"].params
    recordings = sc.read_recordings(db3_bag)
    assert recordings["s1"].t.size == 14451


def test_an_array_bag_in_db3(tmp_path: Path) -> None:
    bag = write_db3(ARRAY, tmp_path / "array")
    mcap, db3 = read_bag(ARRAY), read_bag(bag)
    assert db3.labels == mcap.labels
    for topic, series in mcap.series.items():
        np.testing.assert_array_equal(db3.series[topic].values, series.values)


def test_zstd_per_message_reads(tmp_path: Path) -> None:
    bag = write_db3(MCAP, tmp_path / "per_message", compression=CompressionMode.MESSAGE)
    mcap, db3 = read_bag(MCAP), read_bag(bag)
    np.testing.assert_array_equal(db3.series["/s1/resistance"].values,
                                  mcap.series["/s1/resistance"].values)


def test_zstd_per_file_is_refused_with_how_to_decompress(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_db3(MCAP, tmp_path / "per_file", compression=CompressionMode.FILE)
    assert list(bag.glob("*.db3.zstd"))
    capsys.readouterr()
    assert main(["evaluate", str(bag), "--calibration", CAL]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("strain-comp: error: ")
    assert "compressed per file" in err and "rosbags-convert" in err


def test_a_zstd_bomb_per_message_is_skipped_and_counted(db3_bag: Path, tmp_path: Path) -> None:
    bag = tmp_path / "bomb"
    shutil.copytree(db3_bag, bag)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("compression_format: ''",
                                             "compression_format: zstd")
                    .replace("compression_mode: ''", "compression_mode: MESSAGE"))
    db = next(bag.glob("*.db3"))
    bomb = zstandard.ZstdCompressor().compress(bytes(2**27))  # 128 MiB of zeros
    with sqlite3.connect(db) as conn:
        conn.execute("UPDATE messages SET data = ? WHERE id = 1", (bomb,))
        rows = conn.execute("SELECT id, data FROM messages WHERE id > 1").fetchall()
        conn.executemany("UPDATE messages SET data = ? WHERE id = ?",
                         [(zstandard.ZstdCompressor().compress(d), i) for i, d in rows])
    contents = read_bag(bag)
    assert any("1 messages whose zstd compression cannot be undone" in p
               for p in contents.problems)
    n = read_bag(MCAP).series
    assert sum(s.t.size for s in contents.series.values()) == \
        sum(s.t.size for s in n.values()) - 1


@pytest.mark.parametrize("damage", ["garbage", "truncated", "no_tables"])
def test_a_hostile_db3_is_one_line(damage: str, db3_bag: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    good = next(db3_bag.glob("*.db3")).read_bytes()
    bad = tmp_path / "bad.db3"
    if damage == "garbage":
        bad.write_bytes(b"SQLite format 3\x00" + bytes(range(256)) * 64)
    elif damage == "truncated":
        bad.write_bytes(good[:len(good) // 3])
    else:
        with sqlite3.connect(bad) as conn:
            conn.execute("CREATE TABLE other (x)")
    capsys.readouterr()
    code = main(["evaluate", str(bad), "--calibration", CAL])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("strain-comp: error: ")
    assert str(bad) in err


def test_play_gets_the_same_messages(db3_bag: Path) -> None:
    """``strain-comp play`` publishes ``raw_messages``: the same from either storage."""
    from_mcap, _ = raw_messages(MCAP)
    from_db3, problems = raw_messages(db3_bag)
    assert problems == [] and from_db3 == from_mcap


def test_damaged_db3_files_read_or_are_refused_in_one_line(db3_bag: Path,
                                                           tmp_path: Path) -> None:
    """A seeded run of byte flips, overwritten spans, truncations and duplicated or
    deleted spans of a small .db3 (the MCAP fuzzer's mutations, scripts/fuzz.py): reading
    may only refuse with BagError (one line) or return consistent series."""
    from strain_comp.errors import BagError

    seed = tmp_path / "seed"
    messages, _ = raw_messages(ROOT / "bags" / "steps.mcap")
    with Writer(seed, version=8) as writer:
        connections = {}
        for topic, kind, stamp, payload in messages[:3000]:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=TYPESTORE)
            writer.write(connections[topic], stamp, payload)
    data = next(seed.glob("*.db3")).read_bytes()
    rng = np.random.default_rng(0)
    outcomes = {"read": 0, "refused": 0}
    for k in range(150):
        buf = bytearray(data)
        for _ in range(int(rng.integers(1, 5))):
            i = int(rng.integers(0, len(buf)))
            op = int(rng.integers(0, 4))
            if op == 0:
                buf[i] ^= 1 << int(rng.integers(0, 8))
            elif op == 1:
                buf[i:i + 16] = bytes([int(rng.integers(0, 256))]) * len(buf[i:i + 16])
            elif op == 2:
                del buf[max(i, 200):]
            else:
                buf[i:i] = buf[i:i + int(rng.integers(1, 64))]
        path = tmp_path / f"damaged_{k}.db3"
        path.write_bytes(bytes(buf))
        try:
            contents = read_bag(path)
        except BagError as err:
            assert "\n" not in str(err) and str(path) in str(err)
            outcomes["refused"] += 1
            continue
        for series in contents.series.values():
            assert series.t.shape[0] == series.values.shape[0]
            assert np.isfinite(series.t).all()
        outcomes["read"] += 1
    assert outcomes["read"] > 0 and outcomes["refused"] > 0, outcomes


@pytest.fixture(scope="module")
def small_db3(tmp_path_factory: pytest.TempPathFactory
              ) -> tuple[Path, list[tuple[str, str, int, bytes]]]:
    """A rosbag2 directory of the first 6000 messages of demo_rates (3000 resistances and
    3000 references, interleaved), and those messages."""
    messages, _ = raw_messages(MCAP)
    messages = messages[:6000]
    bag = tmp_path_factory.mktemp("small") / "small"
    with Writer(bag, version=8) as writer:
        connections = {}
        for topic, kind, stamp, payload in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=TYPESTORE)
            writer.write(connections[topic], stamp, payload)
    return bag, messages


def altered(bag: Path, target: Path, *statements: tuple[str, tuple[object, ...]]) -> Path:
    """A copy of ``bag`` whose .db3 file had the SQL ``statements`` run on it."""
    shutil.copytree(bag, target)
    with sqlite3.connect(next(target.glob("*.db3"))) as conn:
        for sql, args in statements:
            conn.execute(sql, args)
    return target


@pytest.mark.parametrize("qos", ["[" * 5000, "- 1\n- 2\n", "{a: [1, {b: *x}]}", "\x00\xff"])
def test_hostile_qos_profiles_are_never_parsed(
        qos: str, small_db3: tuple[Path, list[tuple[str, str, int, bytes]]],
        tmp_path: Path) -> None:
    """rosbag2 stores each topic's offered QoS as YAML text; strain_comp does not need it,
    so a hostile one (deep brackets that overflowed the YAML parser's recursion, a list where
    a mapping belongs) reads as the untouched bag does."""
    bag, messages = small_db3
    hostile = altered(bag, tmp_path / "qos",
                      ("UPDATE topics SET offered_qos_profiles = ?", (qos,)))
    assert raw_messages(hostile) == (messages, [])


def test_a_topic_name_stored_as_a_blob_skips_that_topic(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A topic whose name (or type) is not text, or is longer than MAX_NAME_BYTES, is skipped
    with a problem line; the other topics read exactly. With the resistance topic gone,
    evaluate is one line, exit 2 (it was an internal error, exit 70)."""
    bag, messages = small_db3
    blob = altered(bag, tmp_path / "blob", (
        "UPDATE topics SET name = CAST(name AS BLOB) WHERE name = '/s1/strain_reference'", ()))
    got, problems = raw_messages(blob)
    assert got == [m for m in messages if m[0] != "/s1/strain_reference"]
    assert [p.split(": ", 2)[-1] for p in problems] == [
        "1 topics skipped (a name, type or serialization format that is not text of at most "
        "4096 bytes, or past the first 65535)",
        "3000 messages on a topic not read (not listed, not cdr, or skipped) skipped"]
    long_type = altered(bag, tmp_path / "long", (
        "UPDATE topics SET type = ? WHERE name = '/s1/resistance'", ("x" * 4097,)))
    assert raw_messages(long_type)[0] == [m for m in messages if m[0] != "/s1/resistance"]
    capsys.readouterr()
    assert main(["evaluate", str(long_type), "--calibration", CAL]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("strain-comp: error: ")


def test_a_damaged_row_is_skipped_and_every_other_message_kept(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path) -> None:
    """A message row whose data, time or topic has the wrong type (here the 3000th's data is
    an integer) is skipped and counted: the 2999 before it and the 3000 after it are kept
    (every one was lost before: the block being filled was dropped with the error)."""
    bag, messages = small_db3
    damaged = altered(bag, tmp_path / "row", ("UPDATE messages SET data = 5 WHERE id = 3000", ()),
                      ("UPDATE messages SET timestamp = 'late' WHERE id = 10", ()),
                      ("UPDATE messages SET topic_id = 99 WHERE id = 20", ()))
    got, problems = raw_messages(damaged)
    assert got == [m for i, m in enumerate(messages, 1) if i not in (10, 20, 3000)]
    assert any("2 messages whose time or data has the wrong type" in p for p in problems)
    assert any("1 messages on a topic not read" in p for p in problems)


def test_a_damaged_page_keeps_every_message_before_it(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path) -> None:
    """sqlite's own damage (a page of the messages table overwritten) ends the file: every
    message stored before the damaged page is kept, with a problem line saying so."""
    bag, messages = small_db3
    damaged = tmp_path / "page"
    shutil.copytree(bag, damaged)
    db = next(damaged.glob("*.db3"))
    data = bytearray(db.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    at = data.find(messages[3000][3] + b"")  # the 3001st message's payload
    assert at > 0
    start = at - at % page
    data[start:start + page] = b"\xee" * page
    db.write_bytes(bytes(data))
    got, problems = raw_messages(damaged)
    assert 2000 < len(got) <= 3000
    assert got == messages[:len(got)]
    assert any("database damaged" in p and "the messages before it are kept" in p
               for p in problems)


def test_a_message_beyond_the_budget_is_never_fetched(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The budget is checked on the size sqlite reads from the row's header, before the
    data is fetched: a 24 MiB row against a 1 MiB budget is skipped and counted while the
    Python heap's peak stays far below the row (it was fetched whole, then dropped)."""
    import tracemalloc

    from strain_comp.io.bag import db3

    bag, messages = small_db3
    big = altered(bag, tmp_path / "big",
                  ("UPDATE messages SET data = zeroblob(24 * 1048576) WHERE id = 5", ()))
    monkeypatch.setattr(db3, "MAX_MESSAGE_BYTES", 2**20)
    tracemalloc.start()
    try:
        got, problems = raw_messages(big)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert got == messages[:4] + messages[5:]
    assert any(f"1 messages larger than {2**20} bytes skipped" in p for p in problems)
    assert peak < 8 * 2**20, peak


def test_storage_files_listed_again_are_read_once(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """metadata.yaml listing its one .db3 2000 times (also as ./NAME) reads it once: the
    same messages as one listing (each listing was read again: 2000 x the samples); more
    than MAX_STORAGE_FILES different files is one line, exit 2, before any is opened."""
    from strain_comp.io.bag.layout import MAX_STORAGE_FILES

    bag, messages = small_db3
    name = next(bag.glob("*.db3")).name
    many = tmp_path / "many"
    shutil.copytree(bag, many)
    meta = many / "metadata.yaml"
    text = meta.read_text()
    listing = "".join(f"  - {p}\n" for p in [name, f"./{name}"] * 1000)
    meta.write_text(text.replace(f"  relative_file_paths:\n  - {name}\n",
                                 f"  relative_file_paths:\n{listing}"))
    assert meta.read_text().count(name) > 2000
    assert raw_messages(many) == (messages, [])
    listing = "".join(f"  - part_{i}.db3\n" for i in range(MAX_STORAGE_FILES + 1))
    meta.write_text(text.replace(f"  relative_file_paths:\n  - {name}\n",
                                 f"  relative_file_paths:\n{listing}"))
    capsys.readouterr()
    assert main(["evaluate", str(many), "--calibration", CAL]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"at most {MAX_STORAGE_FILES} are read" in err


def test_blocks_stay_within_the_byte_budget(
        small_db3: tuple[Path, list[tuple[str, str, int, bytes]]], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Per-message zstd frames of a few bytes each may expand to the message budget: a block
    ends once it holds MAX_MESSAGE_BYTES, so the reader's held-bytes budgets are checked
    between blocks (4096 frames of 64 MiB were one block of 256 GiB)."""
    from strain_comp.io.bag import db3

    bag, _ = small_db3
    frame = zstandard.ZstdCompressor().compress(bytes(2**20))  # 1 MiB, ~50 bytes
    packed = altered(bag, tmp_path / "packed",
                     ("UPDATE messages SET data = ? WHERE id <= 40", (frame,)))
    monkeypatch.setattr(db3, "MAX_MESSAGE_BYTES", 4 * 2**20)
    problems: list[str] = []
    blocks = list(db3.db3_messages(next(packed.glob("*.db3")), problems, compressed=True))
    sizes = [sum(len(m[3]) for m in block) for block in blocks]
    assert max(sizes) <= 8 * 2**20 and sum(sizes) >= 40 * 2**20, sizes
    assert [m[3] for block in blocks for m in block][:40] == [bytes(2**20)] * 40
    assert any("5960 messages whose zstd compression cannot be undone" in p for p in problems)
