"""The out-of-range policy: where a sample is flagged, an open circuit or a short, and what
strain a resistance beyond the valid range gives (docs/design.md, "--out-of-range")."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from strain_comp.base.compensator import Compensator
from strain_comp.core.calibration import SensorCalibration, ValidRange
from strain_comp.core.stages import RANGE_COLUMNS

OUT_OF_RANGE_MODES = ("clamp", "extrapolate", "extend")
"""Strain of a sample beyond the valid resistance range (docs/design.md, "--out-of-range")."""
DEFAULT_OUT_OF_RANGE = "extend"
"""Chosen on the generalisation benchmark (docs/results.md, "Out of range")."""


# The out-of-range rule's numbers. docs/results.md gives what keeps each: the largest
# change of a benchmark case with the number set neutral, or the fault test it guards.
OPEN_FACTOR = 100.0  # R above this x r_hi is an open circuit (a test_reliability fault test)
SHORT_FACTOR = 0.01  # 0 < R below this x r_lo is a short circuit (the same fault test)
MARGIN = 0.05  # share of the span widening the valid ranges and the fit's (0: a case 66 %)
EXTEND_SLOPE = (0.5, 2.0)  # extend: end slope within these x the secant (unbounded: 17 %)
EXTEND_MONOTONE = 0.25  # extend: none where the top branch ends this short of it (32 %)
EXTEND_REACH = 1.0  # extend: strain spans the extension reaches at most (unbounded: 17 %)
SETTLE_STEPS = 200  # steps each way of the 10 Hz ramp the end slopes are read on (50: 10 %)


def fitted_rest(valid_range: ValidRange) -> tuple[float, float]:
    """(rest strain, strain span) the calibration was fitted over (less the ``MARGIN``)."""
    span = (valid_range.s_hi - valid_range.s_lo) / (1.0 + 2.0 * MARGIN)
    return valid_range.s_lo + MARGIN * span, span


@dataclass(frozen=True)
class SensorRange:
    """One sensor's limits [ohm, %] and out-of-range extension."""

    r_short: float
    r_open: float
    r_lo: float
    r_hi: float
    s_lo: float
    s_hi: float
    slopes: tuple[float, float] | None = None
    """(dS/dR at r_lo, at r_hi) beyond the valid range when extended, else None (clamped)."""
    reach: tuple[float, float] = (-math.inf, math.inf)
    """Lowest and highest strain an extended estimate reaches (``extend``)."""
    saturate: bool = False
    """``extend``: the model reads the resistance clipped to the valid range."""

    @classmethod
    def build(cls, cal: SensorCalibration, out_of_range: str, model: Compensator
              ) -> SensorRange:
        """The limits of ``cal``'s valid range under the mode ``out_of_range``."""
        vr = cal.valid_range
        r_margin = MARGIN * (vr.r_hi - vr.r_lo)
        s_margin = MARGIN * (vr.s_hi - vr.s_lo)
        plain = cls(r_short=SHORT_FACTOR * vr.r_lo, r_open=OPEN_FACTOR * vr.r_hi,
                    r_lo=vr.r_lo - r_margin, r_hi=vr.r_hi + r_margin,
                    s_lo=vr.s_lo - s_margin, s_hi=vr.s_hi + s_margin)
        if out_of_range == "extrapolate":
            slopes = end_slopes(*branches(plain, model), plain)
            return cls(**{**vars(plain), "slopes": slopes})
        if out_of_range == "extend":
            slopes, reach = bounded_slopes(cal, plain, model)
            return cls(**{**vars(plain), "slopes": slopes, "reach": reach, "saturate": True})
        return plain

    @cached_property
    def row(self) -> np.ndarray:
        """The limits as the stage kernels read them (``stages.RANGE_COLUMNS``)."""
        slopes = self.slopes if self.slopes is not None else (0.0, 0.0)
        values = {"r_lo": self.r_lo, "r_hi": self.r_hi, "s_lo": self.s_lo, "s_hi": self.s_hi,
                  "slope_lo": slopes[0], "slope_hi": slopes[1], "reach_lo": self.reach[0],
                  "reach_hi": self.reach[1], "saturate": float(self.saturate)}
        return np.array([values[name] for name in RANGE_COLUMNS])


def branches(limits: SensorRange, model: Compensator) -> tuple[np.ndarray, np.ndarray]:
    """(loading, unloading) branch of the model over a slow ramp up the valid range and back."""
    n = SETTLE_STEPS
    up = np.linspace(limits.r_lo, limits.r_hi, n + 1)
    r = np.concatenate([up, up[-2::-1]])
    model.reset()
    out = model.run(0.1 * np.arange(r.size), r)
    model.reset()
    return out[:n + 1], out[n:][::-1]


def end_slopes(loading: np.ndarray, unloading: np.ndarray, limits: SensorRange
               ) -> tuple[float, float]:
    """dS/dR of the branches at the range's ends (``extrapolate``)."""
    width = (limits.r_hi - limits.r_lo) / SETTLE_STEPS
    lo = float(unloading[1] - unloading[0]) / width
    hi = float(loading[-1] - loading[-2]) / width
    return (lo if math.isfinite(lo) else 0.0), (hi if math.isfinite(hi) else 0.0)


def bounded_slopes(cal: SensorCalibration, limits: SensorRange, model: Compensator
                   ) -> tuple[tuple[float, float], tuple[float, float]]:
    """``extend``: (end slopes, reach), the rules of docs/design.md, "--out-of-range"."""
    loading, unloading = branches(limits, model)
    lo_end, hi_end = end_slopes(loading, unloading, limits)
    secant = float(loading[-1] - unloading[0]) / (limits.r_hi - limits.r_lo)
    low, high = EXTEND_SLOPE

    def bounded(end: float) -> float:
        if not (math.isfinite(secant) and secant * cal.direction.sign > 0.0
                and end * secant > 0.0):
            return 0.0
        return float(secant * min(max(end / secant, low), high))

    vr = cal.valid_range
    span = vr.s_hi - vr.s_lo
    slopes = [bounded(lo_end), bounded(hi_end)]
    top = 1 if secant > 0.0 else 0  # the end whose branch reads the strain's top
    if (loading[-1] if top else unloading[0]) < vr.s_hi - EXTEND_MONOTONE * span:
        slopes[top] = 0.0
    reach = (min(limits.s_lo, max(0.0, vr.s_lo - EXTEND_REACH * span)),
             max(limits.s_hi, vr.s_hi + EXTEND_REACH * span))
    return (slopes[0], slopes[1]), reach
