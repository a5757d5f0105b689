"""``~/start`` and the standard deviation through the real rclpy node: the service answers
twice, while watching and without a reference, never ending the node; its state is on
/diagnostics; ``NAME/strain_std`` carries the estimate's standard deviation."""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from conftest import NodeUnderTest
from ros_env import use_ros_env

ROS_SLOT = 19
use_ros_env(ROS_SLOT)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402  (after the environment is set)
from std_msgs.msg import Float64  # noqa: E402

from strain_comp.core.calibration_file import load_calibration, save_calibration  # noqa: E402
from strain_comp.core.engine import Engine  # noqa: E402
from strain_comp.core.uncertainty import Uncertainty  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"
BAND = Uncertainty.from_weights({"bias": -2.0, "level": 1.0})


class Harness(NodeUnderTest):
    """The node (wall clock) on the demo calibration with an uncertainty."""

    def __init__(self, ctx: Any, params_file: Path) -> None:
        super().__init__(ctx, params_file.parent, [
            "--ros-args", "--params-file", str(params_file), "-p",
            "diagnostics_period_s:=0.05"])
        self.diag: list[Any] = []
        self.probe.create_subscription(DiagnosticArray, "/diagnostics", self.diag.append, 10)

    def start_state(self, done: Callable[[str], bool]) -> str:
        """The message of ``strain_comp: session start`` once ``done`` holds for it."""
        found = [""]

        def check() -> bool:
            for msg in self.diag[-3:]:
                for s in msg.status:
                    if s.name == "strain_comp: session start":
                        found[0] = s.message
                        if done(s.message):
                            return True
            return False

        assert self.spin_until(check), found[0]
        return found[0]


@pytest.fixture()
def node(context: Any, tmp_path: Path) -> Iterator[Harness]:
    shutil.copy(CONFIG / "compensator_params.yaml", tmp_path)
    cal = load_calibration(CONFIG / "demo_calibration.yaml")
    cal.sensors["s1"] = replace(cal.sensors["s1"], rest_resistance=11.0, uncertainty=BAND)
    save_calibration(cal, tmp_path / "demo_calibration.yaml")
    h = Harness(context, tmp_path / "compensator_params.yaml")
    yield h
    h.close()


def test_start_answers_always_and_the_node_goes_on(node: Harness, tmp_path: Path) -> None:
    strain: list[Any] = []
    std: list[Any] = []
    node.probe.create_subscription(Float64, "/s1/strain", strain.append, 100)
    node.probe.create_subscription(Float64, "/s1/strain_std", std.append, 100)
    resistance = node.wait_matched(node.probe.create_publisher(Float64, "/s1/resistance", 10))
    reference = node.wait_matched(node.probe.create_publisher(Float64,
                                                              "/s1/strain_reference", 10))
    assert node.start_state(lambda m: m.startswith("idle"))
    for _ in range(2):  # no reference, span_strain 0: refused twice, the node goes on
        answer = node.call("/compensator/start")
        assert not answer.success and "span_strain" in answer.message
    assert "span_strain" in node.start_state(lambda m: m.startswith("refused"))
    resistance.publish(Float64(data=12.0))
    assert node.spin_until(lambda: len(std) > 0 and len(strain) > 0)
    cal = load_calibration(tmp_path / "demo_calibration.yaml")
    engine = Engine(cal)
    expected = engine.step("s1", 0.0, 12.0)
    assert strain[-1].data == pytest.approx(expected.strain)
    assert std[-1].data == pytest.approx(expected.std) and math.isfinite(std[-1].data)
    reference.publish(Float64(data=0.0))  # a reference now: ~/start watches
    assert node.spin_until(lambda: node.node.live.starting._last_reference.get("s1")
                           is not None)
    answer = node.call("/compensator/start")
    assert answer.success and "waiting" in answer.message
    answer = node.call("/compensator/start")  # twice: refused, the watch goes on
    assert not answer.success and "already waiting" in answer.message
    assert node.start_state(lambda m: m.startswith("waiting"))
    n = len(strain)
    resistance.publish(Float64(data=12.5))
    assert node.spin_until(lambda: len(strain) > n)
