"""The node under the real rclpy, in one process: topics, QoS, parameters, services,
diagnostics and bad messages, with the bundled params files.

Inputs are stamped by the node's clock; here the node runs with ``use_sim_time`` and each
/clock tick is processed before its input, so the outputs must equal ``strain-comp
replay`` (the engine's batch path) of the same samples.
"""

from __future__ import annotations

import math
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import NodeUnderTest, one_message
from ros_env import use_ros_env

ROS_SLOT = 1
use_ros_env(ROS_SLOT)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402  (after the environment is set)
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, Float64MultiArray, Int8, MultiArrayDimension  # noqa: E402

from strain_comp.core.calibration_file import load_calibration, save_calibration  # noqa: E402
from strain_comp.core.engine import Engine  # noqa: E402
from strain_comp.io.bag.reader import raw_messages  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"
N_BAG = 400


class Harness(NodeUnderTest):
    """The node under test, a probe node, one executor, a sim clock."""

    def __init__(self, ctx: Any, params_file: Path, *extra: str) -> None:
        super().__init__(ctx, params_file.parent, [
            "--ros-args", "--params-file", str(params_file), "-p", "use_sim_time:=true",
            "-p", "diagnostics_period_s:=0.1", *extra])
        self.clock_pub = self.probe.create_publisher(Clock, "/clock", 10)
        self.received: dict[str, list[Any]] = {}
        self.t_ns = 1_000_000_000

    def listen(self, topic: str, kind: Any) -> list[Any]:
        got: list[Any] = []
        self.probe.create_subscription(kind, topic, got.append, 100)
        self.received[topic] = got
        return got

    def tick(self, t_ns: int) -> None:
        """Publish /clock = t_ns and wait until the node's clock shows it."""
        self.t_ns = t_ns
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 1_000_000_000)
        self.clock_pub.publish(msg)
        assert self.spin_until(lambda: self.node.get_clock().now().nanoseconds == t_ns)

    def feed(self, pub: Any, msg: Any, answer: list[Any], t_ns: int | None = None) -> bool:
        """Tick the clock (default +1 ms), publish, wait for one more message on ``answer``."""
        self.tick(self.t_ns + 1_000_000 if t_ns is None else t_ns)
        n = len(answer)
        pub.publish(msg)
        return self.spin_until(lambda: len(answer) > n, 2.0)

    def diagnostics(self) -> dict[str, tuple[int, str, dict[str, str]]]:
        """The statuses of a /diagnostics message published after the clock moved on."""
        got = self.received.get("/diagnostics") or self.listen("/diagnostics", DiagnosticArray)
        n = len(got)
        self.spin_until(lambda: False, 0.05)
        self.tick(self.t_ns + 200_000_000)
        assert self.spin_until(lambda: len(got) > n)
        return {s.name: (s.level[0], s.message, {kv.key: kv.value for kv in s.values})
                for s in got[-1].status}


@pytest.fixture()
def single(context: Any, tmp_path: Path) -> Iterator[Harness]:
    """config/compensator_params.yaml, its calibration copied beside it with a rest R."""
    shutil.copy(CONFIG / "compensator_params.yaml", tmp_path)
    cal = load_calibration(CONFIG / "demo_calibration.yaml")
    cal.sensors["s1"] = cal.sensors["s1"].__class__(
        **{**cal.sensors["s1"].__dict__, "rest_resistance": 11.0})
    save_calibration(cal, tmp_path / "demo_calibration.yaml")
    h = Harness(context, tmp_path / "compensator_params.yaml")
    yield h
    h.close()


@pytest.fixture()
def array(context: Any) -> Iterator[Harness]:
    h = Harness(context, CONFIG / "array_params.yaml")
    yield h
    h.close()


def qos_of(node: Node, topic: str, publishers: bool) -> list[Any]:
    infos = (node.get_publishers_info_by_topic if publishers
             else node.get_subscriptions_info_by_topic)(topic)
    return [i for i in infos if i.node_name == "compensator"]


def test_topics_types_and_qos_of_the_bundled_configs(single: Harness, array: Harness) -> None:
    node = single.probe
    assert single.spin_until(lambda: len(qos_of(node, "/array/resistance", False)) == 1)
    expected = {("/s1/resistance", False): "std_msgs/msg/Float64",
                ("/s1/temperature", False): "sensor_msgs/msg/Temperature",
                ("/a1/temperature", False): "sensor_msgs/msg/Temperature",  # an array's too
                ("/s1/strain", True): "std_msgs/msg/Float64",
                ("/s1/direction", True): "std_msgs/msg/Int8",
                ("/array/resistance", False): "std_msgs/msg/Float64MultiArray",
                ("/array/strain", True): "std_msgs/msg/Float64MultiArray",
                ("/array/direction", True): "std_msgs/msg/Float64MultiArray",
                ("/s1/strain_stamped", True): "sensor_msgs/msg/JointState",
                ("/array/strain_stamped", True): "sensor_msgs/msg/JointState",
                ("/diagnostics", True): "diagnostic_msgs/msg/DiagnosticArray"}
    for (topic, is_pub), kind in expected.items():
        infos = qos_of(node, topic, is_pub)
        assert infos, topic
        assert {i.topic_type for i in infos} == {kind}
        reliability = {i.qos_profile.reliability for i in infos}
        assert reliability == ({ReliabilityPolicy.RELIABLE} if is_pub
                               else {ReliabilityPolicy.BEST_EFFORT}), topic
    services = dict(node.get_service_names_and_types())
    assert services["/compensator/tare"] == ["std_srvs/srv/Trigger"]
    assert services["/compensator/reload_calibration"] == ["std_srvs/srv/Trigger"]


def test_relative_names_follow_the_namespace(context: Any) -> None:
    h = Harness(context, CONFIG / "compensator_params.yaml", "-r", "__ns:=/robot1")
    try:
        assert h.spin_until(lambda: bool(qos_of(h.probe, "/robot1/s1/resistance", False)))
        assert qos_of(h.probe, "/robot1/s1/strain", True)
        assert qos_of(h.probe, "/diagnostics", True)
        assert not qos_of(h.probe, "/s1/strain", True)
    finally:
        h.close()


def test_outputs_equal_replay_in_sim_time(single: Harness, tmp_path: Path) -> None:
    """The node's strain of each input is ``strain-comp replay``'s of the same bag to 1e-9
    (the same engine path: the node's batches are the engine's batches)."""
    from strain_comp.cli import main as cli_main
    from strain_comp.io.bag import read_bag

    messages, _ = raw_messages(ROOT / "bags/demo_rates.mcap", ["/s1/resistance"])
    messages = messages[:N_BAG]
    strain = single.listen("/s1/strain", Float64)
    direction = single.listen("/s1/direction", Int8)
    stamped = single.listen("/s1/strain_stamped", JointState)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    for m in messages:
        assert single.feed(pub, m.data, strain, m.log_time_ns)
    assert single.spin_until(lambda: len(direction) == N_BAG and len(stamped) == N_BAG)
    assert cli_main(["replay", str(ROOT / "bags/demo_rates.mcap"), "--calibration",
                     str(tmp_path / "demo_calibration.yaml"),  # single's
                     "--out", str(tmp_path / "replay.mcap")]) == 0
    replayed = read_bag(tmp_path / "replay.mcap").series
    got = np.array([m.data for m in strain])
    np.testing.assert_allclose(got, replayed["/s1/strain"].values[:N_BAG], rtol=0, atol=1e-9)
    np.testing.assert_array_equal([m.data for m in direction],
                                  replayed["/s1/direction"].values[:N_BAG])
    # the stamped twin: the input's time (its /clock tick), the same strain, no rate
    assert [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in stamped] == [
        m.log_time_ns for m in messages]
    assert {(tuple(m.name), m.header.frame_id, len(m.velocity), len(m.effort))
            for m in stamped} == {(("s1",), "", 0, 0)}
    np.testing.assert_array_equal([m.position[0] for m in stamped], got)


def test_bad_messages_counted_reported_and_recovered(single: Harness) -> None:
    strain = single.listen("/s1/strain", Float64)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    for value in (15.0, 15.1):
        assert single.feed(pub, Float64(data=value), strain)
    held = strain[-1].data
    for value in (math.nan, math.inf, 0.0, -3.0):
        assert single.feed(pub, Float64(data=value), strain)
        assert strain[-1].data == held  # estimate held, node alive
    status = single.diagnostics()["strain_comp: s1"]
    assert status[0] == 2 and status[1].startswith("non-positive input")
    assert status[2]["n_nan"] == "2" and status[2]["n_non_positive"] == "2"
    assert single.feed(pub, Float64(data=math.nan), strain)
    assert single.diagnostics()["strain_comp: s1"][:2] == (2, "non-finite input: estimate held")
    assert single.feed(pub, Float64(data=15.2), strain)
    level, message, values = single.diagnostics()["strain_comp: s1"]
    assert (level, message) == (0, "ok")  # recovers with the next good sample
    assert values["n_nan"] == "3"
    single.tick(single.t_ns + 3_000_000_000)  # silence longer than stale_after_s
    assert single.diagnostics()["strain_comp: s1"][0] == 3


def test_parameters_refused_and_applied(single: Harness) -> None:
    node = single.node
    result = node.set_parameters([Parameter("sensors", Parameter.Type.STRING_ARRAY, ["x"])])[0]
    assert not result.successful and "read-only" in result.reason
    result = node.set_parameters([Parameter("deadzone_scale", Parameter.Type.DOUBLE, -5.0)])[0]
    assert not result.successful and "out of range" in result.reason
    result = node.set_parameters([Parameter("deadzone_scale", Parameter.Type.INTEGER, 500)])[0]
    assert not result.successful and "out of range" in result.reason  # as a double: 500.0
    result = node.set_parameters([Parameter("gap_reset_s", Parameter.Type.STRING, "x")])[0]
    assert not result.successful and result.reason == (
        "Wrong parameter type, expected 'Type.DOUBLE' got 'Type.STRING'")
    assert node.describe_parameter("gap_reset_s").type == Parameter.Type.DOUBLE.value
    assert node.live.engine.deadzone_scale == 1.0
    result = node.set_parameters([Parameter("deadzone_scale", Parameter.Type.DOUBLE, 2.5)])[0]
    assert result.successful and node.live.engine.deadzone_scale == 2.5
    result = node.set_parameters([Parameter("stale_after_s", Parameter.Type.INTEGER, 2)])[0]
    assert result.successful and node.live.engine.stale_after == 2.0
    # the publish-rate limit takes effect on the next message: at 1 Hz, 1 of 3 published
    strain = single.listen("/s1/strain", Float64)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    assert node.set_parameters([Parameter("publish_rate_limit_hz", value=1.0)])[0].successful
    single.feed(pub, Float64(data=15.0), strain)
    for _ in range(2):
        assert not single.feed(pub, Float64(data=15.0), strain)
    assert len(strain) == 1


def test_tare_service_and_diagnostics(single: Harness) -> None:
    strain = single.listen("/s1/strain", Float64)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    refused = single.call("/compensator/tare")
    assert not refused.success and "no good sample" in refused.message
    for value in (12.0, 12.2, 12.4, 12.2, 12.0):
        single.feed(pub, Float64(data=value), strain)
    reply = single.call("/compensator/tare")
    assert reply.success, reply.message
    values = single.diagnostics()["strain_comp: s1"][2]
    assert float(values["rest_resistance"]) == pytest.approx(12.2)
    assert float(values["input_gain"]) == pytest.approx(11.0 / 12.2)
    # effective at once: the next 12.2 ohm is read as the calibration's rest (11 ohm)
    single.feed(pub, Float64(data=12.2), strain)
    fresh = Engine(load_calibration(single.node.base_dir / "demo_calibration.yaml"))
    assert strain[-1].data != fresh.step("s1", 0.0, 12.2).strain


def reload_result(h: Harness) -> str:
    """Call ``~/reload_calibration`` (it answers at once) and wait for its result, the
    calibration status on /diagnostics."""
    reply = h.call("/compensator/reload_calibration")
    assert reply.success and reply.message.startswith("loading "), reply.message
    assert h.spin_until(lambda: h.node._loaded is not None)  # swapped in at the next tick
    return h.diagnostics()["strain_comp: calibration"][1]


@pytest.mark.parametrize("bad", [
    "format: strain_comp/calibration/v1\nsensors: {s1: {model: nope}}\n",
    "a: [unclosed\n", "<17 effect terms>"])
def test_reload_refuses_a_bad_file_in_its_answer_and_keeps_running(single: Harness,
                                                                    bad: str) -> None:
    """A file that will be refused is refused in the answer (success=false, the reason),
    also on /diagnostics; nothing is loaded; the old calibration answers on."""
    cal = single.node.base_dir / "demo_calibration.yaml"
    good = cal.read_text()
    if bad == "<17 effect terms>":  # beyond the budget per sensor
        bad = good.replace("effects: []", "effects: [" + ", ".join(
            f"{{name: o{i}, kind: offset, params: {{}}, coef: 0.0}}" for i in range(17)) + "]")
        assert bad != good
    cal.write_text(bad)
    reply = single.call("/compensator/reload_calibration")
    assert not reply.success and "old calibration keeps running" in reply.message
    assert str(cal) in reply.message, reply.message
    assert single.node._loading is None
    assert single.diagnostics()["strain_comp: calibration"][:2] == (1, reply.message)
    strain = single.listen("/s1/strain", Float64)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    assert single.feed(pub, Float64(data=15.0), strain)
    cal.write_text(good)
    assert reload_result(single).startswith("reloaded ")


def test_reload_loads_off_the_executor_and_swaps_between_messages(
        single: Harness, monkeypatch: pytest.MonkeyPatch) -> None:
    """A load held up on its worker thread: every input meanwhile is answered by the old
    calibration, a second reload is refused, then the new calibration answers from the
    next message on; the health counters go on. The truth: a LiveCompensator on each
    calibration fed the same samples (the new one from the swap on)."""
    from strain_comp.ros.live import LiveCompensator
    from strain_comp.ros.params import parse_values

    release = threading.Event()
    successor = LiveCompensator.successor

    def slow_successor(self: LiveCompensator, params: Any) -> LiveCompensator:
        release.wait(30.0)  # a large file: the load takes until the test lets it go
        return successor(self, params)

    monkeypatch.setattr(LiveCompensator, "successor", slow_successor)
    node, base = single.node, single.node.base_dir
    old_ref = LiveCompensator(parse_values(node.flat, base_dir=base))
    cal = base / "demo_calibration.yaml"
    cal.write_text(cal.read_text().replace("r0: 8.83269945355191", "r0: 9.5"))
    strain = single.listen("/s1/strain", Float64)
    pub = single.probe.create_publisher(Float64, "/s1/resistance", 10)
    single.wait_matched(pub)
    values = [12.0, 12.5, 13.5, 15.0, 17.0, 19.0, 20.0, 18.0, 16.0, 14.0]

    def expect(ref: LiveCompensator, value: float) -> float:
        out = one_message(ref, "s1", single.t_ns * 1e-9, value)
        assert out is not None
        return out.strain

    for value in values[:3]:
        assert single.feed(pub, Float64(data=value), strain)
        assert strain[-1].data == expect(old_ref, value)
    reply = single.call("/compensator/reload_calibration")
    assert reply.success and reply.message == f"loading {cal}", reply.message
    second = single.call("/compensator/reload_calibration")
    assert not second.success and "in flight" in second.message
    for value in values[3:6]:  # the load is under way: outputs go on, old calibration
        assert single.feed(pub, Float64(data=value), strain)
        assert strain[-1].data == expect(old_ref, value)
    assert node._loading is not None and node._loading.is_alive()
    release.set()
    assert single.spin_until(lambda: node._loaded is not None)  # loaded, not yet swapped
    new_ref = LiveCompensator(parse_values(node.flat, base_dir=base))
    for value in values[6:]:  # swapped: the new calibration, its state from the swap on
        assert single.feed(pub, Float64(data=value), strain)
        assert strain[-1].data == expect(new_ref, value) != expect(old_ref, value)
    status = single.diagnostics()
    assert status["strain_comp: calibration"][:2] == (0, f"reloaded {cal}")
    assert status["strain_comp: s1"][2]["n_good"] == str(len(values))


def array_msg(values: list[float], *, offset: int = 0, size: int | None = None) -> Any:
    msg = Float64MultiArray(data=values)
    msg.layout.data_offset = offset
    if size is not None:
        msg.layout.dim = [MultiArrayDimension(label="", size=size, stride=size)]
    return msg


def test_array_layout_honoured_or_refused(array: Harness) -> None:
    strain = array.listen("/array/strain", Float64MultiArray)
    stamped = array.listen("/array/strain_stamped", JointState)
    pub = array.probe.create_publisher(Float64MultiArray, "/array/resistance", 10)
    array.wait_matched(pub)
    engine = Engine(load_calibration(CONFIG / "array_calibration.yaml"),
                    arrays={"array": [f"a{i}" for i in range(1, 7)]})
    rows = [[12.0, 14.0, 13.0, 15.0, 14.5, 16.0], [12.5, 14.2, 13.1, 15.5, 14.0, 16.5]]
    expected = []
    for i, row in enumerate(rows):
        t_ns = 2_000_000_000 + i * 10_000_000
        msg = array_msg([-1.0, -1.0, *row], offset=2, size=6) if i else array_msg(row)
        assert array.feed(pub, msg, strain, t_ns)
        expected.append(engine.step_array("array", t_ns * 1e-9, row).strain)
    np.testing.assert_allclose([m.data for m in strain], expected, rtol=0, atol=1e-12)
    assert [d.size for d in strain[-1].layout.dim] == [6]
    assert array.spin_until(lambda: len(stamped) == 2)
    assert [list(m.name) for m in stamped] == [[f"a{i}" for i in range(1, 7)]] * 2
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in stamped] == [(2, 0),
                                                                               (2, 10_000_000)]
    np.testing.assert_array_equal([m.position for m in stamped], [m.data for m in strain])
    for bad in (array_msg(rows[0][:5]), array_msg(rows[0], size=5),
                array_msg(rows[0], offset=3, size=6)):
        assert not array.feed(pub, bad, strain)
    transport = array.diagnostics()["strain_comp: transport"]
    assert transport[0] == 1 and transport[2]["n_refused"] == "3"
    assert "layout dim[0].size 5 != 6 sensors" in " ".join(transport[2])
    assert array.diagnostics()["strain_comp: transport"][:2] == (0, "ok")  # recovers
    assert array.feed(pub, array_msg([math.nan, *rows[1][1:]]), strain)
    statuses = array.diagnostics()
    assert statuses["strain_comp: a1"][:2] == (2, "non-finite input: estimate held")
    assert statuses["strain_comp: a2"][0] == 0


@pytest.mark.parametrize("names", [["s1"], ["a", "bc", "def", "ghij", "k"],
                                   [f"x{i}" for i in range(256)]])
def test_output_bytes_decode_as_their_messages(names: list[str]) -> None:
    """The node's hand-built CDR of ``strain_stamped``, of an array's ``strain`` and of a
    sensor's ``strain`` and ``direction`` is what rclpy's own type support reads: names,
    stamp, values, empty velocity and effort; the layout labelled with the names."""
    from rclpy.serialization import deserialize_message

    from strain_comp.io.cdr import RowEncoder

    values = np.random.default_rng(len(names)).normal(size=len(names))
    stamps = [1_795_498_137_622_557_762, 0, 5]
    stamped = RowEncoder.joint_state(names).encode(np.tile(values, (3, 1)), np.array(stamps))
    for stamp_ns, message in zip(stamps, stamped, strict=True):
        msg = deserialize_message(message, JointState)
        assert list(msg.name) == names and msg.header.frame_id == ""
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamp_ns
        np.testing.assert_array_equal(msg.position, values)
        assert list(msg.velocity) == [] and list(msg.effort) == []
    vector = deserialize_message(RowEncoder.vector(names).encode(values[None])[0],
                                 Float64MultiArray)
    np.testing.assert_array_equal(vector.data, values)
    assert [(d.label, d.size, d.stride) for d in vector.layout.dim] == [
        (",".join(names), len(names), len(names))]
    assert vector.layout.data_offset == 0
    assert [deserialize_message(b, Float64).data
            for b in RowEncoder.scalar("<f8").encode(values)] == list(values)
    directions = np.array([-1, 0, 1])
    assert [deserialize_message(b, Int8).data
            for b in RowEncoder.scalar("i1").encode(directions)] == [-1, 0, 1]
