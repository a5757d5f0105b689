"""Error metrics, in % strain: RMSE ([Electrolycra] eq. (5)), MAE, max error, R^2."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class ErrorStats:
    """Errors of an estimate against a reference over n finite sample pairs."""

    rmse: float
    mae: float
    max_abs: float
    r2: float
    n: int

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


Z_95 = 1.959963984540054
"""The two-sided 95 % point of the normal distribution: the band is +-Z_95 sigma."""


class ErrorAccumulator:
    """``error_stats`` over a series that arrives in pieces, in constant memory."""

    def __init__(self) -> None:
        self.n = 0
        self.sum_e2 = 0.0
        self.sum_abs = 0.0
        self.max_abs = 0.0
        self.mean = 0.0
        self.m2 = 0.0
        self.n_banded = 0
        self.n_inside = 0

    def add(self, estimate: npt.ArrayLike, reference: npt.ArrayLike,
            std: npt.ArrayLike | None = None) -> None:
        """Take in the finite pairs of one piece (with ``std``: how many lie within the band)."""
        piece = ErrorAccumulator()
        s_hat = np.asarray(estimate, dtype=np.float64)
        s = np.asarray(reference, dtype=np.float64)
        ok = np.isfinite(s_hat) & np.isfinite(s)
        if std is not None:
            sigma = np.asarray(std, np.float64)
            banded = ok & np.isfinite(sigma)
            piece.n_banded = int(banded.sum())
            piece.n_inside = int(np.sum(np.abs(s_hat[banded] - s[banded])
                                        <= Z_95 * sigma[banded]))
        if ok.any():
            s = s[ok]
            e = s_hat[ok] - s
            piece.n, piece.mean = int(ok.sum()), float(s.mean())
            piece.m2 = float(np.sum((s - piece.mean) ** 2))
            piece.sum_e2, piece.sum_abs = float(np.sum(e**2)), float(np.sum(np.abs(e)))
            piece.max_abs = float(np.max(np.abs(e)))
        self.merge(piece)

    def merge(self, other: ErrorAccumulator) -> None:
        """Take in everything ``other`` took in (the pairwise update of mean and m2)."""
        self.n_banded += other.n_banded
        self.n_inside += other.n_inside
        if not other.n:
            return
        if not self.n:
            banded, inside = self.n_banded, self.n_inside
            self.__dict__.update(vars(other))
            self.n_banded, self.n_inside = banded, inside
            return
        total = self.n + other.n
        delta = other.mean - self.mean
        self.m2 = self.m2 + other.m2 + delta * delta * (self.n * other.n / total)
        self.mean = self.mean + delta * (other.n / total)
        self.sum_e2 += other.sum_e2
        self.sum_abs += other.sum_abs
        self.max_abs = max(self.max_abs, other.max_abs)
        self.n = total

    def coverage_95(self) -> float | None:
        """The share of the pairs with a band that lie inside it (None: no band)."""
        return self.n_inside / self.n_banded if self.n_banded else None

    def stats(self) -> ErrorStats:
        if not self.n:
            nan = float("nan")
            return ErrorStats(nan, nan, nan, nan, 0)
        r2 = 1.0 - self.sum_e2 / self.m2 if self.m2 > 0 else float("nan")
        return ErrorStats(rmse=math.sqrt(self.sum_e2 / self.n), mae=self.sum_abs / self.n,
                          max_abs=self.max_abs, r2=r2, n=self.n)


def error_stats(estimate: npt.ArrayLike, reference: npt.ArrayLike) -> ErrorStats:
    """RMSE = sqrt(mean((S_hat - S)^2)) ([Electrolycra] eq. (5)), MAE, max |e| and R^2."""
    acc = ErrorAccumulator()
    acc.add(estimate, reference)
    return acc.stats()
