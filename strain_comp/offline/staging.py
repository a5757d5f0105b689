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
"""A held write: the writer and the indices (ascending) of the messages to write now."""


class StagedWrites:
    """``BagWriter``'s ``write_*`` calls held (those replay makes) until ``write``."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray, Call]] = []
        """(times [ns] in order, the order of the messages by time, the write)."""

    def _hold(self, t: npt.ArrayLike, call: Call) -> None:
        t_ns = np.round(np.asarray(t, np.float64).reshape(-1) * 1e9)
        order = np.argsort(t_ns, kind="stable")  # NaN last
        self.calls.append((t_ns[order], order, call))

    def write(self, writer: BagWriter, lo: float, hi: float | None) -> None:
        """Write the messages of log times in [``lo``, ``hi``) [s], compared as the writer
        stores them (integer ns); ``hi`` None: every message not before ``lo`` (times the
        writer refuses included, so it still refuses them)."""
        lo_ns = np.round(lo * 1e9)
        hi_ns = None if hi is None else np.round(hi * 1e9)
        for t_ns, order, call in self.calls:  # a slice costs its messages, not the piece's
            a = int(np.searchsorted(t_ns, lo_ns, side="left"))
            b = t_ns.size if hi_ns is None else int(np.searchsorted(t_ns, hi_ns, side="left"))
            call(writer, np.sort(order[a:b]))

    def write_float64(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, i: w.write_float64(topic, t[i], v[i]))

    def write_int8(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, i: w.write_int8(topic, t[i], v[i]))

    def write_float64_array(self, topic: str, t: npt.ArrayLike, values2d: npt.ArrayLike,
                            labels: Sequence[str]) -> None:
        t, v = np.asarray(t), np.asarray(values2d)
        self._hold(t, lambda w, i: w.write_float64_array(topic, t[i], v[i], labels))

    def write_joint_state(self, topic: str, t: npt.ArrayLike, names: Sequence[str],
                          position: npt.ArrayLike) -> None:
        t, p = np.asarray(t), np.asarray(position)
        self._hold(t, lambda w, i: w.write_joint_state(topic, t[i], names, p[i]))

    def write_temperature(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        t, v = np.asarray(t), np.asarray(values)
        self._hold(t, lambda w, i: w.write_temperature(topic, t[i], v[i]))

    def write_diagnostics(self, t: npt.ArrayLike, statuses: Sequence[Sequence[Status]], *,
                          topic: str = "/diagnostics") -> None:
        t = np.asarray(t)
        self._hold(t, lambda w, i: w.write_diagnostics(
            t[i], [statuses[k] for k in i.tolist()], topic=topic))
