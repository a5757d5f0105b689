"""The rclpy node (thin): ROS topics, services and parameters around a ``LiveCompensator``.

``ros2 run strain_comp compensator --ros-args --params-file config/compensator_params.yaml``.
Parameters as in ``strain_comp.ros.params`` (structural ones read-only, tunables ranged and
validated, integers accepted for floats); inputs with sensor-data QoS, topic names resolved
in the node's namespace, ``/diagnostics`` absolute; with ``fuse_references: true`` a
``NAME/strain_reference`` input per sensor or array (``LiveCompensator.on_reference``);
services ``~/tare``, ``~/reference`` (every sensor is at ``known_strain`` now: fused into
its output gain and offset, ``LiveCompensator.reference_now``), ``~/span`` (input
zero and span at the known strain ``span_strain``, ``LiveCompensator.span``) and
``~/reload_calibration`` (std_srvs/Trigger: answers "loading ..." at once; a worker
thread loads, the executor swaps the result in between two messages, so outputs go on
while a large file loads; the result goes to the log and /diagnostics). Each input is
stamped with the node clock when its callback runs, so ``use_sim_time`` follows /clock.

Start-up problems (params file missing or not YAML, no block for the node's name, a bad or
unknown parameter, a missing calibration) print one line ``compensator: ...`` and exit 2.
SIGINT / SIGTERM exit 0 at any moment: during start-up at once, while spinning after a clean
shutdown bounded by ``SHUTDOWN_S``. Only the standard library is imported at module level, so
the signal handlers are in place before anything slow is imported.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from copy import copy
from functools import partial
from pathlib import Path
from typing import Any

NODE_NAME = "compensator"
SHUTDOWN_S = 1.5
"""Longest clean shutdown after SIGINT/SIGTERM before the process exits regardless [s]."""
EXIT_BAD_INPUT = 2
INPUT_DEPTH = 50
"""Inputs are best effort (sensor-data QoS) keeping the latest 50 messages: 50 ms of a 1 kHz
stream, so a scheduling stall on a busy computer costs no sample, while an input rate beyond
the node's drops the oldest instead of queuing without bound."""
_stop = threading.Event()
_stopped_by: list[str] = []

# what handling one message or service call can raise: the engine's input errors, and a
# message of the wrong shape or type (no ``data`` field, values that do not convert to float,
# a wrong array length)
_MESSAGE_ERRORS = (ArithmeticError, ValueError, TypeError, LookupError, AttributeError)


def _exit_now(signum: int, frame: Any) -> None:
    os._exit(0)


def _request_stop(signum: int, frame: Any) -> None:
    _stopped_by.append(signal.Signals(signum).name)
    _stop.set()
    watchdog = threading.Timer(SHUTDOWN_S, os._exit, args=(0,))
    watchdog.daemon = True
    watchdog.start()


def _ros_flags(args: list[str], flags: tuple[str, ...]) -> Iterator[tuple[str, str]]:
    """(flag, its value) for each of ``flags`` in the ``--ros-args`` part of ``args``."""
    inside = False
    it = iter(args)
    for arg in it:
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg in flags:
            yield arg, next(it, "")


def _unqualified(key: str) -> str:
    """A rule's key without its ``node:`` prefix (``name:key`` -> ``key``)."""
    return key.split(":", 1)[-1] if key.count(":") == 1 else key


def ros_arguments(args: list[str]) -> tuple[list[Path], str, str]:
    """(params files, node name, namespace) from the ``--ros-args`` part of ``args``."""
    files: list[Path] = []
    name, namespace = NODE_NAME, "/"
    for flag, value in _ros_flags(args, ("--params-file", "-r", "--remap")):
        if flag == "--params-file":
            files.append(Path(value))
        elif ":=" in value:
            key, target = value.split(":=", 1)
            key = _unqualified(key)
            if key == "__node" or key == "__name":
                name = target
            elif key == "__ns":
                namespace = target
    return files, name, namespace


def command_line_params(args: list[str]) -> dict[str, str]:
    """The ``-p NAME:=VALUE`` (``--param``) overrides of the ``--ros-args`` part, as given."""
    return {_unqualified(rule.partition(":=")[0]): rule
            for _, rule in _ros_flags(args, ("-p", "--param"))}


def check_params_files(files: list[Path], name: str, namespace: str) -> Path | None:
    """The folder of the last params file holding a block for the node (relative calibration
    paths resolve there); StrainCompError naming the file when a file cannot be used."""
    from strain_comp.errors import InputError
    from strain_comp.ros.params import block_names, read_blocks

    base = None
    for path in files:
        blocks = read_blocks(path)
        if any(b in blocks for b in block_names(name, namespace)):
            base = path.resolve().parent
        elif name != NODE_NAME or len(files) == 1:
            fqn = f"{namespace.rstrip('/')}/{name}"
            raise InputError(f"{path}: no parameters for node {fqn!r} (the file holds: "
                             f"{', '.join(blocks)}); name a block '{fqn}' or '/**/{name}'")
    return base


def _descriptor(spec: Any) -> Any:
    """The ParameterDescriptor of a ``ParamSpec``: a fixed type (a refused set never changes
    it), the range, the description, read-only."""
    from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType

    kinds = {"double": ParameterType.PARAMETER_DOUBLE, "string": ParameterType.PARAMETER_STRING,
             "bool": ParameterType.PARAMETER_BOOL,
             "string_array": ParameterType.PARAMETER_STRING_ARRAY}
    descriptor = ParameterDescriptor(name=spec.name, description=spec.description,
                                     read_only=spec.read_only, type=kinds[spec.type],
                                     dynamic_typing=False)
    if spec.range is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(spec.range[0]), to_value=float(spec.range[1]), step=0.0)]
    return descriptor


def _send(publisher: Any, message: Callable[[], Any]) -> None:
    """Build and publish a message only when a subscription is matched: at 1 kHz the
    building and serialising of an unread output is most of the node's CPU."""
    if publisher.get_subscription_count():
        publisher.publish(message())


def create_node(node_name: str = NODE_NAME, *, base_dir: Path | None = None,
                **node_options: Any) -> Any:
    """Build the node (rclpy must be initialised); StrainCompError on bad parameters.

    Parameters come from the node's overrides (params files, ``-p``, ``parameter_overrides``).
    """

    import numpy as np
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.clock import JumpThreshold, ROSClock
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.time_source import USE_SIM_TIME_NAME as USE_SIM_TIME
    from sensor_msgs.msg import JointState, Temperature
    from std_msgs.msg import Float64, Float64MultiArray, Int8
    from std_srvs.srv import Trigger

    from strain_comp.errors import ParameterError, StrainCompError
    from strain_comp.ros.cdr import StampedEncoder, VectorEncoder
    from strain_comp.ros.live import OK, WARN, ClockGate, LiveCompensator
    from strain_comp.ros.params import ROS_OWNED, TUNABLE, parse_values, structural_specs

    class CompensatorNode(Node):
        def __init__(self) -> None:
            super().__init__(node_name, **node_options)
            self._loading: threading.Thread | None = None
            self._loaded: Any = None
            """The finished load (a LiveCompensator, or the reason it was refused), swapped
            in by ``_adopt`` before the next message or diagnostics tick (rclpy's
            EventsExecutor has no guard conditions to wake the executor with)."""
            self.flat = {k: p.value for k, p in self._parameter_overrides.items()
                         if k.split(".")[0] not in ROS_OWNED}
            self.base_dir = base_dir
            self.gate = ClockGate()
            self._guard_clock()
            self._jump = self.get_clock().create_jump_callback(
                JumpThreshold(min_forward=Duration(nanoseconds=1), min_backward=None,
                              on_clock_change=False), post_callback=self._on_tick)
            self.live = LiveCompensator(parse_values(self.flat, base_dir=base_dir))
            params = self.live.params
            names = [i.name for i in params.inputs]
            for spec in structural_specs([i.name for i in params.inputs if not i.is_array],
                                         [i.name for i in params.inputs if i.is_array]):
                self._declare(spec, self.flat.get(spec.name, spec.default))
            for name, value in params.tunables.items():
                self._declare(TUNABLE[name], value)
            self.add_pre_set_parameters_callback(self._integers_as_doubles)
            ready = []
            input_qos = copy(qos_profile_sensor_data)
            input_qos.depth = INPUT_DEPTH
            self.stamped = {i.name: StampedEncoder(list(i.sensors)) for i in params.inputs}
            for inp in params.inputs:
                kind = Float64MultiArray if inp.is_array else Float64
                pubs = [self.create_publisher(kind, f"{inp.name}/strain", 10),
                        self.create_publisher(Float64MultiArray if inp.is_array else Int8,
                                              f"{inp.name}/direction", 10),
                        self.create_publisher(JointState, f"{inp.name}/strain_stamped", 10)]
                handler = self._on_array if inp.is_array else self._on_sensor
                sub = self.create_subscription(
                    kind, inp.topic, self._receiver(inp.name, handler, pubs), input_qos)
                if not inp.is_array:  # the array tick has no temperature input
                    self.create_subscription(
                        Temperature, f"{inp.name}/temperature",
                        partial(self._on_temperature, inp.name), qos_profile_sensor_data)
                if params.fuse_references:
                    self.create_subscription(
                        kind, f"{inp.name}/strain_reference",
                        partial(self._on_reference, inp.name, inp.is_array), input_qos)
                models = ",".join(sorted({params.calibration.sensors[s].model
                                          for s in inp.sensors}))
                ready.append(f"{inp.name} [{','.join(inp.sensors)}] ({models}) "
                             f"{sub.topic_name} -> {pubs[0].topic_name}")
            self.vector = {i.name: VectorEncoder(list(i.sensors)) for i in params.inputs}
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(self.live.tunables["diagnostics_period_s"], self._diagnostics)
            self.add_on_set_parameters_callback(self._on_set)
            self.create_service(Trigger, "~/tare", self._tare)
            self.create_service(Trigger, "~/span", self._span)
            self.create_service(Trigger, "~/reference", self._reference)
            self.create_service(Trigger, "~/reload_calibration", self._reload)
            self.calibration_status = (OK, "loaded " + self._paths(self.live))
            self.get_logger().info(f"ready: {len(names)} inputs: " + "; ".join(ready)
                                   + f"; tare {params.tare}; fuse_references "
                                   f"{params.fuse_references}")

        def _guard_clock(self) -> None:
            """/clock through ``_on_clock`` (rclpy's own callback raises on a negative time,
            which would end the node), also when sim time is on from the start."""
            source = self._time_source
            self._clock_callback = source.clock_callback
            source.clock_callback = self._on_clock  # type: ignore[method-assign]
            if source._clock_sub is not None:
                self.destroy_subscription(source._clock_sub)
                source._clock_sub = None
                source._subscribe_to_clock_topic()

        def _on_clock(self, msg: Any) -> None:
            """A /clock tick from any peer: a time rclpy cannot hold (negative) is refused
            and counted under ``/clock``; the clock keeps its time."""
            if msg.clock.sec < 0:
                self._refuse("/clock", ValueError("negative time"))
                return
            self._clock_callback(msg)

        def _declare(self, spec: Any, value: Any) -> None:
            """Declare a parameter with its fixed type; an empty (or, from a dump, null)
            list stays a string array (rclpy would infer BYTE_ARRAY from [])."""
            if spec.type == "string_array" and not value:
                self.declare_parameter(spec.name, Parameter.Type.STRING_ARRAY, _descriptor(spec),
                                       ignore_override=True)
                self._parameters[spec.name] = Parameter(spec.name, Parameter.Type.STRING_ARRAY,
                                                        [])
            else:
                self.declare_parameter(spec.name, float(value) if spec.type == "double"
                                       else value, _descriptor(spec), ignore_override=True)

        def _integers_as_doubles(self, params: list[Any]) -> list[Any]:
            """``ros2 param set deadzone_scale 2``: an integer for a double tunable is set as
            a double (before rclpy's type check, which would refuse it)."""
            return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                    if p.name in TUNABLE and p.type_ == Parameter.Type.INTEGER else p
                    for p in params]

        def _receiver(self, name: str, handler: Any, pubs: list[Any]) -> Callable[[Any], None]:
            def receive(msg: Any) -> None:
                self._arrive(name, handler, msg, pubs)
            return receive

        def _on_temperature(self, sensor: str, msg: Any) -> None:
            self.live.on_temperature(sensor, msg.temperature)

        def _now_ns(self) -> int:
            """The node clock [ns]: the system time, or /clock under sim time."""
            clock = self.get_clock()
            if isinstance(clock, ROSClock) and clock.ros_time_is_active:
                return int(clock.now().nanoseconds)
            return time.time_ns()

        def _on_reference(self, name: str, is_array: bool, msg: Any) -> None:
            """A known strain of a sensor (Float64) or of an array's sensors
            (Float64MultiArray, NaN: none), stamped on arrival; a refusal is counted in
            the sensor's /diagnostics and logged, a malformed message under the transport."""
            if self._loaded is not None:
                self._adopt()
            topic = f"{name}/strain_reference"
            try:
                t = self._now_ns() * 1e-9
                if is_array:
                    refused = self.live.on_reference_array(
                        name, t, msg.data, offset=msg.layout.data_offset,
                        sizes=[d.size for d in msg.layout.dim],
                        label=msg.layout.dim[0].label if msg.layout.dim else "")
                else:
                    refused = {name: self.live.on_reference(name, t, msg.data)}
            except (StrainCompError, *_MESSAGE_ERRORS) as err:  # never stops the node
                self._refuse(topic, err)
                return
            for sensor, reason in refused.items():
                if reason is not None:
                    self.get_logger().warning(f"{sensor}: reference refused: {reason}",
                                              throttle_duration_sec=5.0)

        def _arrive(self, name: str, handler: Any, msg: Any, pubs: list[Any]) -> None:
            if self._loaded is not None:
                self._adopt()
            clock = self.get_clock()
            if not (isinstance(clock, ROSClock) and clock.ros_time_is_active):
                # the system time, which the ROS clock reads without /clock (cheaper than
                # clock.now() at 1 kHz)
                handler(name, time.time_ns(), msg, pubs)
                return
            now = clock.now().nanoseconds
            for stamp, (h, m, p) in self.gate.arrive(name, now, (handler, msg, pubs)):
                h(name, stamp, m, p)

        def _on_tick(self, jump: Any) -> None:
            if self._loaded is not None:
                self._adopt()
            now = self.get_clock().now().nanoseconds
            names = list(self.gate.held)
            for name, (stamp, (h, m, p)) in zip(names, self.gate.tick(now), strict=True):
                h(name, stamp, m, p)

        def _refuse(self, name: str, err: Exception) -> None:
            reason = " ".join(str(err).split())
            self.live.refuse(name, reason)
            self.get_logger().warning(f"{name}: message refused: {reason}",
                                      throttle_duration_sec=5.0)

        def _on_sensor(self, name: str, stamp: int, msg: Any, pubs: list[Any]) -> None:
            try:
                out = self.live.on_sensor(name, stamp * 1e-9, msg.data)
                if out is not None:
                    value, direction = out.strain, int(out.direction)
                    _send(pubs[0], lambda: Float64(data=value))
                    _send(pubs[1], lambda: Int8(data=direction))
                    _send(pubs[2], lambda: self.stamped[name].encode(stamp, np.array([value])))
            except (StrainCompError, *_MESSAGE_ERRORS) as err:  # never stops the node
                self._refuse(name, err)
            self._log_tare()

        def _on_array(self, name: str, stamp: int, msg: Any, pubs: list[Any]) -> None:
            try:
                out = self.live.on_array(name, stamp * 1e-9, msg.data,
                                         offset=msg.layout.data_offset,
                                         sizes=[d.size for d in msg.layout.dim],
                                         label=msg.layout.dim[0].label if msg.layout.dim
                                         else "")
                if out is not None:
                    strain, direction, vector = out.strain, out.direction, self.vector[name]
                    _send(pubs[0], lambda: vector.encode(strain))
                    _send(pubs[1], lambda: vector.encode(direction))
                    _send(pubs[2], lambda: self.stamped[name].encode(stamp, strain))
            except (StrainCompError, *_MESSAGE_ERRORS) as err:  # never stops the node
                self._refuse(name, err)
            self._log_tare()

        def _log_tare(self) -> None:
            while self.live.tare_log:
                self.get_logger().info(self.live.tare_log.pop(0))

        def _diagnostics(self) -> None:
            self._adopt()
            now = self.get_clock().now()
            msg = DiagnosticArray(status=[
                DiagnosticStatus(level=bytes([level]), name=name, message=message,
                                 values=[KeyValue(key=k, value=v) for k, v in values.items()])
                for name, level, message, values in [
                    *self.live.diagnostics(now.nanoseconds * 1e-9),
                    ("strain_comp: calibration", *self.calibration_status, {})]
            ])
            msg.header.stamp = now.to_msg()
            self.diag_pub.publish(msg)

        def _on_set(self, params: list[Any]) -> Any:
            for p in params:  # any peer may call set_parameters: the time source is fixed
                if p.name == USE_SIM_TIME and p.value != self.get_parameter(USE_SIM_TIME).value:
                    return SetParametersResult(successful=False, reason=(
                        f"{USE_SIM_TIME} is fixed at start (params file or -p "
                        f"{USE_SIM_TIME}:=...); restart the node to change it"))
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

        def _busy(self, response: Any) -> bool:
            """Refuse a call into ``response`` while a reload is in flight (its result
            would replace what the call changes)."""
            if self._loading is None:
                return False
            response.success = False
            response.message = "refused: a calibration reload is in flight; call again"
            return True

        def _answer(self, response: Any, act: Callable[[], str]) -> Any:
            """A Trigger response: ``act()``'s summary (logged), or its error in one line;
            refused while a reload is in flight."""
            if self._busy(response):
                return response
            try:
                response.message = act()
                response.success = True
                self.get_logger().info(response.message)
            except (StrainCompError, *_MESSAGE_ERRORS) as err:  # never stops the node
                response.success, response.message = False, " ".join(str(err).split())
            return response

        def _tare(self, request: Any, response: Any) -> Any:
            return self._answer(response, self.live.tare)

        def _reference(self, request: Any, response: Any) -> Any:
            return self._answer(response, lambda: self.live.reference_now(self._now_ns() * 1e-9))

        def _span(self, request: Any, response: Any) -> Any:
            def span() -> str:
                self.live, summary = self.live.span()
                return summary
            return self._answer(response, span)

        @staticmethod
        def _paths(live: Any) -> str:
            return ", ".join(sorted({str(i.calibration_path) for i in live.params.inputs}))

        def _reload(self, request: Any, response: Any) -> Any:
            """Start loading the calibration files on a worker thread and answer at once
            ("loading ..."); the result goes to the log and /diagnostics. A call while a
            load is in flight is refused."""
            if self._busy(response):
                return response
            current = self.live
            self._loading = threading.Thread(target=self._load, args=(current,),
                                             name="reload_calibration", daemon=True)
            self.calibration_status = (OK, "loading " + self._paths(current))
            response.success, response.message = True, self.calibration_status[1]
            self.get_logger().info(response.message)
            self._loading.start()
            return response

        def _load(self, current: Any) -> None:
            """Worker thread: read, validate and build the new compensator (``successor``)
            and leave it (or the reason it was refused) in ``_loaded``."""
            outcome: Any = "the load ended without a result"
            try:
                outcome = current.successor(parse_values(self.flat, base_dir=self.base_dir))
            except Exception as err:  # a worker thread: whatever ends the load is its reason
                outcome = " ".join(str(err).split()) or type(err).__name__
            finally:
                self._loaded = outcome

        def _adopt(self) -> None:
            """Executor thread, before a message or diagnostics tick: once the load has
            finished, swap the loaded compensator in (``hand_over``: counters carry on) or
            log the refusal; the old one keeps running until then, and after a refusal."""
            if self._loaded is None:
                return
            outcome, self._loaded = self._loaded, None
            if self._loading is not None:
                self._loading.join()  # it has left its result: done in a moment
            self._loading = None
            if isinstance(outcome, str):
                self.calibration_status = (WARN, "reload refused, the old calibration keeps "
                                           "running: " + outcome)
                self.get_logger().error(self.calibration_status[1])
                return
            self.live = self.live.hand_over(outcome)
            self.calibration_status = (OK, "reloaded " + self._paths(self.live))
            self.get_logger().info(self.calibration_status[1])

    return CompensatorNode()


def main(args: list[str] | None = None) -> int:
    """``compensator``: spin the node until SIGINT/SIGTERM or shutdown, then exit 0; returns
    ``EXIT_BAD_INPUT`` when the node cannot start."""
    signal.signal(signal.SIGINT, _exit_now)
    signal.signal(signal.SIGTERM, _exit_now)
    argv = list(sys.argv if args is None else args)
    # rclpy's own argument and parameter-file errors (RCLError is a RuntimeError), and what
    # reading a params file can raise
    start_errors: tuple[type[Exception], ...] = (RuntimeError, ValueError, TypeError, OSError)
    try:
        from strain_comp.errors import StrainCompError

        files, name, namespace = ros_arguments(argv)
        base_dir = check_params_files(files, name, namespace)
        import rclpy
        from rclpy.exceptions import ParameterException
        from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions

        start_errors = (*start_errors, ParameterException)

        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        node = create_node(name, base_dir=base_dir)
    except StrainCompError as err:
        given = command_line_params(argv).get(getattr(err, "field", ""))
        if given is not None:  # -p wins over the params files: the command line is at fault
            where = f"command line (-p {given}): "
        elif files and not str(err).startswith(str(files[-1])):
            where = f"{files[-1]}: "
        else:
            where = ""
        print(f"{NODE_NAME}: {where}" + " ".join(str(err).split()), file=sys.stderr)
        return EXIT_BAD_INPUT
    except start_errors as err:
        print(f"{NODE_NAME}: cannot start: " + " ".join(str(err).split()[:40]), file=sys.stderr)
        return EXIT_BAD_INPUT
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)
    # rclpy 7.1.6's EventsExecutor loses inputs under use_sim_time (docs/ros.md)
    sim_time = node.get_parameter("use_sim_time").value
    executor = (EventsExecutor() if node.live.params.executor == "events" and not sim_time
                else SingleThreadedExecutor())
    executor.add_node(node)
    try:
        while not _stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if _stopped_by:
            node.get_logger().info(f"{_stopped_by[0]}: stopped")
        signal.signal(signal.SIGINT, _exit_now)
        signal.signal(signal.SIGTERM, _exit_now)
        executor.shutdown(timeout_sec=0.5)
        node.destroy_node()
        rclpy.try_shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # the interpreter's own teardown of the DDS library can take over a second


if __name__ == "__main__":
    sys.exit(main())
