"""The node's inputs read in bulk from their serialised bytes (CDR), as its outputs are
built (``strain_comp.io.cdr.RowEncoder``): a message built in Python and converted by rclpy
costs tens of microseconds (docs/results.md, "The node's CPU")."""

from __future__ import annotations

import numpy as np

from strain_comp.io import cdr


class RowDecoder:
    """The sensors' values of serialised messages of the layout ``learn`` checked, in bulk."""

    def __init__(self) -> None:
        self._head = b""
        self._size = -1
        self._columns = np.zeros(0, np.intp)

    def learn(self, raw: bytes, n_values: int, columns: np.ndarray, values: np.ndarray
              ) -> None:
        """Learn ``raw``'s layout unless its ``values`` do not read back (big-endian, padded)."""
        if raw[:2] == cdr.ENCAPSULATION[:2] and len(raw) >= 8 * n_values:
            self._head, self._size = raw[:len(raw) - 8 * n_values], len(raw)
            self._columns = columns
            if not np.array_equal(self.rows([raw])[0], values, equal_nan=True):
                self._size = -1  # fits nothing

    def fits(self, raw: bytes) -> bool:
        return len(raw) == self._size and raw.startswith(self._head)

    def rows(self, raws: list[bytes]) -> np.ndarray:
        """The values of messages that fit, one row per message."""
        values = np.ndarray((len(raws), (self._size - len(self._head)) // 8), "<f8",
                            b"".join(raws), len(self._head), (self._size, 8))
        rows: np.ndarray = values[:, self._columns]
        return rows
