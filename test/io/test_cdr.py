"""The CDR encoders (strain_comp.io.cdr: mcap_ros2's encoder, and the templates the writer
and the node fill in bulk) against rosbags' serialiser, an independent implementation of
the ROS 2 types: byte for byte over random messages with empty sequences, unicode strings
and every alignment case."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from strain_comp.io import cdr
from strain_comp.io.bag import SCHEMAS, BagWriter, read_bag

rosbags_typesys = pytest.importorskip("rosbags.typesys")
STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
TEXTS = ["", "a", "ab", "abc", "abcd", "s1", "Dehnung µε", "温度", "🙂x", "k=v,w", "x" * 37]


def _text(rng: np.random.Generator) -> str:
    return str(TEXTS[rng.integers(len(TEXTS))]) + "é" * int(rng.integers(0, 3))


def _floats(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
    special = np.array([0.0, -0.0, np.inf, -np.inf, 5e-324, np.finfo(float).max])
    mask = rng.random(n) < 0.1
    v[mask] = rng.choice(special, int(mask.sum()))
    return v


def _header(rng: np.random.Generator) -> dict[str, Any]:
    return {"stamp": {"sec": int(rng.integers(-2**31, 2**31)),
                      "nanosec": int(rng.integers(0, 10**9))}, "frame_id": _text(rng)}


def _random(kind: str, rng: np.random.Generator) -> dict[str, Any]:
    """A random message of ``kind`` as nested dicts (standard field names)."""
    n = int(rng.choice([0, 0, 1, 2, 3, 5, 8]))
    if kind == "std_msgs/msg/Float64":
        return {"data": float(_floats(rng, 1)[0])}
    if kind == "std_msgs/msg/Float32":
        return {"data": float(np.float32(rng.standard_normal()))}
    if kind == "std_msgs/msg/Int8":
        return {"data": int(rng.integers(-128, 128))}
    if kind == "std_msgs/msg/Float64MultiArray":
        return {"layout": {"dim": [{"label": _text(rng), "size": int(rng.integers(0, 2**32)),
                                    "stride": int(rng.integers(0, 2**32))}
                                   for _ in range(int(rng.integers(0, 3)))],
                           "data_offset": int(rng.integers(0, 2**32))},
                "data": _floats(rng, n)}
    if kind == "sensor_msgs/msg/Temperature":
        return {"header": _header(rng), "temperature": float(_floats(rng, 1)[0]),
                "variance": float(rng.random())}
    if kind == "diagnostic_msgs/msg/DiagnosticArray":
        return {"header": _header(rng), "status": [
            {"level": int(rng.integers(0, 4)), "name": _text(rng), "message": _text(rng),
             "hardware_id": _text(rng),
             "values": [{"key": _text(rng), "value": _text(rng)}
                        for _ in range(int(rng.integers(0, 4)))]}
            for _ in range(n)]}
    if kind == "sensor_msgs/msg/JointState":
        k = int(rng.integers(0, 2)) * n  # velocity / effort either empty or one per name
        return {"header": _header(rng), "name": [_text(rng) for _ in range(n)],
                "position": _floats(rng, n), "velocity": _floats(rng, k),
                "effort": _floats(rng, n if rng.random() < 0.3 else 0)}
    raise AssertionError(kind)


def _lists(msg: Any) -> Any:
    """``msg`` with its numpy arrays as lists (the encoder takes sequences as lists)."""
    if isinstance(msg, dict):
        return {key: _lists(value) for key, value in msg.items()}
    if isinstance(msg, list):
        return [_lists(value) for value in msg]
    return msg.tolist() if isinstance(msg, np.ndarray) else msg


def _encode(kind: str, msg: Any) -> bytes:
    return cdr.message_encoder(kind)(_lists(msg))


def _rosbags(kind: str, msg: Any) -> Any:
    """The same message as a rosbags message object (nested types built by name)."""
    types = {"layout": "std_msgs/msg/MultiArrayLayout",
             "dim": "std_msgs/msg/MultiArrayDimension",
             "header": "std_msgs/msg/Header", "stamp": "builtin_interfaces/msg/Time",
             "status": "diagnostic_msgs/msg/DiagnosticStatus",
             "values": "diagnostic_msgs/msg/KeyValue"}
    fields = {}
    for key, value in msg.items():
        if isinstance(value, dict):
            value = _rosbags(types[key], value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            value = [_rosbags(types[key], v) for v in value]
        elif isinstance(value, np.ndarray):
            value = value.astype(np.float64)
        fields[key] = value
    return STORE.types[kind](**fields)


@pytest.mark.parametrize("kind", sorted(SCHEMAS))
def test_encoders_equal_rosbags_byte_for_byte(kind: str) -> None:
    rng = np.random.default_rng(sum(map(ord, kind)))
    for _ in range(300):
        msg = _random(kind, rng)
        assert _encode(kind, msg) == bytes(STORE.serialize_cdr(_rosbags(kind, msg), kind)), msg


def test_schema_texts_define_the_types_rosbags_knows() -> None:
    """Every schema text parses (rosbags' msg parser) to the field list of the standard type."""
    from rosbags.typesys import get_types_from_msg

    for kind, text in SCHEMAS.items():
        parsed = get_types_from_msg(text, kind)[kind]
        standard = STORE.fielddefs[kind]
        assert [f[0] for f in parsed[1]] == [f[0] for f in standard[1]], kind


def test_joint_state_rows_equal_the_message_encoder(tmp_path: Any) -> None:
    """BagWriter.write_joint_state writes whole runs from one template: every payload equals
    the per-message encoder's (stamps split into sec / nanosec)."""
    from mcap.reader import make_reader

    rng = np.random.default_rng(3)
    names = ["a", "bé", "ccc"]
    t = np.sort(rng.random(50)) * 3e5
    pos = rng.standard_normal((50, 3))
    path = tmp_path / "js.mcap"
    with BagWriter(path) as writer:
        writer.write_joint_state("/arr/strain_stamped", t, names, pos)
        writer.write_joint_state("/s/strain_stamped", t, ["s"], pos[:, :1])
    got: dict[str, list[bytes]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            got.setdefault(channel.topic, []).append(message.data)
    lg = np.round(t * 1e9).astype(np.int64)
    kind = "sensor_msgs/msg/JointState"
    assert got["/arr/strain_stamped"] == [
        _encode(kind, {"header": _stamped(int(s)), "name": names, "position": p,
                       "velocity": [], "effort": []})
        for s, p in zip(lg, pos, strict=True)]
    assert got["/s/strain_stamped"] == [
        _encode(kind, {"header": _stamped(int(s)), "name": ["s"], "position": p[:1],
                       "velocity": [], "effort": []})
        for s, p in zip(lg, pos, strict=True)]
    contents = read_bag(path)  # read back quietly: the types listed, no problem lines
    assert contents.types["/s/strain_stamped"] == "sensor_msgs/msg/JointState"
    assert contents.problems == []


def _stamped(t_ns: int) -> dict[str, Any]:
    sec, nanosec = divmod(t_ns, 10**9)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": ""}


def test_temperature_rows_equal_the_message_encoder(tmp_path: Any) -> None:
    """BagWriter.write_temperature writes whole runs from one template: every payload equals
    rosbags' serialisation of the message (stamp = log time), from values given as a
    strided view too."""
    from mcap.reader import make_reader

    rng = np.random.default_rng(0)
    t = np.sort(rng.random(40)) * 3e5
    values = _floats(rng, 40)
    path = tmp_path / "temperature.mcap"
    with BagWriter(path) as writer:  # every other value of a longer array: a strided view
        writer.write_temperature("/s/temperature", t, np.repeat(values, 2)[::2])
    with path.open("rb") as f:
        got = [m.data for _, _, m in make_reader(f).iter_messages()]
    kind = "sensor_msgs/msg/Temperature"
    assert got == [bytes(STORE.serialize_cdr(_rosbags(kind, {
        "header": _stamped(int(ns)), "temperature": float(v), "variance": 0.0}),
        kind)) for ns, v in zip(np.round(t * 1e9).astype(np.int64), values, strict=True)]


def test_long_strings_and_late_stamps(tmp_path: Any) -> None:
    """Long strings encode as rosbags encodes them; a JointState stamp past int32 seconds
    is refused with a BagError, not wrapped."""
    from strain_comp.errors import BagError

    kind = "diagnostic_msgs/msg/DiagnosticArray"
    msg = {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": ""},
           "status": [{"level": 1, "name": "ü" * 300, "message": "m" * 1000,
                       "hardware_id": "", "values": [{"key": "k", "value": "v" * 257}]}]}
    assert _encode(kind, msg) == bytes(STORE.serialize_cdr(_rosbags(kind, msg), kind))
    with BagWriter(tmp_path / "late.mcap") as writer, pytest.raises(BagError, match="2038"):
        writer.write_joint_state("/s/strain_stamped", [2.0**31 + 1.0], ["s"], [[0.5]])


@pytest.mark.parametrize("names", [[], ["s1"], ["a", "bé", "ccc", "温度"],
                                   [f"x{i}" for i in range(256)]])
def test_node_encoders_equal_the_message_encoders(names: list[str]) -> None:
    """The prebuilt-block encoders (strain_comp.io.cdr.RowEncoder) write the bytes of the
    message encoder: JointState with empty velocity and effort, and the Float64MultiArray
    labelled with the names (one wire format for bags and the node)."""
    from strain_comp.io.cdr import RowEncoder

    rng = np.random.default_rng(len(names))
    stamped, vector = RowEncoder.joint_state(names), RowEncoder.vector(names)
    k = len(names)
    for stamp_ns in (1_795_498_137_622_557_762, 0, 5, -1_500_000_000):
        values = _floats(rng, k)
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        [message] = stamped.encode(np.array([values]), np.array([stamp_ns]))
        assert message == _encode("sensor_msgs/msg/JointState", {
            "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": ""},
            "name": names, "position": values, "velocity": [], "effort": []})
        assert vector.encode(np.array([values])) == [_encode("std_msgs/msg/Float64MultiArray", {
            "layout": {"dim": [{"label": ",".join(names), "size": k, "stride": k}],
                       "data_offset": 0}, "data": values})]


def test_the_encoders_import_first() -> None:
    """``strain_comp.io.cdr`` imported before the bag package (as the node imports it):
    no circular import."""
    import subprocess
    import sys

    subprocess.run([sys.executable, "-c", "import strain_comp.io.cdr"], check=True)
