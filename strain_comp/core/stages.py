"""The per-sample stages every path runs, one scalar kernel each, lifted over a batch for
``Engine.run`` (docs/models.md, "The engine's per-sample path")."""

from __future__ import annotations

import numpy as np

from strain_comp._numba import njit
from strain_comp.base import samples as sc
from strain_comp.base.samples import screen_all

RANGE_COLUMNS = ("r_lo", "r_hi", "s_lo", "s_hi", "slope_lo", "slope_hi", "reach_lo",
                 "reach_hi", "saturate")
"""Columns of a sensor's range row (``range_policy.SensorRange``'s fields)."""
R_LO, R_HI, S_LO, S_HI, SLOPE_LO, SLOPE_HI, REACH_LO, REACH_HI, SATURATE = \
    range(len(RANGE_COLUMNS))


@njit
def clamp(value: float, lo: float, hi: float) -> float:
    """``np.clip`` of one value (NaN stays NaN)."""
    return value if value != value else min(max(value, lo), hi)


@njit
def model_read(ohm: float, row: np.ndarray) -> float:
    """The resistance the model reads: ``ohm``, clipped to the range when ``saturate``."""
    return clamp(ohm, row[R_LO], row[R_HI]) if row[SATURATE] else ohm


@njit
def saturate_all(ohm: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``model_read`` over a batch."""
    out = np.empty(ohm.size)
    for i in range(ohm.size):
        out[i] = model_read(ohm[i], row)
    return out


@njit
def bound(ohm: float, strain: float, row: np.ndarray) -> float:
    """The range stage: clamped, plus the slope times the resistance beyond, within reach."""
    strain = clamp(strain, row[S_LO], row[S_HI])
    if ohm > row[R_HI]:
        strain += row[SLOPE_HI] * (ohm - row[R_HI])
    elif ohm < row[R_LO]:
        strain += row[SLOPE_LO] * (ohm - row[R_LO])
    return clamp(strain, row[REACH_LO], row[REACH_HI])


@njit
def bound_all(ohm: np.ndarray, strain: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``bound`` over a batch."""
    out = np.empty(strain.size)
    for i in range(strain.size):
        out[i] = bound(ohm[i], strain[i], row)
    return out


@njit
def screen_batch(t: np.ndarray, ohm: np.ndarray, forced: np.ndarray, last_good_t: float,
                 r_short: float, r_open: float, r_lo: float, r_hi: float, gap: float
                 ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """``screen_all``, the used samples' indices and where among them a gap reset falls."""
    status, reset, last = screen_all(t, ohm, forced, last_good_t, r_short, r_open, r_lo,
                                     r_hi, gap)
    idx = np.empty(t.size, np.int64)
    starts = np.empty(t.size, np.int64)
    m = 0
    n_starts = 0
    for i in range(t.size):
        if sc.USED_CODE[status[i]]:
            if reset[i]:
                starts[n_starts] = m
                n_starts += 1
            idx[m] = i
            m += 1
    return status, reset, last, idx[:m], starts[:n_starts]


@njit
def hold(status: np.ndarray, reset: np.ndarray, idx: np.ndarray, strain_used: np.ndarray,
         dir_used: np.ndarray, strain: float, direction: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The hold stage over a batch: each sample shows the latest used sample's output."""
    n = status.size
    out_s = np.empty(n)
    out_d = np.empty(n, np.int8)
    oor = np.empty(n, np.bool_)
    counts = np.zeros(sc.OUT_OF_RANGE + 2, np.int64)
    j = 0
    for i in range(n):
        counts[status[i]] += 1
        oor[i] = status[i] == sc.OUT_OF_RANGE
        if reset[i]:
            counts[counts.size - 1] += 1
        if j < idx.size and idx[j] == i:
            strain = strain_used[j]
            direction = dir_used[j]
            j += 1
        out_s[i] = strain
        out_d[i] = direction
    return out_s, out_d, oor, counts


