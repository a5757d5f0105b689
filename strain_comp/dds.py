"""A ROS-free live transport on Cyclone DDS, speaking ROS 2's wire format.

ROS 2 (rmw_cyclonedds) maps a topic ``/a/b`` to the DDS topic ``rt/a/b`` and a message
``std_msgs/msg/Float64`` to the IDL type ``std_msgs::msg::dds_::Float64_``; the types below
are those, field by field, so a ROS 2 node on the same domain talks to this one.

``run_dds_node(params_path)`` reads the same params file as the rclpy node, subscribes to
every resistance topic, feeds one ``LiveCompensator`` and publishes strain and direction
(and ``rt/diagnostics``). The time of a sample is its DDS *source timestamp* (what the
publisher stamped, so a replayed bag gives reproducible numbers); the output carries that
same source timestamp. Run it with ``python -m strain_comp.dds --params FILE``.
"""

# no `from __future__ import annotations`: cyclonedds reads the field types at run time
import argparse
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.core import (
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import byte, float64, int8, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from strain_comp.errors import StrainCompError
from strain_comp.live import LiveCompensator
from strain_comp.params import load_params


@dataclass
class Float64_(IdlStruct, typename="std_msgs::msg::dds_::Float64_"):
    data: float64


@dataclass
class Int8_(IdlStruct, typename="std_msgs::msg::dds_::Int8_"):
    data: int8


@dataclass
class MultiArrayDimension_(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str
    size: uint32
    stride: uint32


@dataclass
class MultiArrayLayout_(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension_]
    data_offset: uint32


@dataclass
class Float64MultiArray_(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout_
    data: sequence[float64]


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_
    frame_id: str


@dataclass
class KeyValue_(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: byte
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue_] = field(default_factory=list)


@dataclass
class DiagnosticArray_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header_
    status: sequence[DiagnosticStatus_]


def ros_topic(name: str) -> str:
    """The DDS topic name of a ROS 2 topic: ``/a/b`` -> ``rt/a/b``."""
    return "rt/" + name.lstrip("/")


def qos(*, reliable: bool) -> Qos:
    """Reliable keep-all (nothing dropped, for tests) or ROS's sensor-data profile."""
    if reliable:
        return Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll)
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))


def array_message(sensors: list[str] | tuple[str, ...], values: Any) -> Float64MultiArray_:
    """A Float64MultiArray whose one dimension names the sensors (as the bags do)."""
    k = len(sensors)
    layout = MultiArrayLayout_([MultiArrayDimension_(",".join(sensors), k, k)], 0)
    return Float64MultiArray_(layout, [float(v) for v in values])


class DdsNode:
    """Readers, writers and the engine of one DDS compensator."""

    def __init__(self, params_path: str, *, domain_id: int = 0,
                 reliable: bool = False) -> None:
        self.live = LiveCompensator(load_params(params_path))
        self.participant = DomainParticipant(domain_id)
        self.waitset = WaitSet(self.participant)
        self.readers: list[tuple[Any, Any, list[Any]]] = []
        sub_qos, pub_qos = qos(reliable=reliable), qos(reliable=True)
        for inp in self.live.params.inputs:
            kind = Float64MultiArray_ if inp.is_array else Float64_
            reader = DataReader(self.participant,
                                Topic(self.participant, ros_topic(inp.topic), kind), qos=sub_qos)
            out_types = ((Float64MultiArray_, Float64MultiArray_) if inp.is_array
                         else (Float64_, Int8_))
            writers = [DataWriter(self.participant, Topic(self.participant,
                                                          ros_topic(f"/{inp.name}/{what}"), t),
                                  qos=pub_qos)
                       for what, t in zip(("strain", "direction"), out_types, strict=True)]
            self.waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any
                                              | InstanceState.Any))
            self.readers.append((inp, reader, writers))
        self.diag_writer = DataWriter(self.participant, Topic(
            self.participant, ros_topic("/diagnostics"), DiagnosticArray_), qos=pub_qos)

    def poll(self, timeout: float) -> int:
        """Wait up to ``timeout`` s for input, handle every sample; how many were handled."""
        self.waitset.wait(duration(seconds=timeout))
        n = 0
        for inp, reader, writers in self.readers:
            for sample in reader.take(N=1000):
                n += 1
                try:
                    self._handle(inp, sample, writers)
                except Exception as err:  # a bad sample must never stop the node
                    self.live.n_errors += 1
                    if self.live.n_errors <= 10:
                        print(f"strain_comp.dds: {inp.topic}: sample not handled: {err}",
                              file=sys.stderr)
        return n

    def _handle(self, inp: Any, sample: Any, writers: list[DataWriter]) -> None:
        stamp = sample.sample_info.source_timestamp
        t = stamp * 1e-9
        if inp.is_array:
            out = self.live.on_array(inp.name, t, list(sample.data))
            if out is not None:
                writers[0].write(array_message(inp.sensors, out.strain), timestamp=stamp)
                writers[1].write(array_message(inp.sensors, out.direction), timestamp=stamp)
        else:
            out = self.live.on_sensor(inp.name, t, sample.data)
            if out is not None:
                writers[0].write(Float64_(out.strain), timestamp=stamp)
                writers[1].write(Int8_(out.direction), timestamp=stamp)

    def publish_diagnostics(self, now: float) -> None:
        """One DiagnosticArray of every sensor's health at clock time ``now`` [s]."""
        sec = int(now)
        self.diag_writer.write(DiagnosticArray_(
            Header_(Time_(sec, int((now - sec) * 1e9)), ""),
            [DiagnosticStatus_(level, name, message, "",
                               [KeyValue_(k, v) for k, v in values.items()])
             for name, level, message, values in self.live.diagnostics(now)]))


def play_bag(path: str, *, domain_id: int = 0, rate: float | None = None,
             wait_match: float = 10.0) -> int:
    """Publish a bag's ``/.../resistance`` topics over DDS, source timestamp = log time.

    A minimal ``ros2 bag play`` for machines without ROS: waits up to ``wait_match`` s for
    a subscriber on every topic, then writes every message (reliable, keep-all) in log-time
    order, as fast as possible (``rate`` None) or at ``rate`` x real time. Returns the count.
    """
    import numpy as np

    from strain_comp.bag import read_bag

    contents = read_bag(path)
    participant = DomainParticipant(domain_id)
    events = []
    writers = []
    for topic, series in contents.series.items():
        if not topic.endswith("/resistance"):
            continue
        is_array = series.values.ndim == 2
        writer = DataWriter(participant, Topic(participant, ros_topic(topic),
                                               Float64MultiArray_ if is_array else Float64_),
                            qos=qos(reliable=True))
        labels = contents.labels.get(topic, [])
        writers.append(writer)
        for i, ns in enumerate(np.round(series.t * 1e9).astype(np.int64).tolist()):
            events.append((ns, len(events), writer, series.values[i], is_array, labels))
    deadline = time.monotonic() + wait_match
    while any(not w.get_matched_subscriptions() for w in writers):
        if time.monotonic() > deadline:
            raise StrainCompError(f"play_bag: no subscriber within {wait_match} s")
        time.sleep(0.02)
    events.sort(key=lambda e: (e[0], e[1]))
    start_wall, start_ns = time.monotonic(), events[0][0] if events else 0
    for ns, _, writer, value, is_array, labels in events:
        if rate is not None:
            time.sleep(max(0.0, (ns - start_ns) * 1e-9 / rate - (time.monotonic() - start_wall)))
        sample = array_message(labels, value) if is_array else Float64_(float(value))
        writer.write(sample, timestamp=ns)
    return len(events)


def run_dds_node(params_path: str, *, duration: float | None = None, domain_id: int = 0,
                 reliable: bool = False, ready: Any = None) -> DdsNode:
    """Run until ``duration`` seconds have passed (forever if None) or Ctrl-C.

    ``ready`` (a callable) is called once the readers and writers exist.
    """
    node = DdsNode(params_path, domain_id=domain_id, reliable=reliable)
    if ready is not None:
        ready()
    period = node.live.tunables["diagnostics_period_s"]
    start = time.monotonic()
    next_diag = start + period
    try:
        while duration is None or time.monotonic() - start < duration:
            node.poll(min(0.1, period))
            if time.monotonic() >= next_diag:
                node.publish_diagnostics(time.time())
                next_diag += period
    except KeyboardInterrupt:
        pass
    return node


def main(argv: list[str] | None = None) -> int:
    """``python -m strain_comp.dds --params FILE [--duration S] [--domain N] [--reliable]``."""
    parser = argparse.ArgumentParser(prog="strain_comp.dds", description=__doc__.splitlines()[0])
    parser.add_argument("--params", help="node params YAML (ros__parameters): run the node")
    parser.add_argument("--play", metavar="BAG", help="instead, publish a bag's resistance")
    parser.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    parser.add_argument("--domain", type=int, default=0, help="DDS domain id")
    parser.add_argument("--reliable", action="store_true",
                        help="reliable keep-all inputs instead of best-effort sensor data")
    args = parser.parse_args(argv)
    if (args.params is None) == (args.play is None):
        parser.error("give exactly one of --params (run the node) or --play BAG")
    try:
        if args.play is not None:
            print(f"published {play_bag(args.play, domain_id=args.domain)} messages")
            return 0
        run_dds_node(args.params, duration=args.duration, domain_id=args.domain,
                     reliable=args.reliable, ready=lambda: print("ready", flush=True))
    except StrainCompError as err:
        print(f"strain_comp.dds: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
