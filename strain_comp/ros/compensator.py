"""The compensator node: ROS topics, services and parameters around the ``LiveCompensator``
it owns (docs/ros.md; docs/reliability.md, "The live node")."""

from __future__ import annotations

import threading
import traceback
from collections.abc import Callable
from copy import copy
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.clock import Clock, JumpThreshold, TimeJump
from rclpy.clock_type import ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from rclpy.time_source import USE_SIM_TIME_NAME as USE_SIM_TIME
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Float64, Float64MultiArray, Int8
from std_srvs.srv import Trigger

from strain_comp.core.calibration import expected_words
from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.cdr import RowEncoder
from strain_comp.io.multiarray import array_values
from strain_comp.ros.cdr import RowDecoder
from strain_comp.ros.live import NON_FINITE, OK, WARN, ClockGate, LiveCompensator
from strain_comp.ros.params import (
    ROS_OWNED,
    TUNABLE,
    InputTopic,
    NodeParams,
    ParamSpec,
    parse_values,
    structural_specs,
)
from strain_comp.ros.rclpy_typed import destroy, logger, parameter

INPUT_DEPTH = 200
"""Inputs are best effort keeping the latest 200 messages, 200 ms at 1 kHz (docs/ros.md)."""
OUTPUT_DEPTH = 100
"""Outputs are reliable, keeping 100 messages for a subscriber not scheduled in time."""
LOG_THROTTLE_S = 5.0
"""A refusal or a program error of one kind is logged at most once per this many seconds."""


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """A ``ParamSpec``'s descriptor, with a fixed type (a refused set never changes it)."""
    kind = getattr(ParameterType, f"PARAMETER_{spec.type.upper()}")
    described = ParameterDescriptor(name=spec.name, description=spec.description,
                                    read_only=spec.read_only, type=kind)
    if spec.range is not None:
        described.floating_point_range = [FloatingPointRange(
            from_value=float(spec.range[0]), to_value=float(spec.range[1]), step=0.0)]
    return described


def _taken_later(msg: Any) -> None:
    """The intake subscriptions' callback, never called: no executor spins their node."""


def _one_line(error: BaseException) -> str:
    """An error's message on one line (its type's name when it has none)."""
    return " ".join(str(error).split()) or type(error).__name__


class CompensatorNode(Node):
    """The node (rclpy must be initialised); StrainCompError on bad parameters."""

    def __init__(self, node_name: str, *, base_dir: Path | None = None,
                 **node_options: Any) -> None:
        super().__init__(node_name, **node_options)
        self._loading: threading.Thread | None = None
        self._loaded: LiveCompensator | str | None = None
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
        for spec in structural_specs([i.name for i in params.inputs if not i.is_array],
                                     [i.name for i in params.inputs if i.is_array]):
            self._declare(spec, self.flat.get(spec.name, spec.default))
        for name, value in params.tunables.items():
            self._declare(TUNABLE[name], value)
        self.add_pre_set_parameters_callback(self._integers_as_doubles)
        self._arrays = {i.name for i in params.inputs if i.is_array}
        self._sensors = {i.name: i.sensors for i in params.inputs}
        self._queued: dict[str, tuple[list[int], list[np.ndarray]]] = {
            i.name: ([], []) for i in params.inputs}
        """Per input, the stamps [ns] and values (blocks of rows) not yet handled."""
        self._outputs: dict[str, list[tuple[Publisher, RowEncoder, str]]] = {}
        """Per input, its outputs: (publisher, encoder, the ``ArrayOutput`` field)."""
        self._intake = None if self.get_parameter(USE_SIM_TIME).value else Node(
            f"{node_name}_intake", namespace=self.get_namespace(), context=self.context,
            start_parameter_services=False, enable_rosout=False)
        """Off sim time, the input subscriptions' node, spun by no executor (``_flush``)."""
        self._takes: list[tuple[str, Subscription, RowDecoder]] = []
        ready = [self._connect(i) for i in params.inputs]
        self.create_timer(self.live.tunables["batch_period_s"], self._flush,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(self.live.tunables["diagnostics_period_s"], self._diagnostics)
        self.add_on_set_parameters_callback(self._on_set)
        services: dict[str, Callable[[], tuple[LiveCompensator, str]]] = {
            "tare": lambda: (self.live, self.live.taring.tare()),
            "span": lambda: self.live.span(),
            "reference": lambda: (self.live, self.live.reference_now(self._now_ns() * 1e-9)),
            "start": lambda: self.live.start(self._now_ns() * 1e-9),
            "reload_calibration": lambda: (self.live, self._reload())}
        for service, act in services.items():
            self.create_service(Trigger, f"~/{service}", partial(self._answer, service, act))
        self.calibration_status = (OK, "loaded " + self._paths(self.live))
        self.ready_line = (f"ready: {len(ready)} inputs: " + "; ".join(ready)
                           + f"; tare {params.tare}; fuse_references {params.fuse_references}")

    def _connect(self, inp: InputTopic) -> str:
        """The publishers and subscriptions of an input; its line of the ready log."""
        params, name = self.live.params, inp.name
        input_qos = copy(qos_profile_sensor_data)
        input_qos.depth = INPUT_DEPTH
        kind = Float64MultiArray if inp.is_array else Float64
        value = RowEncoder.vector(list(inp.sensors)) if inp.is_array else RowEncoder.scalar("<f8")
        stamped = RowEncoder.joint_state(list(inp.sensors))
        outputs = [(kind, "strain", value, "strain"),
                   (Float64MultiArray if inp.is_array else Int8, "direction",
                    value if inp.is_array else RowEncoder.scalar("i1"), "direction"),
                   (JointState, "strain_stamped", stamped, "strain")]
        if any(params.calibration.sensors[s].uncertainty for s in inp.sensors):  # the band
            outputs += [(kind, "strain_std", value, "std"),
                        (JointState, "strain_std_stamped", stamped, "std")]
        self._outputs[name] = [
            (self.create_publisher(msg_type, f"{name}/{topic}", OUTPUT_DEPTH), encoder, field)
            for msg_type, topic, encoder, field in outputs]
        if self._intake is None:
            sub = self.create_subscription(kind, inp.topic, partial(self._arrive, name),
                                           input_qos)
        else:
            sub = self._intake.create_subscription(kind, self.resolve_topic_name(inp.topic),
                                                   _taken_later, input_qos)
            self._takes.append((name, sub, RowDecoder()))
        for sensor in inp.sensors:  # as replay reads them: SENSOR/temperature
            self.create_subscription(Temperature, f"{sensor}/temperature",
                                     partial(self._on_temperature, sensor),
                                     qos_profile_sensor_data)
        self.create_subscription(kind, f"{name}/strain_reference",  # fused, or ~/start's
                                 partial(self._on_reference, name, inp.is_array), input_qos)
        models = ",".join(sorted({params.calibration.sensors[s].model for s in inp.sensors}))
        members = (f"{len(inp.sensors)} sensors: {inp.sensors[0]} .. {inp.sensors[-1]}"
                   if inp.is_array else ",".join(inp.sensors))
        expected = [expected_words(params.calibration.sensors[s]) for s in inp.sensors]
        told = next((f", {w}" for w in expected if w), "")
        return (f"{name} [{members}] ({models}{told}) {sub.topic_name} -> "
                f"{self._outputs[name][0][0].topic_name}")

    # --- what goes wrong ------------------------------------------------------------------

    def destroy_node(self) -> None:
        """The node and its intake node."""
        if self._intake is not None:
            destroy(self._intake)
        own: Callable[[], None] = super().destroy_node
        own()

    def _refuse(self, name: str, reason: str) -> None:
        """A message (or /clock tick) refused for what it carries: counted, logged."""
        reason = " ".join(reason.split())
        self.live.refuse(name, reason)
        logger(self).warning(f"{name}: message refused: {reason}",
                                  throttle_duration_sec=LOG_THROTTLE_S)

    def _fault(self, name: str, error: Exception) -> None:
        """A program error while handling ``name``: counted apart, logged with its traceback."""
        self.live.fault(name, error)
        logger(self).error(
            f"{name}: program error (a bug, not the message): {type(error).__name__}: "
            f"{_one_line(error)}\n" + "".join(traceback.format_exception(error)).rstrip(),
            throttle_duration_sec=LOG_THROTTLE_S)

    def _guarded(self, name: str, act: Callable[[], object]) -> None:
        """``act()``; a refusal or a program error is counted, never ends the node."""
        try:
            act()
        except StrainCompError as err:
            self._refuse(name, str(err))
        except Exception as err:  # a fault of the program: reported as one, the node goes on
            self._fault(name, err)

    # --- the clock ------------------------------------------------------------------------

    def _guard_clock(self) -> None:
        """/clock through ``_on_clock`` (rclpy's own raises on a negative time)."""
        source = self._time_source
        self._clock_callback = source.clock_callback
        source.clock_callback = self._on_clock  # type: ignore[method-assign]
        if source._clock_sub is not None:
            self.destroy_subscription(source._clock_sub)
            source._clock_sub = None
            source._subscribe_to_clock_topic()

    def _on_clock(self, msg: Any) -> None:
        """A /clock tick: a time rclpy cannot hold (negative) is refused under ``/clock``."""
        def tick() -> None:
            if msg.clock.sec < 0:
                raise InputError("negative time")
            self._clock_callback(msg)
        self._guarded("/clock", tick)

    def _now_ns(self) -> int:
        """The node clock [ns]: the system time, or /clock under sim time."""
        return int(self.get_clock().now().nanoseconds)

    def _on_tick(self, jump: TimeJump) -> None:
        """The sim clock moved: the inputs held for it are handled, stamped with it."""
        self._gated(self.gate.tick)

    def _arrive(self, name: str, msg: Any) -> None:
        """Under sim time, an input: handled once its /clock tick has come (the gate)."""
        self._gated(lambda now: self.gate.arrive(name, now, msg))

    def _gated(self, release: Callable[[int], list[tuple[str, int, Any]]]) -> None:
        """What the gate releases at the node clock's time, queued and handled."""
        self._adopt()
        for name, stamp, msg in release(self._now_ns()):
            self._guarded(name, partial(self._queue, name, stamp, msg))
        self._flush()

    # --- parameters -----------------------------------------------------------------------

    def _declare(self, spec: ParamSpec, value: Any) -> None:
        """Declare a parameter; an empty list stays a string array (rclpy infers BYTE_ARRAY)."""
        if spec.type == "string_array" and not value:
            self.declare_parameter(spec.name, Parameter.Type.STRING_ARRAY, _descriptor(spec),
                                   ignore_override=True)
            self._parameters[spec.name] = parameter(spec.name, Parameter.Type.STRING_ARRAY, [])
        else:
            self.declare_parameter(spec.name, float(value) if spec.type == "double"
                                   else value, _descriptor(spec), ignore_override=True)

    def _integers_as_doubles(self, params: list[Parameter]) -> list[Parameter]:
        """An integer for a double tunable set as a double (rclpy's type check refuses it)."""
        return [parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                if p.name in TUNABLE and p.type_ == Parameter.Type.INTEGER else p
                for p in params]

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Tunables applied (the descriptors checked them); ``use_sim_time`` fixed at start."""
        self._flush()
        for p in params:  # any peer may call set_parameters: the time source is fixed
            if p.name == USE_SIM_TIME and p.value != self.get_parameter(USE_SIM_TIME).value:
                return SetParametersResult(successful=False, reason=(
                    f"{USE_SIM_TIME} is fixed at start (params file or -p "
                    f"{USE_SIM_TIME}:=...); restart the node to change it"))
        for p in params:  # rclpy refused a read-only, mistyped or out-of-range value before
            if p.name in TUNABLE:
                self.live.set_tunable(p.name, p.value)
        return SetParametersResult(successful=True)

    # --- messages -------------------------------------------------------------------------

    def _read(self, name: str, msg: Any) -> tuple[np.ndarray, np.ndarray, int]:
        """A message's values in sensor order, their columns in its data, its value count."""
        if name not in self._arrays:
            return np.array([msg.data]), np.zeros(1, np.intp), 1
        data, dims, sensors = msg.data, msg.layout.dim, self._sensors[name]
        where = array_values(np.arange(len(data)), msg.layout.data_offset,
                             [d.size for d in dims], len(sensors),
                             dims[0].label if dims else "", sensors)
        columns = where.astype(np.intp)
        return np.asarray(data, dtype=np.float64)[columns], columns, len(data)

    def _queue(self, name: str, stamp: int, msg: Any) -> tuple[np.ndarray, np.ndarray, int]:
        read = self._read(name, msg)
        self._queue_rows(name, [stamp], read[0][None])
        return read

    def _learn(self, name: str, stamp: int, raw: bytes, kind: Any, decoder: RowDecoder
               ) -> None:
        """Queue an intake message of a new layout; read that layout in bulk from then on."""
        values, columns, n_values = self._queue(name, stamp, deserialize_message(raw, kind))
        decoder.learn(raw, n_values, columns, values)

    def _queue_rows(self, name: str, stamps: list[int], rows: np.ndarray) -> None:
        queued_stamps, blocks = self._queued[name]
        queued_stamps.extend(stamps)
        blocks.append(rows)

    def _flush(self) -> None:
        """Handle what arrived, one batch per input (before anything that reads the state)."""
        for name, sub, decoder in self._takes:
            self._guarded(name, partial(self._take, name, sub, decoder))
        for name, (stamps, values) in self._queued.items():
            if stamps:
                self._queued[name] = ([], [])
                self._guarded(name, partial(self._handle, name, stamps, values))
        while self.live.taring.log:  # the automatic tares taken or declined
            logger(self).info(self.live.taring.log.pop(0))

    def _take(self, name: str, sub: Subscription, decoder: RowDecoder) -> None:
        """Queue what arrived on ``sub`` as bytes, the layout last read in bulk (``decoder``)."""
        with sub.handle:
            taken = []
            while (one := sub.handle.take_message(sub.msg_type, True)) is not None:
                taken.append(one)
        stamps: list[int] = []
        raws: list[bytes] = []
        for raw, info in taken:
            if not decoder.fits(raw):
                if raws:
                    self._queue_rows(name, stamps, decoder.rows(raws))
                    stamps, raws = [], []
                self._guarded(name, partial(self._learn, name, info["received_timestamp"], raw,
                                            sub.msg_type, decoder))
            else:
                stamps.append(info["received_timestamp"])
                raws.append(raw)
        if raws:
            self._queue_rows(name, stamps, decoder.rows(raws))

    def _handle(self, name: str, stamps: list[int], blocks: list[np.ndarray]) -> None:
        """A batch of input ``name``'s messages through the compensator; publish the outputs."""
        stamps_ns = np.array(stamps, dtype=np.int64)
        t = stamps_ns.astype(np.float64) * 1e-9
        out, publish, refused = self.live.on_input(name, t, np.concatenate(blocks))
        for _ in range(int(np.count_nonzero(refused))):
            self._refuse(name, NON_FINITE)
        rows = np.flatnonzero(publish)
        if not rows.size:
            return
        for pub, encoder, field in self._outputs[name]:
            if pub.get_subscription_count():
                messages = encoder.encode(getattr(out, field)[rows], stamps_ns[rows])
                handle = pub.handle  # rclpy's Publisher.publish of bytes, once per batch
                with handle:
                    for message in messages:
                        handle.publish_raw(message)

    def _on_temperature(self, sensor: str, msg: Any) -> None:
        self._flush()
        self._guarded(f"{sensor}/temperature", lambda: self.live.on_temperature(
            sensor, msg.temperature))

    def _on_reference(self, name: str, is_array: bool, msg: Any) -> None:
        """A known strain of a sensor or of an array's sensors (NaN: none), stamped on arrival."""
        self._adopt()
        self._flush()

        def handle() -> None:
            t = self._now_ns() * 1e-9
            values = self._read(name, msg)[0]  # an array's NaN: no reference
            given = {s: float(v) for s, v in zip(self._sensors[name], values, strict=True)
                     if not (is_array and np.isnan(v))}
            refused = ({s: self.live.on_reference(s, t, v) for s, v in given.items()}
                       if self.live.fusion else {})
            for sensor, value in given.items():
                self.live = self.live.start_reference(sensor, t, value)
            for sensor, reason in refused.items():
                if reason is not None:
                    logger(self).warning(f"{sensor}: reference refused: {reason}",
                                              throttle_duration_sec=LOG_THROTTLE_S)
        self._guarded(f"{name}/strain_reference", handle)

    def _diagnostics(self) -> None:
        def publish() -> None:
            self._adopt()
            self._flush()
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
        self._guarded("/diagnostics", publish)

    # --- services -------------------------------------------------------------------------

    def _answer(self, service: str, act: Callable[[], tuple[LiveCompensator, str]],
                request: Any, response: Any) -> Any:
        """``act()``'s summary (logged) or error; refused while a reload is in flight."""
        if self._loading is not None:
            response.success = False
            response.message = "refused: a calibration reload is in flight; call again"
            return response
        self._flush()
        try:
            self.live, response.message = act()  # the compensator to go on with
            response.success = True
            logger(self).info(response.message)
        except StrainCompError as err:
            response.success, response.message = False, _one_line(err)
        except Exception as err:  # a fault of the program: answered and reported as one
            self._fault(f"~/{service}", err)
            response.success = False
            response.message = (f"internal error: {type(err).__name__}: {_one_line(err)} (a "
                                "bug: the node's log has the traceback)")
        return response

    @staticmethod
    def _paths(live: LiveCompensator) -> str:
        return ", ".join(sorted({str(i.calibration_path) for i in live.params.inputs}))

    def _reload(self) -> str:
        """Validate the calibration files, then build on a worker thread (docs/ros.md)."""
        current = self.live
        try:  # the sensors are the params', read-only: a file lacking one is refused here
            params = parse_values(self.flat, base_dir=self.base_dir)
        except (StrainCompError, OSError) as err:  # the files' fault (a bug: ``_answer``)
            self._refused_reload(_one_line(err))
            raise StrainCompError(self.calibration_status[1]) from None
        self._loading = threading.Thread(target=self._load, args=(current, params),
                                         name="reload_calibration", daemon=True)
        self.calibration_status = (OK, "loading " + self._paths(current))
        self._loading.start()
        return self.calibration_status[1]

    def _refused_reload(self, reason: str) -> None:
        self.calibration_status = (WARN, "reload refused, the old calibration keeps "
                                   "running: " + reason)
        logger(self).error(self.calibration_status[1])

    def _load(self, current: LiveCompensator, params: NodeParams) -> None:
        """Worker thread: ``successor`` (or the reason it failed) into ``_loaded``."""
        try:
            self._loaded = current.successor(params)
        except Exception as err:  # a worker thread: whatever ends the load is its reason
            self._loaded = _one_line(err)

    def _adopt(self) -> None:
        """Executor thread: swap a finished load in (``hand_over``) or log its refusal."""
        if self._loaded is None:
            return
        outcome, self._loaded = self._loaded, None
        if self._loading is not None:
            self._loading.join()  # it has left its result: done in a moment
        self._loading = None
        if isinstance(outcome, str):
            self._refused_reload(outcome)
            return
        self._flush()  # what arrived before the swap: the old calibration's
        self.live = self.live.hand_over(outcome)
        self.calibration_status = (OK, "reloaded " + self._paths(self.live))
        logger(self).info(self.calibration_status[1])
