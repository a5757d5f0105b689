"""Known strains through the real rclpy node: ``NAME/strain_reference`` and
``ARRAY/strain_reference`` subscribed with ``fuse_references: true``, the ``~/reference``
service at ``known_strain``, the fusion state on /diagnostics, refusals counted."""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import NodeUnderTest
from ros_env import use_ros_env

ROS_SLOT = 13
use_ros_env(ROS_SLOT)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402  (after the environment is set)
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension  # noqa: E402

from strain_comp.core.calibration_file import load_calibration  # noqa: E402
from strain_comp.core.engine import Engine  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"


class Harness(NodeUnderTest):
    """The node (wall clock) with ``fuse_references: true``, a probe node, one executor."""

    def __init__(self, ctx: Any, params_file: Path, fuse: str = "true") -> None:
        super().__init__(ctx, params_file.parent, [
            "--ros-args", "--params-file", str(params_file), "-p",
            "diagnostics_period_s:=0.05", "-p", f"fuse_references:={fuse}"])
        self.diag: list[Any] = []
        self.probe.create_subscription(DiagnosticArray, "/diagnostics", self.diag.append, 10)

    def publisher(self, kind: Any, topic: str) -> Any:
        return self.wait_matched(self.probe.create_publisher(kind, topic, 10))

    def status(self, name: str, done: Callable[[dict[str, str]], bool]) -> dict[str, str]:
        """The key-values of ``name`` in the first /diagnostics for which ``done`` holds."""
        found: dict[str, str] = {}

        def check() -> bool:
            for msg in self.diag[-3:]:
                for s in msg.status:
                    if s.name == name:
                        found.clear()
                        found.update({kv.key: kv.value for kv in s.values})
                        if done(found):
                            return True
            return False

        assert self.spin_until(check), found
        return found


@pytest.fixture()
def single(context: Any, tmp_path: Path) -> Iterator[Harness]:
    shutil.copy(CONFIG / "compensator_params.yaml", tmp_path)
    shutil.copy(CONFIG / "demo_calibration.yaml", tmp_path)
    h = Harness(context, tmp_path / "compensator_params.yaml")
    yield h
    h.close()


def test_reference_topic_and_service_update_the_output_and_diagnostics(
        single: Harness) -> None:
    assert any(t == "/s1/strain_reference" and "std_msgs/msg/Float64" in k for t, k in
               single.node.get_subscriber_names_and_types_by_node("compensator", "/"))
    strain: list[Any] = []
    single.probe.create_subscription(Float64, "/s1/strain", strain.append, 100)
    resistance = single.publisher(Float64, "/s1/resistance")
    reference = single.publisher(Float64, "/s1/strain_reference")
    engine = Engine(load_calibration(CONFIG / "demo_calibration.yaml"))
    raw = engine.step("s1", 0.0, 13.0).strain  # a memoryless first sample: the node's too
    resistance.publish(Float64(data=13.0))
    assert single.spin_until(lambda: len(strain) == 1)
    assert strain[0].data == pytest.approx(raw, abs=1e-9)
    reference.publish(Float64(data=raw + 2.0))  # the sensor reads 2 % low here
    values = single.status("strain_comp: s1", lambda v: v.get("fusion_n_used") == "1")
    assert float(values["fusion_offset"]) > 0.0 and values["fusion_n_refused"] == "0"
    resistance.publish(Float64(data=13.0))
    assert single.spin_until(lambda: len(strain) == 2)
    assert strain[1].data > raw + 0.2  # later outputs follow the known strain
    for bad in (math.nan, 1e9):  # non-finite; far beyond the gate
        reference.publish(Float64(data=bad))
    values = single.status("strain_comp: s1", lambda v: v.get("fusion_n_refused") == "2")
    assert values["fusion_refused[non-finite reference]"] == "1"
    assert values["fusion_refused[beyond the gate]"] == "1"
    single.node.set_parameters([Parameter("known_strain", Parameter.Type.DOUBLE,
                                          strain[1].data + 1.0)])
    answer = single.call("/compensator/reference")
    assert answer.success and answer.message.startswith("known strain")
    single.status("strain_comp: s1", lambda v: v.get("fusion_n_used") == "2")


def test_without_fusion_a_reference_is_not_fused_and_the_service_refuses(
        context: Any, tmp_path: Path) -> None:
    """The reference topic is read (the stretch ``~/start`` watches), never fused."""
    shutil.copy(CONFIG / "compensator_params.yaml", tmp_path)
    shutil.copy(CONFIG / "demo_calibration.yaml", tmp_path)
    h = Harness(context, tmp_path / "compensator_params.yaml", fuse="false")
    try:
        reference = h.publisher(Float64, "/s1/strain_reference")
        reference.publish(Float64(data=5.0))
        assert h.spin_until(lambda: "s1" in h.node.live.starting._last_reference)
        assert not h.node.live.fusion
        answer = h.call("/compensator/reference")
        assert not answer.success and "fuse_references" in answer.message
    finally:
        h.close()


def test_array_reference_nan_for_none_and_a_bad_layout_counted(context: Any) -> None:
    h = Harness(context, CONFIG / "array_params.yaml")
    try:
        strain: list[Any] = []
        h.probe.create_subscription(Float64MultiArray, "/array/strain", strain.append, 100)
        resistance = h.publisher(Float64MultiArray, "/array/resistance")
        reference = h.publisher(Float64MultiArray, "/array/strain_reference")
        resistance.publish(Float64MultiArray(data=[12.0, 14.0, 13.0, 15.0, 14.5, 16.0]))
        assert h.spin_until(lambda: len(strain) == 1)
        known = [math.nan] * 6
        known[1] = strain[0].data[1] + 1.0
        reference.publish(Float64MultiArray(data=known))
        h.status("strain_comp: a2", lambda v: v.get("fusion_n_used") == "1")
        values = h.status("strain_comp: a1", lambda v: "fusion_n_used" in v)
        assert values["fusion_n_used"] == "0" and values["fusion_n_refused"] == "0"
        bad = Float64MultiArray(data=[1.0] * 6)
        bad.layout.dim = [MultiArrayDimension(label="a1,a2,a3,a4,a5,zz", size=6, stride=6)]
        reference.publish(bad)  # a sensor the calibration lacks: the message is refused
        transport = h.status("strain_comp: transport", lambda v: v.get("n_refused") == "1")
        assert any("array/strain_reference" in k for k in transport)
    finally:
        h.close()
