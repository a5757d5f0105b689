"""The node against hostile peers, under the real rclpy in one process: a negative /clock, a
peer switching ``use_sim_time`` through ``set_parameters``, arrays whose ``dim[0].label``
orders or names the sensors differently, and a flood of distinct refusal reasons."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import NodeUnderTest
from ros_env import ros_env, use_ros_env

ROS_SLOT = 7
use_ros_env(ROS_SLOT)

from rclpy.parameter import Parameter  # noqa: E402  (after the environment is set)
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray, MultiArrayDimension  # noqa: E402

from strain_comp.core.calibration_file import load_calibration  # noqa: E402
from strain_comp.core.engine import Engine  # noqa: E402
from strain_comp.ros.live import MAX_REFUSAL_KEYS  # noqa: E402

CONFIG = Path(__file__).resolve().parents[2] / "config"
SENSORS = [f"a{i}" for i in range(1, 7)]


class Peer(NodeUnderTest):
    """The node (array config) and a hostile peer node on one executor."""

    def __init__(self, ctx: Any, sim_time: bool) -> None:
        super().__init__(ctx, CONFIG, ["--ros-args", "--params-file",
                                       str(CONFIG / "array_params.yaml"),
                                       "-p", f"use_sim_time:={str(sim_time).lower()}"],
                         probe_name="peer")
        self.clock = self.probe.create_publisher(Clock, "/clock", 10)

    def tick(self, sec: int, nanosec: int = 0) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = sec, nanosec
        self.clock.publish(msg)


@pytest.fixture()
def sim(context: Any) -> Iterator[Peer]:
    p = Peer(context, True)
    yield p
    p.close()


def test_a_negative_clock_is_refused_and_counted_not_fatal(sim: Peer) -> None:
    sim.wait_matched(sim.clock)
    sim.tick(5)
    assert sim.spin_until(lambda: sim.node.get_clock().now().nanoseconds == 5 * 10**9)
    for n in range(1, 4):  # rclpy's own clock callback raises ValueError here
        sim.tick(-1, 5)
        assert sim.spin_until(lambda n=n: sim.node.live.refused["/clock: negative time"] == n)
    assert sim.node.get_clock().now().nanoseconds == 5 * 10**9  # kept its time
    sim.tick(6)
    assert sim.spin_until(lambda: sim.node.get_clock().now().nanoseconds == 6 * 10**9)


@pytest.mark.parametrize("sim_time", [False, True])
def test_a_peer_cannot_switch_use_sim_time(context: Any, sim_time: bool) -> None:
    """Through the standard set_parameters service, from another node."""
    p = Peer(context, sim_time)
    try:
        client = AsyncParameterClient(p.probe, "compensator")
        assert p.spin_until(client.services_are_ready)
        future = client.set_parameters([Parameter("use_sim_time", value=not sim_time)])
        assert p.spin_until(future.done)
        result = future.result().results[0]
        assert not result.successful and "fixed at start" in result.reason
        assert p.node.get_parameter("use_sim_time").value is sim_time
        assert p.node.get_clock().ros_time_is_active is sim_time
        same = client.set_parameters([Parameter("use_sim_time", value=sim_time)])
        assert p.spin_until(same.done) and same.result().results[0].successful
    finally:
        p.close()


def _array(values: list[float], label: str) -> Float64MultiArray:
    msg = Float64MultiArray()
    msg.data = [float(v) for v in values]
    msg.layout.dim = [MultiArrayDimension(label=label, size=len(values), stride=len(values))]
    return msg


def test_array_values_are_matched_by_label_and_refused_when_labels_differ(sim: Peer) -> None:
    """The same sample sent in the calibration's order and in reverse order with reversed
    labels gives the same strains (the engine's, sensor by sensor); labels naming another
    sensor are refused and counted."""
    strain: list[Any] = []
    sim.probe.create_subscription(Float64MultiArray, "/array/strain", strain.append, 10)
    pub = sim.probe.create_publisher(Float64MultiArray, "/array/resistance", 10)
    sim.wait_matched(pub)
    engine = Engine(load_calibration(CONFIG / "array_calibration.yaml"),
                    arrays={"array": SENSORS})
    rows = [[12.0, 14.0, 13.0, 15.0, 14.5, 16.0], [12.5, 14.2, 13.1, 15.5, 14.0, 16.5]]
    expected = []
    for i, (row, reverse) in enumerate(zip(rows, (False, True), strict=True)):
        t = 2 * 10**9 + i * 10**7
        sim.tick(*divmod(t, 10**9))
        assert sim.spin_until(lambda t=t: sim.node.get_clock().now().nanoseconds == t)
        msg = (_array(row[::-1], ",".join(SENSORS[::-1])) if reverse
               else _array(row, ",".join(SENSORS)))
        pub.publish(msg)
        assert sim.spin_until(lambda n=i + 1: len(strain) == n)
        expected.append(engine.step_array("array", t * 1e-9, row).strain)
    np.testing.assert_allclose([m.data for m in strain], expected, rtol=0, atol=1e-12)
    sim.tick(2, 30_000_000)
    pub.publish(_array(rows[0], ",".join(["a1", "a2", "a3", "a4", "a5", "x6"])))
    key = "array: layout dim[0].label does not name the sensors a1,a2,a3,a4,a5,a6"
    assert sim.spin_until(lambda: sim.node.live.refused[key] == 1)
    assert len(strain) == 2


def test_on_the_system_clock_messages_are_read_in_bulk_as_one_by_one(context: Any) -> None:
    """The intake reads a run of one layout in bulk from the bytes: interleaved layouts
    (plain, labelled in reverse order, a data_offset, a refused label, plain again) each
    give the engine's strains of the sample in sensor order, at the stamp published."""
    p = Peer(context, False)
    try:
        stamped: list[Any] = []
        p.probe.create_subscription(JointState, "/array/strain_stamped", stamped.append, 100)
        pub = p.probe.create_publisher(Float64MultiArray, "/array/resistance", 100)
        p.wait_matched(pub)
        rng = np.random.default_rng(3)
        rows = [list(12.0 + 4.0 * rng.random(6)) for _ in range(12)]
        offset = _array([99.0, *rows[5]], ",".join(SENSORS))
        offset.layout.data_offset = 1
        offset.layout.dim[0].size = offset.layout.dim[0].stride = 6
        messages = [*(_array(r, "") for r in rows[:3]),
                    _array(rows[3][::-1], ",".join(SENSORS[::-1])),
                    _array(rows[4][::-1], ",".join(SENSORS[::-1])), offset,
                    _array(rows[0], "a1,a2,a3,a4,a5,x6"),
                    *(_array(r, ",".join(SENSORS)) for r in rows[6:])]
        for msg in messages:
            pub.publish(msg)
        assert p.spin_until(lambda: len(stamped) == len(rows))
        key = "array: layout dim[0].label does not name the sensors a1,a2,a3,a4,a5,a6"
        assert p.node.live.refused[key] == 1
    finally:
        p.close()
    engine = Engine(load_calibration(CONFIG / "array_calibration.yaml"),
                    arrays={"array": SENSORS})
    for msg, row in zip(stamped, rows, strict=True):
        t = (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) * 1e-9  # as the node
        np.testing.assert_allclose(msg.position, engine.step_array("array", t, row).strain,
                                   rtol=0, atol=1e-12)


def test_refusal_counters_stay_bounded(sim: Peer) -> None:
    """Arrays of 200 different wrong sizes: MAX_REFUSAL_KEYS reasons plus one "other
    reasons" counter, every refusal counted."""
    for size in range(7, 207):
        sim.node.live.refuse("array", f"expected 6 values, got {size}")
    refused = sim.node.live.refused
    assert len(refused) == MAX_REFUSAL_KEYS + 1 and sum(refused.values()) == 200
    assert refused["array: other reasons"] == 200 - MAX_REFUSAL_KEYS


@pytest.mark.parametrize(("entry", "field"), [
    ("sensors: [finger-1]\n    finger-1: {calibration: CAL}", "sensors"),
    ("sensors: [s1]\n    s1: {topic: s1/re sistance, calibration: CAL}", "s1.topic"),
    ("sensors: [s1]\n    s1: {topic: 1s/resistance, calibration: CAL}", "s1.topic"),
    ("arrays: [hand]\n    hand: {sensors: [a1, 'a,2'], calibration: CAL}", "hand.sensors"),
])
def test_an_invalid_ros_name_in_the_params_file_is_one_line(tmp_path: Path, entry: str,
                                                            field: str) -> None:
    """``finger-1`` and friends: ``compensator`` exits 2 with one line naming the field and
    the rule, never a traceback from rclpy."""
    params = tmp_path / "params.yaml"
    params.write_text("compensator:\n  ros__parameters:\n    "
                      + entry.replace("CAL", str(CONFIG / "demo_calibration.yaml")) + "\n")
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from strain_comp.ros.node import main; "
         "sys.exit(main(sys.argv))", "--ros-args", "--params-file", str(params)],
        capture_output=True, text=True, timeout=60, env={**os.environ, **ros_env(7)})
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert field in lines[0] and "not a valid ROS" in lines[0], lines[0]
