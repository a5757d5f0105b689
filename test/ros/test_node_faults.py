"""A fault of the program inside the node, under the real rclpy in one process: reported as
a program error (logged with its traceback, counted apart on /diagnostics, a service's
answer saying so), never as a refused message, and the node goes on with the next message.

The truth for "goes on": the outputs equal a fresh ``LiveCompensator``'s on the same samples
with the faulty one left out."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import NodeUnderTest, one_message
from ros_env import use_ros_env

ROS_SLOT = 17
use_ros_env(ROS_SLOT)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402  (after the environment is set)
from std_msgs.msg import Float64  # noqa: E402

from strain_comp.ros.compensator import CompensatorNode  # noqa: E402
from strain_comp.ros.live import LiveCompensator  # noqa: E402
from strain_comp.ros.params import parse_values  # noqa: E402

CONFIG = Path(__file__).resolve().parents[2] / "config"


class Rig(NodeUnderTest):
    """The node (config/compensator_params.yaml, system time), a probe node, an executor."""

    def __init__(self, ctx: Any) -> None:
        super().__init__(ctx, CONFIG, ["--ros-args", "--params-file",
                                       str(CONFIG / "compensator_params.yaml"),
                                       "-p", "diagnostics_period_s:=0.05"])
        self.node: CompensatorNode
        self.strain: list[Any] = []
        self.diags: list[Any] = []
        self.probe.create_subscription(Float64, "/s1/strain", self.strain.append, 100)
        self.probe.create_subscription(DiagnosticArray, "/diagnostics", self.diags.append, 100)
        self.pub = self.wait_matched(self.probe.create_publisher(Float64, "/s1/resistance", 10))

    def send(self, value: float) -> None:
        """Publish one good resistance and spin until its strain came back."""
        n = len(self.strain)
        self.pub.publish(Float64(data=value))
        assert self.spin_until(lambda: len(self.strain) > n)

    def status(self, name: str) -> tuple[int, str, dict[str, str]]:
        """``name``'s status in a /diagnostics message published from now on."""
        n = len(self.diags)
        assert self.spin_until(lambda: len(self.diags) > n + 1)
        found = {s.name: (s.level[0], s.message, {kv.key: kv.value for kv in s.values})
                 for s in self.diags[-1].status}
        return found[name]


@pytest.fixture()
def rig(context: Any) -> Iterator[Rig]:
    r = Rig(context)
    yield r
    r.close()


def test_a_program_error_in_a_callback_is_reported_as_such_and_the_node_goes_on(
        rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    real = rig.node.live.on_input
    calls: list[tuple[float, float]] = []

    def faulty(name: str, t: np.ndarray, values: np.ndarray) -> Any:
        calls.extend(zip(t.tolist(), values[:, 0].tolist(), strict=True))
        if 13.0 in values:
            raise TypeError("unsupported operand type(s) for +: 'float' and 'NoneType'")
        return real(name, t, values)

    monkeypatch.setattr(rig.node.live, "on_input", faulty)
    logged: list[str] = []
    logger = rig.node.get_logger()
    monkeypatch.setattr(type(logger), "error",
                        lambda self, message, **kw: logged.append(message) or True)
    rig.send(12.0)
    rig.pub.publish(Float64(data=13.0))
    assert rig.spin_until(lambda: sum(rig.node.live.faults.values()) == 1)
    rig.send(14.0)  # alive: 14 ohm answered
    assert [v for _, v in calls] == [12.0, 13.0, 14.0]

    truth = LiveCompensator(parse_values(rig.node.flat, base_dir=CONFIG))
    expected = [one_message(truth, "s1", t, v) for t, v in calls if v != 13.0]  # 13 left out
    assert [m.data for m in rig.strain] == [o.strain for o in expected if o is not None]
    assert rig.node.live.faults == {"s1: TypeError": 1}
    assert sum(rig.node.live.refused.values()) == 0  # not a refused message
    assert any("s1: program error (a bug, not the message): TypeError" in line
               and "Traceback (most recent call last)" in line for line in logged)
    level, _, values = rig.status("strain_comp: program errors")
    assert (level, values["n_errors"]) in ((2, "1"), (0, "1"))  # ERROR in the first after
    assert values["error[s1: TypeError]"] == "1"
    transport = rig.status("strain_comp: transport")
    assert transport[2]["n_refused"] == "0"
    assert rig.status("strain_comp: program errors")[:2] == (0, "ok")  # until the next one


def test_a_program_error_in_a_service_answers_so_and_is_counted(
        rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken() -> str:
        raise KeyError("s1")

    monkeypatch.setattr(rig.node.live.taring, "tare", broken)
    reply = rig.call("/compensator/tare")
    assert not reply.success
    assert reply.message.startswith("internal error: KeyError: 's1' (a bug")
    assert rig.node.live.faults == {"~/tare: KeyError": 1}
    monkeypatch.undo()
    reply = rig.call("/compensator/tare")  # the real one: refused for what it has
    assert not reply.success and reply.message.startswith("tare: refused: s1: ")
    assert rig.node.live.faults == {"~/tare: KeyError": 1}
