"""Wiring of the rclpy node against a recording fake of rclpy: this is NOT a ROS 2 run.

rclpy cannot be installed on this machine. The test puts minimal fake modules (rclpy,
rcl_interfaces, std_msgs, sensor_msgs, diagnostic_msgs) into ``sys.modules``; they only
record what the node asks for. Checked: topic names, message types, QoS profile,
parameter declarations with read-only flags and ranges, the on-set validation, and that a
Float64 fed to the subscription callback publishes what ``Engine.step`` gives. Not checked:
that real rclpy accepts these calls, real message classes and serialisation, parameter
overrides parsed by rcl from a params file, executors, timers and ``use_sim_time``.
"""

from __future__ import annotations

import enum
import math
import sys
import types
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from conftest import cubic_cal

from strain_comp.core.calibration import Calibration, save_calibration
from strain_comp.core.engine import Engine
from strain_comp.ros.params import TUNABLES

SENSOR_DATA = object()  # stands for rclpy.qos.qos_profile_sensor_data


def message(type_name: str, /, **defaults: Any) -> type:
    def __init__(self: Any, **values: Any) -> None:
        for key, value in defaults.items():
            setattr(self, key, value() if callable(value) else value)
        for key, value in values.items():
            setattr(self, key, value)
    return type(type_name, (), {"__init__": __init__})


class FakePublisher:
    def __init__(self, kind: type, topic: str, qos: Any) -> None:
        self.kind, self.topic, self.qos, self.sent = kind, topic, qos, []

    def publish(self, msg: Any) -> None:
        assert isinstance(msg, self.kind)
        self.sent.append(msg)


class FakeClock:
    t = 0.0

    def now(self) -> Any:
        ns = round(FakeClock.t * 1e9)
        return types.SimpleNamespace(nanoseconds=ns, to_msg=lambda: ("stamp", ns))


class FakeNode:
    overrides: ClassVar[dict[str, Any]] = {}

    def __init__(self, name: str, **options: Any) -> None:
        self.name = name
        self.declared: dict[str, Any] = {}
        self.subscriptions: list[tuple[type, str, Any, Any]] = []
        self.publishers: list[FakePublisher] = []
        self.timers: list[tuple[float, Any]] = []
        self.on_set: list[Any] = []
        self.warnings: list[str] = []

    def declare_parameter(self, name: str, value: Any, descriptor: Any) -> Any:
        assert name not in self.declared
        self.declared[name] = descriptor
        default = None if isinstance(value, FakeParameter.Type) else value
        return types.SimpleNamespace(value=self.overrides.get(name, default))

    def create_subscription(self, kind: type, topic: str, callback: Any, qos: Any) -> None:
        self.subscriptions.append((kind, topic, callback, qos))

    def create_publisher(self, kind: type, topic: str, qos: Any) -> FakePublisher:
        self.publishers.append(FakePublisher(kind, topic, qos))
        return self.publishers[-1]

    def create_timer(self, period: float, callback: Any) -> None:
        self.timers.append((period, callback))

    def add_on_set_parameters_callback(self, callback: Any) -> None:
        self.on_set.append(callback)

    def get_clock(self) -> FakeClock:
        return FakeClock()

    def get_logger(self) -> Any:
        return types.SimpleNamespace(
            warning=lambda text, throttle_duration_sec=None: self.warnings.append(text))

    def destroy_node(self) -> None:
        pass


class FakeParameter:
    class Type(enum.Enum):
        STRING = 4
        STRING_ARRAY = 9


@pytest.fixture
def fake_ros(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    std = {"Float64": message("Float64", data=0.0), "Int8": message("Int8", data=0),
           "MultiArrayDimension": message("MultiArrayDimension", label="", size=0, stride=0)}
    std["MultiArrayLayout"] = message("MultiArrayLayout", dim=list, data_offset=0)
    std["Float64MultiArray"] = message("Float64MultiArray", layout=std["MultiArrayLayout"],
                                       data=list)
    diag = {"DiagnosticArray": message("DiagnosticArray", status=list,
                                       header=lambda: types.SimpleNamespace(stamp=None)),
            "DiagnosticStatus": message("DiagnosticStatus", level=b"\0", name="", message="",
                                        hardware_id="", values=list),
            "KeyValue": message("KeyValue", key="", value="")}
    rcl = {"ParameterDescriptor": message("ParameterDescriptor", floating_point_range=list),
           "FloatingPointRange": message("FloatingPointRange"),
           "SetParametersResult": message("SetParametersResult", reason=""),
           "ParameterType": types.SimpleNamespace(PARAMETER_DOUBLE=3, PARAMETER_STRING=4,
                                                  PARAMETER_STRING_ARRAY=9)}
    spun: list[Any] = []

    def spin(node: Any) -> None:
        spun.append(node)
        raise KeyboardInterrupt

    modules = {
        "rclpy": {"init": lambda args=None: None, "spin": spin, "try_shutdown": lambda: None},
        "rclpy.node": {"Node": FakeNode},
        "rclpy.parameter": {"Parameter": FakeParameter},
        "rclpy.qos": {"qos_profile_sensor_data": SENSOR_DATA},
        "rclpy.executors": {"ExternalShutdownException": type("ESE", (Exception,), {})},
        "rcl_interfaces": {}, "rcl_interfaces.msg": rcl,
        "std_msgs": {}, "std_msgs.msg": std,
        "sensor_msgs": {}, "sensor_msgs.msg": {"Temperature": message("Temperature",
                                                                      temperature=0.0)},
        "diagnostic_msgs": {}, "diagnostic_msgs.msg": diag,
    }
    for name, attrs in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    return {**std, **diag, "spun": spun}


def configure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Calibration:
    cal = Calibration({n: cubic_cal(n) for n in ("s1", "a", "b")})
    save_calibration(cal, tmp_path / "cal.yaml")
    monkeypatch.setattr(FakeNode, "overrides", {
        "sensors": ["s1"], "s1.calibration": str(tmp_path / "cal.yaml"),
        "arrays": ["arr"], "arr.sensors": ["a", "b"], "arr.calibration": str(tmp_path / "cal.yaml"),
        "arr.topic": "/hand/ohm"})
    return cal


def test_node_wiring(fake_ros: dict[str, Any], tmp_path: Path,
                     monkeypatch: pytest.MonkeyPatch) -> None:
    cal = configure(tmp_path, monkeypatch)
    from strain_comp.ros.node import create_node

    node = create_node()
    subs = {topic: (kind.__name__, qos) for kind, topic, _, qos in node.subscriptions}
    assert subs == {"/s1/resistance": ("Float64", SENSOR_DATA),
                    "/hand/ohm": ("Float64MultiArray", SENSOR_DATA),
                    **{f"/{n}/temperature": ("Temperature", SENSOR_DATA) for n in ("s1", "a", "b")}}
    pubs = {p.topic: p.kind.__name__ for p in node.publishers}
    assert pubs == {"/s1/strain": "Float64", "/s1/direction": "Int8",
                    "/arr/strain": "Float64MultiArray", "/arr/direction": "Float64MultiArray",
                    "/diagnostics": "DiagnosticArray"}
    declared = node.declared
    structural = ["sensors", "arrays", "s1.topic", "s1.calibration", "arr.topic", "arr.sensors",
                  "arr.calibration"]
    assert list(declared) == structural + [s.name for s in TUNABLES]
    assert all(declared[name].read_only for name in structural)
    for spec in TUNABLES:
        d = declared[spec.name]
        assert d.read_only == spec.read_only and d.description == spec.description
        assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == \
            spec.range
    assert node.timers[0][0] == 1.0 and len(node.on_set) == 1

    # a Float64 through the callback publishes what Engine.step gives
    on_s1 = next(cb for _, topic, cb, _ in node.subscriptions if topic == "/s1/resistance")
    engine = Engine(Calibration({"s1": cal.sensors["s1"]}))
    strain_pub, direction_pub = node.publishers[0], node.publishers[1]
    for k, r in enumerate([150.0, 152.0, math.nan, 155.0, 160.0, -2.0, 158.0]):
        FakeClock.t = 10.0 + 0.01 * k
        on_s1(fake_ros["Float64"](data=r))
        expected = engine.step("s1", FakeClock.t, r)
        assert strain_pub.sent[-1].data == pytest.approx(expected.strain, nan_ok=True)
        assert direction_pub.sent[-1].data == expected.direction
    on_arr = next(cb for _, topic, cb, _ in node.subscriptions if topic == "/hand/ohm")
    on_arr(fake_ros["Float64MultiArray"](data=[150.0, 170.0]))
    sent = node.publishers[2].sent[-1]
    assert sent.layout.dim[0].label == "a,b" and len(sent.data) == 2

    # a malformed message is counted and logged, never raised
    on_s1(object())
    on_arr(fake_ros["Float64MultiArray"](data=[1.0, 2.0, 3.0]))
    assert node.live.n_errors == 2 and len(node.warnings) == 2

    # tunables are validated as a batch; diagnostics carry each sensor
    result = node.on_set[0]([types.SimpleNamespace(name="deadzone_scale", value=0.0)])
    assert not result.successful and "deadzone_scale" in result.reason
    result = node.on_set[0]([types.SimpleNamespace(name="deadzone_scale", value=2.0),
                             types.SimpleNamespace(name="use_sim_time", value=True)])
    assert result.successful and node.live.engine.deadzone_scale == 2.0
    node.timers[0][1]()
    diag = node.publishers[-1].sent[-1]
    names = [s.name for s in diag.status]
    assert names[:3] == ["strain_comp: s1", "strain_comp: a", "strain_comp: b"]
    assert all(isinstance(s.level, bytes) for s in diag.status)
    assert np.isfinite(node.live.engine.health()["s1"].last_good_t)


def test_main_exit_codes(fake_ros: dict[str, Any], tmp_path: Path,
                         monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    from strain_comp.ros.node import main

    monkeypatch.setattr(FakeNode, "overrides", {})
    assert main([]) == 2
    assert "nothing to compensate" in capsys.readouterr().err
    configure(tmp_path, monkeypatch)
    assert main([]) == 0 and len(fake_ros["spun"]) == 1
