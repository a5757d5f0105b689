"""Reduction of long training runs before a model fit (docs/architecture.md): a zero-phase
low-pass, every f-th sample, plus the reversals and hold ends at their own samples. Lost:
motion faster than fs / (2f) and minor loops under ``REVERSAL_FRACTION``."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.models import Segment

FIT_SAMPLE_BUDGET = 250_000
"""Good training samples of one sensor above which the model is fitted on a reduction."""
REVERSAL_FRACTION = 0.01
"""Turning points with a swing of at least this share of the segment's span are kept."""
HOLD_RATE_FRACTION = 0.01
"""The reference is still where ``|dS/dt|`` is at most this share of its 99.5th percentile."""


def moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average, over the samples that exist near the ends."""
    n = x.size
    c: npt.NDArray[np.float64] = np.concatenate(([0.0], np.cumsum(x)))
    i = np.arange(n)
    lo: npt.NDArray[np.int_] = np.maximum(i - (width - 1) // 2, 0)
    hi: npt.NDArray[np.int_] = np.minimum(i + width // 2 + 1, n)
    return (c[hi] - c[lo]) / (hi - lo)


def lowpass(x: np.ndarray, factor: int) -> np.ndarray:
    """Two ``factor``-sample averages over ``x`` extended by its odd reflection at both ends."""
    k = min(factor, x.size - 1)
    if k < 1:
        return np.copy(x, order="C")
    padded = np.concatenate((2.0 * x[0] - x[k:0:-1], x, 2.0 * x[-1] - x[-2:-k - 2:-1]))
    smooth = moving_average(moving_average(padded, factor)[::-1], factor)[::-1]
    return smooth[k:k + x.size]


@njit
def turning_points(x: np.ndarray, swing: float) -> np.ndarray:
    """Indices of the alternating extremes of ``x`` at least ``swing`` apart."""
    n = x.size
    out = np.empty(n, np.int64)
    count = 0
    if n == 0:
        return out[:0]
    hi_i = 0
    lo_i = 0
    trend = 0  # +1 rising (tracking a peak), -1 falling (tracking a valley), 0 unknown
    for i in range(1, n):
        v = x[i]
        if trend >= 0 and v > x[hi_i]:
            hi_i = i
        if trend <= 0 and v < x[lo_i]:
            lo_i = i
        if trend == 0:
            if x[hi_i] - x[lo_i] >= swing:
                if hi_i > lo_i:  # rose from the valley: it is a turning point
                    out[count] = lo_i
                    count += 1
                    trend = 1
                    lo_i = i
                else:
                    out[count] = hi_i
                    count += 1
                    trend = -1
                    hi_i = i
        elif trend > 0 and x[hi_i] - v >= swing:
            out[count] = hi_i
            count += 1
            trend = -1
            lo_i = i
        elif trend < 0 and v - x[lo_i] >= swing:
            out[count] = lo_i
            count += 1
            trend = 1
            hi_i = i
    return out[:count]


def _reversals(x: np.ndarray, swing: float, limit: int) -> np.ndarray:
    """``turning_points(x, swing)``, the swing doubled until at most ``limit`` remain."""
    found = turning_points(x, swing)
    while found.size > limit:
        swing *= 2.0
        found = turning_points(x, swing)
    return found


def still_stretches(rate: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(start, stop) of every stretch where ``rate`` <= ``HOLD_RATE_FRACTION`` x ``scale``."""
    still = np.concatenate(([False], rate <= HOLD_RATE_FRACTION * scale, [False]))
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    return edges[::2], edges[1::2]


def hold_edges(t: np.ndarray, s: np.ndarray, min_length: int) -> np.ndarray:
    """First and last index of every still stretch of ``s`` at least ``min_length`` long."""
    rate = np.abs(np.gradient(s, t))
    scale = float(np.percentile(rate, 99.5))
    if scale <= 0.0:
        return np.empty(0, np.int64)
    start, stop = still_stretches(rate, scale)
    long_ = stop - start >= min_length
    return np.concatenate((start[long_], stop[long_] - 1))


def reduce_segment(seg: Segment, factor: int) -> Segment:
    """``seg`` reduced by ``factor`` (module docstring)."""
    n = seg.t.size
    if factor <= 1 or n <= 2 * factor:
        return seg
    r, s = lowpass(seg.r, factor), lowpass(seg.s, factor)
    keep = [np.arange(0, n, factor), np.array([n - 1])]
    for x in (r, s):
        span = float(np.ptp(x))
        if span > 0.0:
            keep.append(_reversals(x, REVERSAL_FRACTION * span, n // factor))
    keep.append(hold_edges(seg.t, s, 2 * factor))
    idx = np.unique(np.concatenate(keep))
    return Segment(seg.t[idx], r[idx], s[idx])


def reduce_segments(segments: Sequence[Segment], budget: int = FIT_SAMPLE_BUDGET
                    ) -> tuple[list[Segment], int]:
    """The segments a model is fitted on, and the factor that brings them within ``budget``."""
    total = sum(seg.t.size for seg in segments)
    if total <= budget:
        return list(segments), 1
    factor = math.ceil(total / budget)
    return [reduce_segment(seg, factor) for seg in segments], factor
