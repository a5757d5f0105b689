"""Sample screening: which raw samples may reach a model's state.

A sample is bad when its resistance is not finite, is <= 0 ohm, or its time does not
move forward past the last good sample. Bad samples are counted and reported by the
caller; they never reach a model (docs/design.md, "Units and conventions").
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt


class SampleStatus(IntEnum):
    """Why a sample was accepted or rejected (the value is stored in replay output)."""

    GOOD = 0
    NOT_FINITE = 1
    NON_POSITIVE = 2
    TIME_NOT_INCREASING = 3


def classify(t: npt.ArrayLike, r: npt.ArrayLike, last_good_t: float = -np.inf) -> np.ndarray:
    """Status of every sample (uint8 SampleStatus values), judged in order.

    Time must exceed the time of the last *good* sample before it (``last_good_t`` for
    the first), so one sample from a looped bag or a sim-time reset rejects only the
    samples that go back, not the ones after the clock catches up again.
    """
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    status = np.zeros(t.shape, dtype=np.uint8)
    status[~np.isfinite(r) | ~np.isfinite(t)] = SampleStatus.NOT_FINITE
    status[(status == 0) & (r <= 0.0)] = SampleStatus.NON_POSITIVE
    candidate = status == 0
    # time must beat the running maximum of earlier good times
    t_good = np.where(candidate, t, -np.inf)
    previous_max = np.maximum.accumulate(np.concatenate(([last_good_t], t_good[:-1])))
    status[candidate & (t <= previous_max)] = SampleStatus.TIME_NOT_INCREASING
    return status


def good_mask(t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
    """True where a sample may be fed to a model."""
    return classify(t, r) == SampleStatus.GOOD
