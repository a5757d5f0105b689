"""A std_msgs/Float64MultiArray's values for known sensors, by layout and by the names of
``layout.dim[0].label`` (the array topics of docs/design.md, "Topics")."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from strain_comp.errors import InputError


def label_names(label: str) -> list[str]:
    """Split a ``dim[0].label`` into sensor names."""
    return [x.strip() for x in label.split(",")] if label.strip() else []


@functools.lru_cache(maxsize=64)
def label_order(label: str, names: tuple[str, ...]) -> np.ndarray | None:
    """The indices that put an array labelled ``label`` in the order of ``names``."""
    if not label.strip() or label == ",".join(names):
        return None
    given = label_names(label)
    if given == list(names):
        return None
    if sorted(given) != sorted(names):
        raise ValueError("the label names other sensors")
    at = {name: i for i, name in enumerate(given)}
    order = np.array([at[name] for name in names], dtype=np.intp)
    order.flags.writeable = False
    return order


def array_values(data: Any, offset: int, sizes: list[int], k: int, label: str = "",
                 sensors: Sequence[str] | None = None) -> np.ndarray:
    """The k values of a Float64MultiArray, ``data[offset:offset + dim[0].size]``."""
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
    if label and sensors is not None:
        try:
            order = label_order(label, tuple(sensors))
        except ValueError:
            raise InputError(f"layout dim[0].label does not name the sensors "
                             f"{','.join(sensors)}") from None
        if order is not None:
            values = values[order]
    return values
