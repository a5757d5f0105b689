"""The compensated series as CSV: ``replay --csv`` and ``evaluate --csv`` (columns and cells:
docs/design.md, "JSON outputs"), written atomically; ``-`` writes to stdout."""

from __future__ import annotations

import io
import os
import sys
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager

import numpy as np

from strain_comp.base.samples import Status
from strain_comp.errors import OutputError
from strain_comp.io.atomic import AtomicFile
from strain_comp.io.recording import PieceAlign

COLUMNS = ("sensor", "time_s", "resistance_ohm", "estimate", "reference", "unit",
           "direction", "status")
_STATUS = {int(s): s.name.lower() for s in Status}


def _number(values: np.ndarray, missing: str = "nan") -> list[str]:
    """Shortest round-trip text of each value, ``missing`` for NaN."""
    return [missing if v != v else repr(v) for v in values.tolist()]


class SeriesCSV:
    """Rows of the module's columns, streamed into ``path`` (atomically) or stdout (``-``)."""

    def __init__(self, path: str | os.PathLike[str], *,
                 inputs: Iterable[str | os.PathLike[str]] = (), bag: bool = False) -> None:
        self.path = path
        self.file = None if str(path) == "-" else AtomicFile(path, inputs=inputs)
        self.bag = bag
        self.write(",".join((("bag",) if bag else ()) + COLUMNS) + "\n")

    def write(self, text: str) -> None:
        """Text as it is: a header, rows already formatted (``evaluate --jobs``'s parts)."""
        if self.file is None:
            sys.stdout.write(text)
        else:
            try:
                self.file.handle.write(text.encode("utf-8"))
            except OSError as err:  # a full disk, ``ulimit -f``: named, nothing left
                self.file.discard()
                raise OutputError(f"{self.path}: cannot write: {err.strerror or err}"
                                  ) from None

    def add(self, sensor: str, t: np.ndarray, resistance: np.ndarray, estimate: np.ndarray,
            reference: np.ndarray | None, direction: np.ndarray, status: np.ndarray, *,
            unit: str, bag: str = "") -> None:
        """Rows for one sensor's samples (arrays of equal length)."""
        ref = (np.full(np.asarray(t).size, np.nan) if reference is None
               else np.asarray(reference, np.float64))
        head = f"{_cell(bag)},{_cell(sensor)}" if self.bag else _cell(sensor)
        tail = _cell(unit)
        buf = io.StringIO()
        for row in zip(_number(np.asarray(t, np.float64)),
                       _number(np.asarray(resistance, np.float64)),
                       _number(np.asarray(estimate, np.float64)), _number(ref, ""),
                       np.asarray(direction).astype(int).tolist(),
                       np.asarray(status).astype(int).tolist(), strict=True):
            buf.write(f"{head},{row[0]},{row[1]},{row[2]},{row[3]},{tail},{row[4]},"
                      f"{_STATUS.get(row[5], str(row[5]))}\n")
        self.write(buf.getvalue())

    def close(self) -> None:
        if self.file is not None:
            self.file.commit()
        else:
            sys.stdout.flush()

    def discard(self) -> None:
        if self.file is not None:
            self.file.discard()


@contextmanager
def series_csv(path: str | os.PathLike[str] | None, *,
               inputs: Iterable[str | os.PathLike[str]] = (), bag: bool = False
               ) -> Iterator[SeriesCSV | None]:
    """A ``SeriesCSV`` for ``path``, committed at the block's end, discarded if it raises."""
    if path is None:
        yield None
        return
    table = SeriesCSV(path, inputs=inputs, bag=bag)
    try:
        yield table
    except BaseException:
        table.discard()
        raise
    table.close()


def _cell(text: str) -> str:
    """A text cell, quoted when it holds a comma, a quote or a line break."""
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


class PendingSeries:
    """One replayed sensor's rows waiting for their reference, aligned as ``evaluate``'s."""

    def __init__(self, name: str, unit: str) -> None:
        self.name = name
        self.unit = unit
        self.align = PieceAlign()
        self.columns: list[np.ndarray] = [np.empty(0)] * 5

    def add(self, t: np.ndarray, resistance: np.ndarray, estimate: np.ndarray,
            direction: np.ndarray, status: np.ndarray, ref_t: np.ndarray,
            ref_v: np.ndarray) -> None:
        """A piece's outputs and the piece's reference samples (may be empty)."""
        self.align.add(t, ref_t, ref_v)
        new: Sequence[np.ndarray] = (t, resistance, estimate, direction, status)
        self.columns = [np.concatenate((old, np.asarray(v, np.float64)))
                        for old, v in zip(self.columns, new, strict=True)]

    def flush(self, out: SeriesCSV, *, final: bool = False) -> None:
        """Write the rows whose reference is known (all of them with ``final``)."""
        if final:
            self.align.finish()
        n = int(np.searchsorted(self.columns[0], self.align.horizon(), side="right"))
        if n == 0:
            return
        t, r, est, direction, status = (c[:n] for c in self.columns)
        self.columns = [c[n:] for c in self.columns]
        out.add(self.name, t, r, est, self.align.take(t), direction, status, unit=self.unit)
