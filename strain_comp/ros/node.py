"""The rclpy node (thin): ROS topics and parameters around a ``LiveCompensator``.

``ros2 run strain_comp compensator --ros-args --params-file config/compensator_params.yaml``.
Parameters as in ``strain_comp.ros.params`` (structural ones read-only, tunables ranged and
validated on change); inputs with sensor-data QoS; message time from the node clock, so
``use_sim_time`` works with ``ros2 bag play --clock``. rclpy is imported only here, lazily.
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

from strain_comp.errors import ParameterError, StrainCompError
from strain_comp.ros.params import TUNABLE, TUNABLES, ParamSpec, parse_values, structural_specs

# what handling one message can raise: the engine's input errors, and a message of the
# wrong shape or type (no ``data`` field, values that do not convert to float, a wrong
# array length)
_MESSAGE_ERRORS = (StrainCompError, ArithmeticError, ValueError, TypeError, LookupError,
                   AttributeError)


def _descriptor(spec: ParamSpec) -> Any:
    from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType

    kinds = {"double": ParameterType.PARAMETER_DOUBLE, "string": ParameterType.PARAMETER_STRING,
             "string_array": ParameterType.PARAMETER_STRING_ARRAY}
    descriptor = ParameterDescriptor(name=spec.name, type=kinds[spec.type],
                                     description=spec.description, read_only=spec.read_only)
    if spec.range is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(spec.range[0]), to_value=float(spec.range[1]), step=0.0)]
    return descriptor


def create_node(node_name: str = "compensator", **node_options: Any) -> Any:
    """Build the node (rclpy must be initialised); StrainCompError on bad parameters."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Temperature
    from std_msgs.msg import Float64, Float64MultiArray, Int8, MultiArrayDimension

    from strain_comp.ros.live import LiveCompensator

    class CompensatorNode(Node):
        def __init__(self) -> None:
            super().__init__(node_name, **node_options)
            flat = self._declare(structural_specs([], []))
            specs = structural_specs(flat.get("sensors", []), flat.get("arrays", []))
            flat.update(self._declare(specs[2:] + list(TUNABLES)))
            self.live = LiveCompensator(parse_values(flat))  # warms the kernels up
            for inp in self.live.params.inputs:
                if inp.is_array:
                    k = len(inp.sensors)
                    dim = MultiArrayDimension(label=",".join(inp.sensors), size=k, stride=k)
                    pubs = [self.create_publisher(Float64MultiArray, f"/{inp.name}/{what}", 10)
                            for what in ("strain", "direction")]
                    self.create_subscription(
                        Float64MultiArray, inp.topic,
                        partial(self._on_array, inp.name, pubs=pubs, dim=dim),
                        qos_profile_sensor_data)
                else:
                    pubs = [self.create_publisher(Float64, f"/{inp.name}/strain", 10),
                            self.create_publisher(Int8, f"/{inp.name}/direction", 10)]
                    self.create_subscription(
                        Float64, inp.topic,
                        partial(self._on_sensor, inp.name, pubs=pubs),
                        qos_profile_sensor_data)
                for sensor in inp.sensors:
                    self.create_subscription(
                        Temperature, f"/{sensor}/temperature",
                        partial(self._on_temperature, sensor),
                        qos_profile_sensor_data)
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(self.live.tunables["diagnostics_period_s"], self._diagnostics)
            self.add_on_set_parameters_callback(self._on_set)

        def _declare(self, specs: list[ParamSpec]) -> dict[str, Any]:
            values = {}
            for spec in specs:
                default = (Parameter.Type.STRING_ARRAY if spec.type == "string_array"
                           else Parameter.Type.STRING if spec.type == "string" else spec.default)
                value = self.declare_parameter(spec.name, default, _descriptor(spec)).value
                if value is not None and value != "":
                    values[spec.name] = list(value) if spec.type == "string_array" else value
            return values

        def _now(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def _guard(self, name: str, err: Exception) -> None:
            self.live.n_errors += 1
            self.get_logger().warning(f"{name}: message not handled: {err}",
                                      throttle_duration_sec=5.0)

        def _on_temperature(self, name: str, msg: Any) -> None:
            self.live.on_temperature(name, msg.temperature)

        def _on_sensor(self, name: str, msg: Any, pubs: list[Any]) -> None:
            try:
                out = self.live.on_sensor(name, self._now(), msg.data)
                if out is not None:
                    pubs[0].publish(Float64(data=out.strain))
                    pubs[1].publish(Int8(data=out.direction))
            except _MESSAGE_ERRORS as err:  # a bad message must never stop the node
                self._guard(name, err)

        def _on_array(self, name: str, msg: Any, pubs: list[Any], dim: Any) -> None:
            try:
                out = self.live.on_array(name, self._now(), list(msg.data))
                if out is not None:
                    for pub, values in zip(pubs, (out.strain, out.direction), strict=True):
                        msg = Float64MultiArray(data=[float(v) for v in values])
                        msg.layout.dim = [dim]
                        pub.publish(msg)
            except _MESSAGE_ERRORS as err:  # a bad message must never stop the node
                self._guard(name, err)

        def _diagnostics(self) -> None:
            now = self.get_clock().now()
            msg = DiagnosticArray(status=[
                DiagnosticStatus(level=bytes([level]), name=name, message=message,
                                 values=[KeyValue(key=k, value=v) for k, v in values.items()])
                for name, level, message, values in self.live.diagnostics(now.nanoseconds * 1e-9)
            ])
            msg.header.stamp = now.to_msg()
            self.diag_pub.publish(msg)

        def _on_set(self, params: list[Any]) -> Any:
            try:
                for p in params:  # validate all first, then apply
                    if p.name in TUNABLE:
                        self.live.check_tunable(p.name, p.value)
                for p in params:
                    if p.name in TUNABLE:
                        self.live.set_tunable(p.name, p.value)
            except ParameterError as err:
                return SetParametersResult(successful=False, reason=str(err))
            return SetParametersResult(successful=True)

    return CompensatorNode()


def main(args: list[str] | None = None) -> int:
    """``compensator`` console script: spin the node until shutdown."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init(args=args)
    try:
        node = create_node()
    except StrainCompError as err:
        print(f"compensator: {err}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
