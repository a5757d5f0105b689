"""Reduction of long training runs before a model fit: anti-aliased decimation that keeps
the reversals and the holds.

A model fit costs time and memory in proportion to its training samples (APL's QP builds a
samples x (N + M + 2) matrix per grid point), and a 1e7-sample run holds far more samples
than its motion needs: a strain protocol moves at a few Hz at most. Above
``FIT_SAMPLE_BUDGET`` good samples, ``fit_sensor`` fits the model on a reduction of every
segment by the integer factor ``f = ceil(samples / budget)``; everything else the
calibration holds (normalisation, valid range, direction detector, rest resistance, the
fit error ``fit_rmse``) is still computed on the full data. Below the budget nothing
changes: the fit sees every sample.

Per segment (``reduce_segment``):

1. **Anti-aliasing**: R and S are low-passed by a centred triangular filter of 2f - 1
   taps (two passes of an f-sample moving average; zero phase, so no lag enters the
   hysteresis; zero gain at multiples of the new sample rate fs / f, side lobes below
   -26 dB; at the segment ends the signal is extended by its odd reflection, so a ramp
   stays exact there).
2. **Decimation**: every f-th filtered sample, plus the last.
3. **Reversals**: every turning point of the filtered S and of the filtered R whose swing
   to the next one is at least ``REVERSAL_FRACTION`` of the segment's span (a peak-valley
   scan with that hysteresis, so noise does not count) is kept at its own sample: the
   extremes that set a hysteresis model's memory survive exactly where they were. At most
   as many as the decimated samples: for a signal noisier than that, the swing doubles
   until they fit, so a reduction never holds more than about 4 n / f samples.
4. **Holds**: the first and last sample of every stretch of at least 2f samples where the
   filtered S is still (``|dS/dt|`` at most ``HOLD_RATE_FRACTION`` of the segment's
   99.5th-percentile rate, the rule ``deadzone.find_hold`` uses), so a hold starts and ends
   where it did; inside it the decimated samples carry its relaxation.

Kept samples are the union, in time order, with the filtered values. What a reduction
loses: motion faster than fs / (2f) and minor loops under ``REVERSAL_FRACTION`` of the span
between two decimated samples; a rate-dependent model's sigma grid follows the reduced
sample interval (``APL.fit``: up to 0.2 / interval).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.models import Segment

FIT_SAMPLE_BUDGET = 250_000
"""Good training samples of one sensor above which the model is fitted on a reduction
(each measured recording in ``../shared/data/measured`` holds under 70 000)."""
REVERSAL_FRACTION = 0.01
"""Turning points with a swing of at least this share of the segment's span are kept."""
HOLD_RATE_FRACTION = 0.01
"""The reference is still where ``|dS/dt|`` is at most this share of its 99.5th percentile."""


def moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average (odd widths centred exactly, even ones half a sample late),
    over the samples that exist near the ends."""
    n = x.size
    c: npt.NDArray[np.float64] = np.concatenate(([0.0], np.cumsum(x)))
    i = np.arange(n)
    lo: npt.NDArray[np.int_] = np.maximum(i - (width - 1) // 2, 0)
    hi: npt.NDArray[np.int_] = np.minimum(i + width // 2 + 1, n)
    return (c[hi] - c[lo]) / (hi - lo)


def lowpass(x: np.ndarray, factor: int) -> np.ndarray:
    """The triangular anti-aliasing filter of step 1: two ``factor``-sample averages, over
    ``x`` extended by its odd reflection at both ends (a ramp stays exact up to the end)."""
    k = min(factor, x.size - 1)
    if k < 1:
        return np.copy(x, order="C")
    padded = np.concatenate((2.0 * x[0] - x[k:0:-1], x, 2.0 * x[-1] - x[-2:-k - 2:-1]))
    smooth = moving_average(moving_average(padded, factor)[::-1], factor)[::-1]
    return smooth[k:k + x.size]


@njit
def turning_points(x: np.ndarray, swing: float) -> np.ndarray:
    """Indices of the alternating extremes of ``x`` that differ from their neighbours by at
    least ``swing`` (peak-valley scan with hysteresis ``swing``)."""
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
    """``turning_points(x, swing)``, the swing doubled until at most ``limit`` remain (a
    signal noisier than the swing would otherwise keep most of its samples)."""
    found = turning_points(x, swing)
    while found.size > limit:
        swing *= 2.0
        found = turning_points(x, swing)
    return found


def hold_edges(t: np.ndarray, s: np.ndarray, min_length: int) -> np.ndarray:
    """First and last index of every still stretch of ``s`` (still: ``|dS/dt|`` <=
    ``HOLD_RATE_FRACTION`` x its 99.5th percentile)."""
    rate = np.abs(np.gradient(s, t))
    scale = float(np.percentile(rate, 99.5))
    if scale <= 0.0:
        return np.empty(0, np.int64)
    still = np.concatenate(([False], rate <= HOLD_RATE_FRACTION * scale, [False]))
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    start, stop = edges[::2], edges[1::2]
    long_ = stop - start >= min_length
    return np.concatenate((start[long_], stop[long_] - 1))


def reduce_segment(seg: Segment, factor: int) -> Segment:
    """``seg`` reduced by ``factor`` (module docstring, steps 1-4)."""
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


def reduction_factor(segments: Sequence[Segment], budget: int = FIT_SAMPLE_BUDGET) -> int:
    """The factor that brings the segments within ``budget``."""
    total = sum(seg.t.size for seg in segments)
    return 1 if total <= budget else math.ceil(total / budget)


def reduce_segments(segments: Sequence[Segment], budget: int = FIT_SAMPLE_BUDGET
                    ) -> tuple[list[Segment], int]:
    """The segments a model is fitted on."""
    factor = reduction_factor(segments, budget)
    if factor == 1:
        return list(segments), 1
    return [reduce_segment(seg, factor) for seg in segments], factor
