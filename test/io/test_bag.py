"""Bag I/O: round trips, rosbags compatibility, rosbag2 directories, damaged files, fuzz."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.highlevel import AnyReader

import strain_comp.io.bag.schemas as bag_module
from strain_comp.errors import BagError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.bag.reader import raw_messages
from strain_comp.io.cdr import message_encoder

N = 3000
T = 1.0 + np.arange(N) * 0.01
R = 10.0 + np.sin(T)
LABELS = ["a1", "a2", "a3"]
ARRAY = np.column_stack([R, 2 * R, -R])
STATUSES = [[("s1", 0, "ok", {"bad": "0"})],
            [("s1", 1, "warn", {"bad": "3", "stale": "no"}), ("s2", 2, "error", {})]]


def _write_all(path: Path, *, chunk_size: int = 1 << 20) -> None:
    with BagWriter(path, chunk_size=chunk_size) as w:
        w.write_float64("/s1/resistance", T, R)
        w.write_int8("/s1/direction", T, np.sign(np.cos(T)))
        w.write_float64_array("/arr/resistance", T, ARRAY, LABELS)
        w.write_temperature("/s1/temperature", T[::100], 20.0 + T[::100])
        w.write_diagnostics(T[:2], STATUSES)


def _check_all(contents) -> None:
    assert contents.problems == []
    s = contents.series
    np.testing.assert_array_equal(s["/s1/resistance"].values, R)
    np.testing.assert_allclose(s["/s1/resistance"].t, T, atol=1e-9)
    np.testing.assert_array_equal(s["/s1/direction"].values, np.sign(np.cos(T)))
    np.testing.assert_array_equal(s["/arr/resistance"].values, ARRAY)
    np.testing.assert_array_equal(s["/s1/temperature"].values, 20.0 + T[::100])
    assert contents.labels["/arr/resistance"] == LABELS
    assert [d[1] for d in contents.diagnostics] == STATUSES
    assert contents.types["/s1/direction"] == "std_msgs/msg/Int8"


def test_round_trip_every_type(tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    _write_all(path)
    _check_all(read_bag(path))


def test_topic_filter(tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    _write_all(path)
    messages, _ = raw_messages(path, ["/s1/resistance"])
    assert {m.topic for m in messages} == {"/s1/resistance"}


def _rosbags_values(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for con, stamp, raw in reader.messages():
            msg = reader.deserialize(raw, con.msgtype)
            out.setdefault(con.topic, []).append((stamp, msg))
    return out


def _check_rosbags(values: dict[str, list]) -> None:
    res = values["/s1/resistance"]
    np.testing.assert_array_equal([m.data for _, m in res], R)
    np.testing.assert_array_equal([s for s, _ in res], np.round(T * 1e9).astype(np.int64))
    np.testing.assert_array_equal([m.data for _, m in values["/s1/direction"]],
                                  np.sign(np.cos(T)))
    arr = values["/arr/resistance"]
    np.testing.assert_array_equal(np.array([m.data for _, m in arr]), ARRAY)
    assert arr[0][1].layout.dim[0].label == ",".join(LABELS)
    np.testing.assert_array_equal([m.temperature for _, m in values["/s1/temperature"]],
                                  20.0 + T[::100])
    diag = values["/diagnostics"][1][1]
    assert [(x.name, x.level, x.message) for x in diag.status] == [
        ("s1", 1, "warn"), ("s2", 2, "error")]
    assert {kv.key: kv.value for kv in diag.status[0].values} == STATUSES[1][0][3]


def test_written_bag_readable_by_rosbags(tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    _write_all(path, chunk_size=20000)  # several chunks
    _check_rosbags(_rosbags_values(path))


def _rosbag2_dir(tmp_path: Path) -> Path:
    """A rosbag2 directory as `ros2 bag record -s mcap` writes it (split in two files)."""
    bag = tmp_path / "rosbag2_2026_01_01"
    bag.mkdir()
    half = N // 2
    with BagWriter(bag / "rosbag2_2026_01_01_0.mcap") as w:
        w.write_float64("/s1/resistance", T[:half], R[:half])
    with BagWriter(bag / "rosbag2_2026_01_01_1.mcap") as w:
        w.write_float64("/s1/resistance", T[half:], R[half:])
    start, dur = int(T[0] * 1e9), int((T[-1] - T[0]) * 1e9)
    names = [f"rosbag2_2026_01_01_{i}.mcap" for i in (0, 1)]
    info = {
        "version": 8, "storage_identifier": "mcap", "duration": {"nanoseconds": dur},
        "starting_time": {"nanoseconds_since_epoch": start}, "message_count": N,
        "topics_with_message_count": [{
            "topic_metadata": {"name": "/s1/resistance", "type": "std_msgs/msg/Float64",
                               "serialization_format": "cdr",
                               "offered_qos_profiles": bag_module.OFFERED_QOS,
                               "type_description_hash": ""},
            "message_count": N}],
        "compression_format": "", "compression_mode": "", "relative_file_paths": names,
        "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": dur}, "message_count": n}
                  for name, n in zip(names, (half, N - half), strict=True)],
        "custom_data": None, "ros_distro": "jazzy"}
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return bag


def test_rosbag2_directory(tmp_path: Path) -> None:
    bag = _rosbag2_dir(tmp_path)
    contents = read_bag(bag)
    assert contents.problems == []
    np.testing.assert_array_equal(contents.series["/s1/resistance"].values, R)
    values = _rosbags_values(bag)["/s1/resistance"]
    np.testing.assert_array_equal([m.data for _, m in values], R)


def test_big_endian_payloads_are_honoured(tmp_path: Path) -> None:
    """A CDR_BE Float64 payload (flag byte 0) decodes like the little-endian one."""
    from mcap.writer import Writer

    path = tmp_path / "be.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n")
        cid = w.register_channel("/x/resistance", "cdr", sid)
        for i, v in enumerate((1.5, -2.25, 1e300)):
            w.add_message(cid, i, b"\0\0\0\0" + np.array([v], ">f8").tobytes(), i)
        w.add_message(cid, 3, b"\0\1\0\0" + np.array([7.0], "<f8").tobytes(), 3)
        w.finish()
    np.testing.assert_array_equal(read_bag(path).series["/x/resistance"].values,
                                  [1.5, -2.25, 1e300, 7.0])


def test_unknown_schema_is_skipped_and_reported(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / "unknown.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        sid = w.register_schema("geometry_msgs/msg/Point", "ros2msg",
                                b"float64 x\nfloat64 y\nfloat64 z\n")
        cid = w.register_channel("/point", "cdr", sid)
        w.add_message(cid, 0, b"\0\1\0\0" + bytes(24), 0)
        fid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n")
        cid2 = w.register_channel("/s/resistance", "cdr", fid)
        w.add_message(cid2, 1, b"\0\1\0\0" + np.array([3.0]).tobytes(), 1)
        w.finish()
    contents = read_bag(path)
    assert list(contents.series) == ["/s/resistance"]
    assert any("/point" in p and "unsupported" in p for p in contents.problems)


@pytest.fixture(scope="module")
def chunked(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("bags") / "chunked.mcap"
    with BagWriter(path, chunk_size=8000) as w:
        w.write_float64("/s1/resistance", T, R)
    return path.read_bytes()


@pytest.mark.parametrize("fraction", [0.02, 0.25, 0.5, 0.77, 0.93])
def test_truncated_bag_keeps_prefix(tmp_path: Path, chunked: bytes, fraction: float) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(chunked[:int(len(chunked) * fraction)])
    contents = read_bag(path)
    series = contents.series.get("/s1/resistance")
    n = 0 if series is None else series.values.size
    if series is not None:
        np.testing.assert_array_equal(series.values, R[:n])
    # every chunk that lies wholly before the cut is kept: at most one chunk is lost
    per_chunk = 8000 // 43 + 1
    assert n >= int(N * fraction) - 2 * per_chunk - 200
    assert any("truncated" in p for p in contents.problems)


def test_flipped_bytes_never_crash_and_keep_good_chunks(tmp_path: Path, chunked: bytes) -> None:
    rng = np.random.default_rng(7)
    path = tmp_path / "flip.mcap"
    for _ in range(20):
        data = bytearray(chunked)
        for i in rng.integers(8, len(data), 4):
            data[i] ^= int(rng.integers(1, 256))
        path.write_bytes(bytes(data))
        contents = read_bag(path)
        series = contents.series.get("/s1/resistance")
        if series is not None:  # what survives is exact (chunk CRCs)
            idx = np.searchsorted(T, series.t - 1e-9)
            np.testing.assert_array_equal(series.values, R[np.clip(idx, 0, N - 1)])


def test_missing_and_non_mcap_files_raise(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no such bag"):
        read_bag(tmp_path / "nope.mcap")
    text = tmp_path / "notes.mcap"
    text.write_text("this is not a bag\n")
    with pytest.raises(BagError, match="not an MCAP"):
        read_bag(text)
    empty_dir = tmp_path / "empty"
    empty_dir.mkdir()
    with pytest.raises(BagError):
        read_bag(empty_dir)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=6),
       cut=st.floats(0.05, 1.0))
def test_fuzz_reader_only_raises_bag_error(tmp_path_factory: pytest.TempPathFactory,
                                           chunked: bytes, edits: list, cut: float) -> None:
    data = bytearray(chunked[:max(8, int(len(chunked) * cut))])
    for where, value in edits:
        data[min(len(data) - 1, int(where * len(data)))] = value
    path = tmp_path_factory.mktemp("fuzz") / "f.mcap"
    path.write_bytes(bytes(data))
    try:
        read_bag(path)
    except BagError:
        pass


def test_regression_fuzz_overflowing_chunk_length(tmp_path: Path, chunked: bytes) -> None:
    """Found by scripts/fuzz_bag_reader.py: a chunk whose inner length is ~2**64 raised
    OverflowError inside mcap's record parser."""
    data = bytearray(chunked)
    pos = data.index(b"zstd") + 4  # the chunk's records-length field follows its compression
    data[pos:pos + 8] = b"\xff" * 8
    path = tmp_path / "overflow.mcap"
    path.write_bytes(bytes(data))
    contents = read_bag(path)
    assert any("corrupt record" in p for p in contents.problems)
    assert contents.series["/s1/resistance"].values.size > N // 2  # later chunks resynced


def test_damaged_schema_text_of_a_standard_type_is_not_used(tmp_path: Path) -> None:
    """A mangled schema text (found by the fuzzer: it decoded into objects without the
    expected fields) does not matter: a standard type is decoded with its standard
    definition, so the value is read exactly."""
    from mcap.writer import Writer

    path = tmp_path / "schema.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        text = bag_module.SCHEMAS["sensor_msgs/msg/Temperature"].replace("temperature",
                                                                         "temperatura")
        sid = w.register_schema("sensor_msgs/msg/Temperature", "ros2msg", text.encode())
        cid = w.register_channel("/s/temperature", "cdr", sid)
        payload = message_encoder("sensor_msgs/msg/Temperature")(
            {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
             "temperature": 21.0, "variance": 0.0})
        w.add_message(cid, 0, payload, 0)
        w.finish()
    contents = read_bag(path)
    assert contents.problems == []
    np.testing.assert_array_equal(contents.series["/s/temperature"].values, [21.0])


MESSAGES = {  # one message per type the writer encodes, as the writer passes them
    "std_msgs/msg/Float64": {"data": -1.25e-3},
    "std_msgs/msg/Float32": {"data": 0.5},
    "std_msgs/msg/Int8": {"data": -1},
    "std_msgs/msg/Float64MultiArray": {
        "layout": {"dim": [{"label": "a,b,c", "size": 3, "stride": 3}], "data_offset": 0},
        "data": [1.0, -2.5, 3.0e9]},
    "sensor_msgs/msg/Temperature": {
        "header": {"stamp": {"sec": 12, "nanosec": 345}, "frame_id": "s1"},
        "temperature": 21.5, "variance": 0.25},
    "diagnostic_msgs/msg/DiagnosticArray": {
        "header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": ""},
        "status": [{"level": 2, "name": "s1", "message": "bad input", "hardware_id": "",
                    "values": [{"key": "n_nan", "value": "3"}]}]},
    "sensor_msgs/msg/JointState": {
        "header": {"stamp": {"sec": 5, "nanosec": 6}, "frame_id": ""}, "name": ["a", "b"],
        "position": [0.5, -1.0], "velocity": [], "effort": []},
}


def _plain(msg: object) -> object:
    """A rosbags message as nested dicts/lists of plain values (constants left out)."""
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [_plain(m) for m in msg]
    if hasattr(msg, "__dataclass_fields__"):
        return {k: _plain(getattr(msg, k)) for k in msg.__dataclass_fields__
                if k != "__msgtype__" and not k.isupper()}
    return msg


@pytest.mark.parametrize("kind", sorted(MESSAGES))
def test_every_encoder_matches_the_rosbags_deserialiser(kind: str) -> None:
    """The writer's CDR encoders (strain_comp.io.cdr) decoded by rosbags, an
    independent implementation of the ROS 2 types (test_cdr compares the bytes)."""
    from rosbags.typesys import Stores, get_typestore

    assert set(MESSAGES) == set(bag_module.SCHEMAS)
    data = message_encoder(kind)(MESSAGES[kind])
    decoded = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(data, kind)
    assert _plain(decoded) == MESSAGES[kind]


def test_array_values_are_matched_by_label_whatever_the_first_message_says(
        tmp_path: Path) -> None:
    """An array topic whose first message carries 2 labels for 3 values, then arrays in the
    sensors' order, reversed with reversed labels, behind a data_offset, unlabelled, and
    labelled with another sensor: every labelled array is read by name as the node reads it
    (``array_values``), the two whose labels do not name the sensors are skipped and counted.
    The truth: the rows written, in the order a, b, c."""
    from mcap_ros2.writer import Writer

    from strain_comp.io.bag.schemas import SCHEMAS

    rows = np.random.default_rng(25).uniform(10.0, 30.0, (6, 3))
    kind = "std_msgs/msg/Float64MultiArray"
    sent = [("a,b", 0, rows[0]), ("a,b,c", 0, rows[1]), ("c,b,a", 0, rows[2][::-1]),
            ("b,c,a", 1, np.r_[-1.0, rows[3][[1, 2, 0]]]), ("", 0, rows[4]),
            ("a,b,x", 0, rows[5])]
    path = tmp_path / "labels.mcap"
    with path.open("wb") as handle:
        writer = Writer(handle)
        schema = writer.register_msgdef(kind, SCHEMAS[kind])
        for i, (label, offset, data) in enumerate(sent):
            writer.write_message("/arr/resistance", schema, {
                "layout": {"dim": [{"label": label, "size": 3, "stride": 3}],
                           "data_offset": offset},
                "data": data.tolist()}, log_time=10**9 * (i + 1), publish_time=10**9 * (i + 1))
        writer.finish()
    contents = read_bag(path)
    assert contents.labels["/arr/resistance"] == ["a", "b", "c"]
    series = contents.series["/arr/resistance"]
    np.testing.assert_array_equal(series.t, [2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(series.values, rows[1:5])
    assert contents.problems == [f"{path}: /arr/resistance: 2 arrays whose dim[0].label "
                                 "does not name the sensors a,b,c skipped"]
