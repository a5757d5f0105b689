"""A std_msgs/Float64MultiArray's values for known sensors, by layout and by label."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from strain_comp.errors import InputError


def label_names(label: str) -> list[str]:
    """The sensor names of a ``dim[0].label`` (comma-separated; empty: none given)."""
    return [x.strip() for x in label.split(",")] if label.strip() else []


def array_values(data: Any, offset: int, sizes: list[int], k: int, label: str = "",
                 sensors: Sequence[str] | None = None) -> np.ndarray:
    """The k values of a Float64MultiArray: ``data[offset:offset + dim[0].size]``, in the
    order of ``sensors`` when ``label`` (``dim[0].label``, comma-separated sensor names, as
    the node publishes and ``replay`` reads) is given: values are matched by name. The
    node and the bag reader both read arrays through this one function.

    InputError with the reason when the layout does not describe k values inside ``data``
    or the label names other sensors.
    """
    values = np.asarray(data, dtype=np.float64)
    size = sizes[0] if sizes else values.size - offset
    if sizes and size != k:
        raise InputError(f"layout dim[0].size {size} != {k} sensors")
    if offset < 0 or offset + size > values.size:
        raise InputError(f"layout data_offset {offset} + size {size} exceeds the "
                         f"{values.size} values")
    if size != k:
        raise InputError(f"expected {k} values, got {size}")
    values = values[offset:offset + k]
    names = label_names(label)
    if names and sensors is not None and names != list(sensors):
        if sorted(names) != sorted(sensors):
            raise InputError(f"layout dim[0].label does not name the sensors "
                             f"{','.join(sensors)}")
        values = values[[names.index(s) for s in sensors]]
    return values
