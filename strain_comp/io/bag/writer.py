"""MCAP bag writing: one time-ordered, chunked (zstd), fully indexed ros2-profile file
(docs/design.md, "Bags"); payloads of a fixed layout built as numpy rows of one template
(``strain_comp.io.cdr.RowEncoder``), the records written by ``strain_comp.io.bag.stream``."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from strain_comp.errors import BagError
from strain_comp.io import cdr
from strain_comp.io.atomic import check_output
from strain_comp.io.bag.schemas import CHUNK_SIZE, MAX_TIME_S, Status
from strain_comp.io.bag.stream import Pending, Stream, Topic
from strain_comp.io.cdr import RowEncoder


def _ns(t: npt.ArrayLike) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if not np.isfinite(t).all() or (t < 0).any():
        raise BagError("message times must be finite and >= 0 s")
    if (t > MAX_TIME_S).any():
        raise BagError(f"message times beyond {MAX_TIME_S} s (2038-01-19) cannot be stored "
                       f"(got {t.max():.6g} s; epoch milli- or nanoseconds?)")
    return np.round(t * 1e9).astype(np.int64)


class BagWriter:
    """Write a ros2-profile MCAP bag; use as a context manager."""

    def __init__(self, path: str | Path, *, chunk_size: int = CHUNK_SIZE,
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
        """A writer for ``path``; nothing is written before the first ``flush`` or the exit."""
        self.path = Path(path)
        self.chunk_size = chunk_size
        self.inputs = list(inputs)
        check_output(self.path, self.inputs)  # refused before anything is computed
        self._topics: dict[str, Topic] = {}
        self._pending = Pending()
        self._closed = False
        self._out: Stream | None = None

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Give up: delete the temporary file, leave ``path`` as it was."""
        self._closed = True
        if self._out is not None:
            self._out.abort()

    def _add(self, topic: str, kind: str, t_ns: np.ndarray,
             rows: np.ndarray | list[bytes] | tuple[np.ndarray, np.ndarray]) -> None:
        if self._closed:
            raise BagError(f"{self.path}: writer already closed")
        if not topic.startswith("/"):
            raise BagError(f"topic {topic!r} must start with '/'")
        entry = self._topics.setdefault(topic, Topic(len(self._topics) + 1, kind))
        if entry.type != kind:
            raise BagError(f"topic {topic} already holds {entry.type}, not {kind}")
        if isinstance(rows, tuple):
            blob, lengths = rows
        elif isinstance(rows, np.ndarray):
            lengths = np.full(rows.shape[0], rows.shape[1], np.int64)
            blob = rows.reshape(-1)
        else:
            lengths = np.array([len(r) for r in rows], np.int64)
            blob = np.frombuffer(b"".join(rows), dtype=np.uint8)
        if lengths.size != t_ns.size:
            raise BagError(f"{topic}: {t_ns.size} times but {lengths.size} values")
        p = self._pending
        p.t_ns.append(t_ns)
        p.chan.append(np.full(t_ns.size, entry.id, np.uint16))
        p.seq.append(np.arange(entry.n + 1, entry.n + 1 + t_ns.size, dtype=np.uint32))
        p.lengths.append(lengths)
        p.payloads.append(blob)
        p.nbytes += blob.size
        entry.n += t_ns.size

    def write_float64(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        """Add std_msgs/msg/Float64 messages, one per (t, value)."""
        v = np.asarray(values, dtype="<f8").reshape(-1)
        self._add(topic, "std_msgs/msg/Float64", _ns(t), RowEncoder.scalar("<f8").rows(v))

    def write_int8(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        """Add std_msgs/msg/Int8 messages, one per (t, value)."""
        v = np.asarray(values)
        if v.size and (np.abs(v) > 128).any():
            raise BagError(f"{topic}: Int8 values out of range")
        v = v.astype(np.int8).reshape(-1)
        self._add(topic, "std_msgs/msg/Int8", _ns(t), RowEncoder.scalar("i1").rows(v))

    def write_float64_array(self, topic: str, t: npt.ArrayLike, values2d: npt.ArrayLike,
                            labels: Sequence[str]) -> None:
        """Add std_msgs/msg/Float64MultiArray messages, one per row."""
        v = np.asarray(values2d, dtype="<f8")
        if v.ndim != 2 or v.shape[1] != len(labels):
            raise BagError(f"{topic}: values must be (n, {len(labels)}) for {len(labels)} labels")
        if any("," in x for x in labels):
            raise BagError(f"{topic}: sensor labels must not contain commas")
        self._add(topic, "std_msgs/msg/Float64MultiArray", _ns(t),
                  RowEncoder.vector(labels).rows(v))

    def write_joint_state(self, topic: str, t: npt.ArrayLike, names: Sequence[str],
                          position: npt.ArrayLike) -> None:
        """Add sensor_msgs/msg/JointState messages, one per row of ``position``, stamped
        with the log time."""
        t_ns = _ns(t)  # refuses stamps past int32 seconds
        p = np.asarray(position, dtype="<f8").reshape(t_ns.size, len(names))
        self._add(topic, "sensor_msgs/msg/JointState", t_ns,
                  RowEncoder.joint_state(names).rows(p, t_ns))

    def write_temperature(self, topic: str, t: npt.ArrayLike, values: npt.ArrayLike) -> None:
        """Add sensor_msgs/msg/Temperature messages, header stamp = log time."""
        t_ns = _ns(t)
        v = np.asarray(values, dtype="<f8").reshape(-1)
        if v.size != t_ns.size:
            raise BagError(f"{topic}: {t_ns.size} times but {v.size} values")
        self._add(topic, "sensor_msgs/msg/Temperature", t_ns,
                  RowEncoder.temperature().rows(v, t_ns))

    def write_diagnostics(self, t: npt.ArrayLike, statuses: Sequence[Sequence[Status]], *,
                          topic: str = "/diagnostics") -> None:
        """Add diagnostic_msgs/msg/DiagnosticArray messages, one per time."""
        t_ns = _ns(t)
        rows = []
        for i, st in zip(range(t_ns.size), statuses, strict=False):
            blob, _ = cdr.diagnostic_arrays(t_ns[i:i + 1], "", [
                (np.array([level], np.uint8), name, message, "",
                 [(str(a), str(b)) for a, b in values.items()])
                for name, level, message, values in st])
            rows.append(blob.tobytes())
        self._add(topic, "diagnostic_msgs/msg/DiagnosticArray", t_ns, rows)

    def write_diagnostic_payloads(self, t: npt.ArrayLike, blob: np.ndarray,
                                  lengths: np.ndarray, *, topic: str = "/diagnostics") -> None:
        """Add DiagnosticArray messages already encoded (``diagnostic_arrays``)."""
        self._add(topic, "diagnostic_msgs/msg/DiagnosticArray", _ns(t), (blob, lengths))

    def flush(self, *, before: float | None = None) -> None:
        """Write the buffered messages as complete chunks; the rest stays buffered."""
        if self._closed:
            raise BagError(f"{self.path}: writer already closed")
        self._write_pending(final=False, before=None if before is None else
                            round(before * 1e9))

    def close(self) -> None:
        """Write the remaining messages, the summary and the footer (once); if that fails
        (a full disk, ``ulimit -f``), the temporary file is deleted (``abort``)."""
        if self._closed:
            return
        try:
            self._write_pending(final=True)
        except BaseException:
            self.abort()
            raise
        self._closed = True
        assert self._out is not None
        self._out.finish()

    def _write_pending(self, *, final: bool, before: int | None = None) -> None:
        if self._out is None:
            self._out = Stream(self.path, self.inputs, self.chunk_size)
        p = self._pending
        self._pending = Pending()
        if not p.t_ns:
            return
        rest = self._out.write_messages(self._topics, p, final=final, before=before)
        if rest is not None:
            self._pending = rest
