"""Sensor names of an array message: a std_msgs/msg/Float64MultiArray's ``layout.dim[0].label``
holds them comma-separated (the node and the bag writer label their arrays so), and a
reader matches the values to its sensors by name (the node's input, the bag reader)."""

from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=64)
def label_order(label: str, names: tuple[str, ...]) -> np.ndarray | None:
    """The indices that put the values of an array labelled ``label`` in the order of
    ``names``: None when the label is empty or already that order; ValueError when it
    names other sensors. Cached: a stream repeats its label in every message, and parsing
    a label of 256 names costs about 60 us (the node reads up to 1 kHz)."""
    if not label.strip() or label == ",".join(names):
        return None
    given = [x.strip() for x in label.split(",")]
    if given == list(names):
        return None
    if sorted(given) != sorted(names):
        raise ValueError("the label names other sensors")
    at = {name: i for i, name in enumerate(given)}
    order = np.array([at[name] for name in names], dtype=np.intp)
    order.flags.writeable = False
    return order
