"""``strain-comp play``: publish a bag's messages over ROS 2 at their recorded times, or in
lockstep with the node's answers (docs/architecture.md, "Inside the node")."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from strain_comp.errors import BagError
from strain_comp.io.bag.reader import RawMessage, raw_messages
from strain_comp.io.bag.schemas import norm_type

if TYPE_CHECKING:
    from rclpy.executors import Executor

LOCKSTEP_TIMEOUT_S = 1.0
MATCH_S = 2.0
"""How long play waits for the other topics' subscribers once one topic has one [s]."""


PLAYABLE = ("std_msgs/msg/Float64", "std_msgs/msg/Float32", "std_msgs/msg/Int8",
            "std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/Temperature",
            "diagnostic_msgs/msg/DiagnosticArray")
"""The message types ``play`` publishes (and a lockstep topic may have)."""


def message_class(type_name: str) -> type | None:
    """The Python class of one of the ``PLAYABLE`` types."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Temperature
    from std_msgs.msg import Float32, Float64, Float64MultiArray, Int8

    classes = dict(zip(PLAYABLE, (Float64, Float32, Int8, Float64MultiArray, Temperature,
                                  DiagnosticArray), strict=True))
    return classes.get(norm_type(type_name))


def spin_until(executor: Executor, ready: Callable[..., bool], timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.01)
    return True


def play(path: str | Path, *, clock: bool = False, rate: float = 1.0,
         topics: list[str] | None = None, lockstep: str | None = None,
         wait_s: float = 10.0) -> int:
    """Play the bag; rclpy must be initialised."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    from strain_comp.ros.rclpy_typed import destroy

    messages, problems = raw_messages(path, topics)  # the bag reader's walk and budgets
    for problem in problems:
        print(f"play: {problem}", file=sys.stderr)
    if not messages:
        raise BagError(f"{path}: no CDR messages" + (f" on {', '.join(topics)}" if topics else ""))
    kinds = {name: message_class(name) for name in {m.type_name for m in messages}}
    skipped = sorted(name for name, kind in kinds.items() if kind is None)
    if skipped:
        n = sum(1 for m in messages if kinds[m.type_name] is None)
        print(f"play: {n} messages of types not played: {', '.join(skipped)}"[:500],
              file=sys.stderr)
        messages = [m for m in messages if kinds[m.type_name] is not None]
        if not messages:
            raise BagError(f"{path}: no message of a type play publishes "
                           f"({', '.join(PLAYABLE)})")
    node = Node("strain_comp_player")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    pubs = {}
    for m in messages:
        if m.topic not in pubs:
            pubs[m.topic] = node.create_publisher(kinds[m.type_name], m.topic, 100)
    clock_pub = node.create_publisher(Clock, "/clock", 100) if clock else None
    answers = [0]
    try:
        if lockstep is not None:
            if not spin_until(executor, lambda: lockstep in dict(node.get_topic_names_and_types()),
                         wait_s):
                raise BagError(f"lockstep topic {lockstep} does not appear within {wait_s} s")
            kind = message_class(dict(node.get_topic_names_and_types())[lockstep][0])
            if kind is None:
                raise BagError(f"lockstep topic {lockstep} has a type play does not read")
            node.create_subscription(kind, lockstep,
                                     lambda _msg: answers.__setitem__(0, answers[0] + 1), 100)
            if not spin_until(executor, lambda: node.count_publishers(lockstep) > 0, wait_s):
                raise BagError(f"no publisher on {lockstep} within {wait_s} s")
        messages = _subscribed(executor, pubs, messages, wait_s)
        time.sleep(0.2)  # let the subscribers' matching of the publishers complete too
        t0_ns, start = messages[0].log_time_ns, time.monotonic()
        for m in messages:
            if lockstep is None and rate > 0:
                delay = start + (m.log_time_ns - t0_ns) * 1e-9 / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            if clock_pub is not None:
                stamp = Clock()
                stamp.clock.sec, stamp.clock.nanosec = divmod(m.log_time_ns, 1_000_000_000)
                clock_pub.publish(stamp)
            expected = answers[0] + 1
            pubs[m.topic].publish(m.data)
            if lockstep is not None:
                spin_until(executor, lambda e=expected: answers[0] >= e, LOCKSTEP_TIMEOUT_S)
    finally:
        executor.shutdown(timeout_sec=0.5)
        destroy(node)
    return len(messages)


def _subscribed(executor: Executor, pubs: dict[str, Any], messages: list[RawMessage],
                wait_s: float) -> list[RawMessage]:
    """The messages on topics with a subscriber (the others named on stderr), within wait_s."""
    def heard() -> set[str]:
        return {topic for topic, pub in pubs.items() if pub.get_subscription_count() > 0}

    if not spin_until(executor, lambda: bool(heard()), wait_s):
        raise BagError(f"no subscriber on {', '.join(pubs)} within {wait_s} s (is the node "
                       "running, in this ROS_DOMAIN_ID?)")
    spin_until(executor, lambda: len(heard()) == len(pubs), MATCH_S)
    played = heard()
    unheard = [topic for topic in pubs if topic not in played]
    if unheard:
        n = sum(1 for m in messages if m.topic not in played)
        named = ", ".join(unheard[:5]) + (f" and {len(unheard) - 5} more" if unheard[5:] else "")
        print(f"play: no subscriber on {named}: {n} messages not played (--topic TOPIC "
              "chooses the topics to play)", file=sys.stderr)
    return [m for m in messages if m.topic in played]


def main(path: str | Path, **options: Any) -> int:
    """``strain-comp play``: init rclpy, play, shut down."""
    import rclpy
    from rclpy.utilities import try_shutdown

    rclpy.init()
    try:
        return play(path, **options)
    finally:
        try_shutdown()
