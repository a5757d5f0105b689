"""A piece's writes held and written into the bag one log-time slice at a time.

Replay adds a piece's messages in a fixed order (outputs, /diagnostics, copied inputs),
which is also their order within one log time in the bag (``BagWriter`` merges by time,
stably). A long, sparse piece has thousands of /diagnostics ticks; to write them a batch
at a time, flushed in between, while keeping that order, the outputs and the copies are
held here as the arrays they were given (not yet encoded) and handed to the writer slice
by slice: each slice's outputs, its ticks, its copies, then a flush. Every held call is
made in every slice, empty ones included, so each topic is first named, and numbered, as
it would be written in one go."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from strain_comp.io.bag import BagWriter
from strain_comp.io.bag.schemas import Status

Call = Callable[[BagWriter, np.ndarray], None]
"""A held write: the writer and the mask of the messages to write now."""


class StagedWrites:
    """``BagWriter``'s ``write_*`` calls held (those replay makes) until ``write``."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, Call]] = []

    def _hold(self, t: npt.ArrayLike, call: Call) -> None:
        self.calls.append((np.round(np.asarray(t, np.float64).reshape(-1) * 1e9), call))

    def write(self, writer: BagWriter, lo: float, hi: float | None) -> None:
        """Write the messages of log times in [``lo``, ``hi``) [s], compared as the writer
        stores them (integer ns); ``hi`` None: every message not before ``lo`` (times the
        writer refuses included, so it still refuses them)."""
        lo_ns = np.round(lo * 1e9)
        hi_ns = None if hi is None else np.round(hi * 1e9)
        for t_ns, call in self.calls:
            call(writer, ~(t_ns < lo_ns) if hi_ns is None else (t_ns >= lo_ns) & (t_ns < hi_ns))

    def write_float64(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, m: w.write_float64(topic, t[m], v[m]))

    def write_int8(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, m: w.write_int8(topic, t[m], v[m]))

    def write_float64_array(self, topic: str, t: npt.ArrayLike, values2d: npt.ArrayLike,
                            labels: Sequence[str]) -> None:
        t, v = np.asarray(t), np.asarray(values2d)
        self._hold(t, lambda w, m: w.write_float64_array(topic, t[m], v[m], labels))

    def write_joint_state(self, topic: str, t: npt.ArrayLike, names: Sequence[str],
                          position: npt.ArrayLike) -> None:
        t, p = np.asarray(t), np.asarray(position)
        self._hold(t, lambda w, m: w.write_joint_state(topic, t[m], names, p[m]))

    def write_temperature(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, m: w.write_temperature(topic, t[m], v[m]))

    def write_diagnostics(self, t: npt.ArrayLike, statuses: Sequence[Sequence[Status]], *,
                          topic: str = "/diagnostics") -> None:
        t = np.asarray(t)
        self._hold(t, lambda w, m: w.write_diagnostics(
            t[m], [statuses[i] for i in np.flatnonzero(m).tolist()], topic=topic))
