"""Sample screening: the one rule (``screen_one``) deciding which raw samples reach a model,
in the engine and the fit, and what each status means (docs/models.md, "Screening").
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit


class Status(IntEnum):
    """Per-sample status (the ``/NAME/status`` value in replay output)."""

    GOOD = 0
    NOT_FINITE = 1
    NON_POSITIVE = 2
    TIME_NOT_INCREASING = 3
    OPEN_CIRCUIT = 4
    SHORT_CIRCUIT = 5
    GAP_RESET = 6
    OUT_OF_RANGE = 7


DEFAULT_GAP_RESET = 5.0  # [s]: a longer jump between good samples resets the state
GAP_INTERVALS = 10.0  # for a slow instrument the gap is at least this many sample intervals


def gap_for(sample_interval: float | None, gap: float = DEFAULT_GAP_RESET) -> float:
    """The gap of a sensor: ``gap``, or ``GAP_INTERVALS`` intervals when that is longer."""
    return gap if sample_interval is None else max(gap, GAP_INTERVALS * sample_interval)

# the codes as plain ints, for the numba kernels (compile-time constants there)
GOOD: Final = int(Status.GOOD)
NOT_FINITE: Final = int(Status.NOT_FINITE)
NON_POSITIVE: Final = int(Status.NON_POSITIVE)
TIME_NOT_INCREASING: Final = int(Status.TIME_NOT_INCREASING)
OPEN_CIRCUIT: Final = int(Status.OPEN_CIRCUIT)
SHORT_CIRCUIT: Final = int(Status.SHORT_CIRCUIT)
GAP_RESET: Final = int(Status.GAP_RESET)
OUT_OF_RANGE: Final = int(Status.OUT_OF_RANGE)

STATUS_RULES: Final[dict[Status, tuple[bool, str | None]]] = {
    Status.GOOD: (True, None),
    Status.NOT_FINITE: (False, "n_nan"),
    Status.NON_POSITIVE: (False, "n_non_positive"),
    Status.TIME_NOT_INCREASING: (False, "n_time_backwards"),
    Status.OPEN_CIRCUIT: (False, "n_open"),
    Status.SHORT_CIRCUIT: (False, "n_short"),
    Status.GAP_RESET: (True, None),
    Status.OUT_OF_RANGE: (True, "n_out_of_range"),
}
"""Per status: is the sample fed to the model (``n_good``), and its health counter besides."""

USED: Final = frozenset(s for s, (used, _) in STATUS_RULES.items() if used)
# USED as a table by status code, for arrays and numba kernels (a constant there)
USED_CODE: Final[npt.NDArray[np.bool_]] = np.array(
    [STATUS_RULES[Status(c)][0] for c in range(len(Status))], dtype=np.bool_)


@njit
def screen_one(t: float, r: float, forced: int, last_good_t: float, r_short: float,
               r_open: float, r_lo: float, r_hi: float, gap: float) -> tuple[int, bool]:
    """Screen one sample (docs/models.md, "Screening")."""
    if not (math.isfinite(t) and math.isfinite(r)):
        return NOT_FINITE if forced == GOOD else forced, False
    if forced != GOOD:
        return forced, False
    if r <= 0.0:
        return NON_POSITIVE, False
    if r > r_open:
        return OPEN_CIRCUIT, False
    if r < r_short:
        return SHORT_CIRCUIT, False
    reset = False
    if last_good_t > -math.inf:
        if t <= last_good_t - gap or t - last_good_t > gap:
            reset = True
        elif t <= last_good_t:
            return TIME_NOT_INCREASING, False
    if r < r_lo or r > r_hi:
        return OUT_OF_RANGE, reset
    return (GAP_RESET if reset else GOOD), reset


@njit
def screen_all(t: np.ndarray, r: np.ndarray, forced: np.ndarray, last_good_t: float,
               r_short: float, r_open: float, r_lo: float, r_hi: float,
               gap: float) -> tuple[np.ndarray, np.ndarray, float]:
    n = t.size
    status = np.empty(n, dtype=np.int8)
    reset = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        code, rst = screen_one(t[i], r[i], forced[i], last_good_t, r_short, r_open,
                               r_lo, r_hi, gap)
        status[i] = code
        reset[i] = rst
        if USED_CODE[code]:
            last_good_t = t[i]
    return status, reset, last_good_t


def classify(t: npt.ArrayLike, r: npt.ArrayLike, *, gap: float = DEFAULT_GAP_RESET
             ) -> np.ndarray:
    """Status codes by ``screen_one`` with no resistance range (what the fit can know)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    forced = np.zeros(t.shape, dtype=np.int8)
    status, _, _ = screen_all(t, r, forced, -math.inf, 0.0, math.inf, -math.inf, math.inf,
                              float(gap))
    return status


def good_mask(t: npt.ArrayLike, r: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Where a sample may be fed to a model, judged by ``classify``."""
    return np.take(USED_CODE, classify(t, r))


def used_mask(status: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Where a sample was fed to the model."""
    return np.take(USED_CODE, np.asarray(status))
