"""Typed views of the rclpy calls that rclpy 7 (ROS 2 Jazzy) leaves unannotated, so ros/
type-checks under strict mypy: each states the type the call has at run time; the call
itself is rclpy's own."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from rclpy.node import Node
from rclpy.parameter import Parameter


class Logger(Protocol):
    """The methods of rclpy's ``RcutilsLogger`` the package calls."""

    def info(self, message: str, *, throttle_duration_sec: float = ...) -> bool: ...

    def warning(self, message: str, *, throttle_duration_sec: float = ...) -> bool: ...

    def error(self, message: str, *, throttle_duration_sec: float = ...) -> bool: ...


def logger(node: Node) -> Logger:
    """``node.get_logger()``: the node's ``RcutilsLogger``."""
    get: Callable[[], Logger] = node.get_logger
    return get()


def destroy(node: Node) -> None:
    """``node.destroy_node()``: frees its publishers, subscriptions, services and timers."""
    destroy_node: Callable[[], None] = node.destroy_node
    destroy_node()


def parameter(name: str, type_: Parameter.Type, value: object) -> Parameter:
    make: Callable[[str, Parameter.Type, object], Parameter] = Parameter
    return make(name, type_, value)
