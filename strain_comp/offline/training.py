"""The training data of a fit: screened as the engine screens, cut into segments where the
engine resets, checked, and their valid range.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.base.samples import GAP_INTERVALS, gap_for, good_mask
from strain_comp.core.calibration import PARAM_MAX, STRAIN_MAX, ValidRange, check_reference
from strain_comp.core.engine import GAP_RESET
from strain_comp.core.tare import rest_resistance_from_reference
from strain_comp.errors import FitError
from strain_comp.models import Segment

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

GAP_SECONDS = GAP_RESET
"""A step between good samples longer than this [s] cuts a segment (engine ``gap_reset``)."""
MIN_SEGMENT = 8
"""Segments with fewer good samples are not used for fitting."""
MIN_SPAN = 1e-9
"""Smallest span of the training resistance [ohm] and strain: a finer one is a unit mistake
that the least-squares solvers cannot resolve (LAPACK fails)."""
TRAINING_WIDENING = 0.05
"""Valid range = training range widened by this fraction of its span on each side."""


def split_segments(t: np.ndarray, r: np.ndarray, s: np.ndarray, *,
                   gap: float = GAP_SECONDS) -> list[Segment]:
    """Good, referenced samples cut where the time steps back or forward by over ``gap``."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    keep = good_mask(t, r) & np.isfinite(s)
    t, r, s = t[keep], r[keep], s[keep]
    if t.size < 2:
        return []
    step = np.diff(t)
    cuts = np.flatnonzero((step > gap) | (step < 0.0)) + 1
    bounds = np.concatenate(([0], cuts, [t.size]))
    return [Segment(t[a:b], r[a:b], s[a:b]) for a, b in pairwise(bounds)
            if b - a >= MIN_SEGMENT]


def training_segments(recordings: Sequence[Recording], name: str,
                      interval: float | None) -> list[Segment]:
    """Every recording's segments (``split_segments``, the gap of ``interval``)."""
    segments: list[Segment] = []
    for rec in recordings:
        if rec.s is None:
            raise FitError(f"sensor {name!r}: recording has no strain_reference to fit to")
        segments.extend(split_segments(rec.t, rec.r, rec.s, gap=gap_for(interval)))
    if not segments:
        raise FitError(f"sensor {name!r}: no stretch of {MIN_SEGMENT} or more good samples "
                       "with a finite reference strain")
    return segments


def check_training_span(segments: Sequence[Segment], name: str) -> None:
    """Check that the training data can be fitted in float64."""
    r_all = np.concatenate([seg.r for seg in segments])
    s_all = np.concatenate([seg.s for seg in segments])
    if not (np.ptp(r_all) > 0 and np.ptp(s_all) > 0):
        raise FitError(f"sensor {name!r}: the training data span no range of resistance "
                       "or strain")
    check_reference(name, s_all, FitError)
    span = valid_range(segments)
    if not max(abs(span.s_lo), abs(span.s_hi)) <= STRAIN_MAX:  # widened beyond it
        raise FitError(f"sensor {name!r}: the reference strain spans {s_all.min():.4g} to "
                       f"{s_all.max():.4g}, beyond the +/- {STRAIN_MAX:g} a calibration "
                       "holds once widened; import it in a larger unit (microstrain to %: "
                       "import-csv --scales strain=1e-4)")
    for what, values, top in (("resistance", r_all, PARAM_MAX), ("strain", s_all, STRAIN_MAX)):
        # a span a float64 fit cannot resolve (1e-300) or values a calibration cannot hold
        if np.ptp(values) < MIN_SPAN or np.abs(values).max() > top:
            raise FitError(f"sensor {name!r}: the training {what} spans "
                           f"[{values.min():.3g}, {values.max():.3g}]: a fit needs a span of "
                           f"at least {MIN_SPAN:g} and values within +/- {top:g} "
                           "(a unit or scale mistake?)")


def valid_range(segments: Sequence[Segment]) -> ValidRange:
    """Training range of R and S widened by ``TRAINING_WIDENING`` (R kept > 0)."""
    r = np.concatenate([seg.r for seg in segments])
    s = np.concatenate([seg.s for seg in segments])
    r_lo, r_hi = float(r.min()), float(r.max())
    s_lo, s_hi = float(s.min()), float(s.max())
    r_pad, s_pad = TRAINING_WIDENING * (r_hi - r_lo), TRAINING_WIDENING * (s_hi - s_lo)
    return ValidRange(max(r_lo - r_pad, 0.5 * r_lo), r_hi + r_pad, s_lo - s_pad, s_hi + s_pad)


def slow_sample_interval(recordings: Sequence[Recording]) -> float | None:
    """The median interval between good samples, where a slow instrument's (else None)."""
    steps = [np.diff(np.asarray(rec.t, dtype=np.float64)[good_mask(rec.t, rec.r)])
             for rec in recordings]
    dt = np.concatenate(steps) if steps else np.empty(0)
    dt = dt[dt > 0.0]
    if not dt.size:
        return None
    interval = float(np.median(dt))
    return interval if GAP_INTERVALS * interval > GAP_SECONDS else None


def training_rest_resistance(recordings: Sequence[Recording], *, pair: str = "mean",
                             ) -> float | None:
    """The median over the runs of each one's leading rest level, as an automatic tare's."""
    levels = [rest_resistance_from_reference(rec.t, rec.r, rec.s, pair=pair)
              for rec in recordings
              if rec.s is not None]
    found = [level for level in levels if level is not None]
    return float(np.median(found)) if found else None
