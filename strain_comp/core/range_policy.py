"""The out-of-range policy: where a sample is flagged, an open circuit or a short, and what
strain a resistance beyond the valid range gives (``OUT_OF_RANGE_MODES``); the numbers are
the constants below (docs/results.md, "Out of range", gives what keeps each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from strain_comp.base.compensator import Compensator
from strain_comp.core.calibration import SensorCalibration, ValidRange
from strain_comp.core.stages import RANGE_COLUMNS

OUT_OF_RANGE_MODES = ("clamp", "extrapolate", "extend")
"""Strain of a sample beyond the valid resistance range: clamped to the valid strain range
(plus the margin); or that plus the model's end slope times the resistance beyond it; or
that plus a bounded slope, within a bounded reach (``bounded_slopes``)."""
DEFAULT_OUT_OF_RANGE = "extend"
"""Chosen on the generalisation benchmark (docs/results.md): the lowest median and
worst ratio over every sensor and model on the headline workflow."""


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
    """``extend``: the model reads the resistance clipped to the valid range, so that its
    output beyond the range is its output at the range's end (a polynomial that turns back
    past the end, or cells driven where no data were, do not move it)."""

    @classmethod
    def build(cls, cal: SensorCalibration, out_of_range: str = "clamp",
              model: Compensator | None = None) -> SensorRange:
        """The limits of ``cal``'s valid range under the mode ``out_of_range``."""
        vr = cal.valid_range
        r_margin = MARGIN * (vr.r_hi - vr.r_lo)
        s_margin = MARGIN * (vr.s_hi - vr.s_lo)
        plain = cls(r_short=SHORT_FACTOR * vr.r_lo, r_open=OPEN_FACTOR * vr.r_hi,
                    r_lo=vr.r_lo - r_margin, r_hi=vr.r_hi + r_margin,
                    s_lo=vr.s_lo - s_margin, s_hi=vr.s_hi + s_margin)
        if out_of_range == "extrapolate":
            slopes = end_slopes(*branches(cal, plain, model), plain)
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


def branches(cal: SensorCalibration, limits: SensorRange, model: Compensator | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """(loading, unloading) branch of the model along a slow ramp over the valid range and
    back, both at ``np.linspace(r_lo, r_hi, n + 1)``; ``model`` reset before and after."""
    n = SETTLE_STEPS
    up = np.linspace(limits.r_lo, limits.r_hi, n + 1)
    r = np.concatenate([up, up[-2::-1]])
    if model is None:
        model = cal.build_model()
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


def bounded_slopes(cal: SensorCalibration, limits: SensorRange,
                   model: Compensator | None = None,
                   ) -> tuple[tuple[float, float], tuple[float, float]]:
    """``extend``: (slopes, reach). Each end slope kept within ``extend_slope`` x the
    secant slope of the model over the valid range (``branches``: the top of its loading
    branch to the bottom of its unloading one); zero (the range's end is held) where the
    map does not rise the way the gauge does (a secant against ``direction.sign``) or turns
    back at that end (an end slope against the secant, as past the resistance peak of a
    carbon-black strip); nor where the branch that reads the top of the strain ends
    ``extend_monotone`` of the span short of it: the training resistance peaked before the
    strain did. The extended estimate reaches at most ``extend_reach`` calibrated strain
    spans above the range, and below it never past zero strain: a resistance under the
    calibrated rest is far more often a rest level that moved than a compression."""
    loading, unloading = branches(cal, limits, model)
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
