"""What a message carries, checked before use: a scalar's value, a Float64MultiArray's
layout. A message that fails is refused for what it carries (``InputError``), never because
the node raised (docs/ros.md). Duck-typed, no ROS import: the node's messages, or any object
with their fields."""

from __future__ import annotations

from typing import Any

from strain_comp.errors import InputError


def sensor_value(msg: Any, field: str = "data") -> float:
    """A scalar message's value (``std_msgs/Float64.data``, ``Temperature.temperature``). NaN
    and inf pass: the engine screens them."""
    value = getattr(msg, field, None)
    if isinstance(value, bool) or not isinstance(value, (float, int)):
        raise InputError(f"{field} is not a number ({type(value).__name__})")
    return float(value)


def array_layout(msg: Any) -> tuple[Any, int, list[int], str]:
    """A Float64MultiArray's fields, each checked for its type. The sizes and the offset are
    then checked against the sensors by ``array_values``."""
    layout = getattr(msg, "layout", None)
    data = getattr(msg, "data", None)
    offset = getattr(layout, "data_offset", None)
    dims = getattr(layout, "dim", None)
    if data is None or isinstance(data, (str, bytes)) or not hasattr(data, "__len__"):
        raise InputError("data is not a sequence of numbers")
    if isinstance(offset, bool) or not isinstance(offset, int):
        raise InputError("layout data_offset is not an integer")
    if dims is None or not hasattr(dims, "__iter__"):
        raise InputError("layout dim is not a list")
    sizes = [getattr(d, "size", None) for d in dims]
    if any(isinstance(s, bool) or not isinstance(s, int) for s in sizes):
        raise InputError("layout dim[*].size is not an integer")
    label = getattr(dims[0], "label", "") if sizes else ""
    if not isinstance(label, str):
        raise InputError("layout dim[0].label is not a string")
    return data, offset, [int(s) for s in sizes if s is not None], label
