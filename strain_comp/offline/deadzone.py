"""The direction detector's settings from training data ([EGaIn] section V.E: dead zone = k
sigma of dR/dt noise) on the second half of the longest hold of the reference, else on seeded
white noise of R's robust sigma; ``direction_from`` in the provenance says which."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from strain_comp.base.direction import DirectionSettings, estimate_deadzone
from strain_comp.models import Segment
from strain_comp.offline.reduce import HOLD_RATE_FRACTION, still_stretches

MIN_HOLD_SAMPLES = 40
DEFAULT_K_SIGMA = 4.0
"""Dead zone = k sigma of the derivative noise ([EGaIn] section V.E: 3 or 4)."""
TAU_GRID = (0.0, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
"""Derivative low-pass time constants [s] tried, shortest (least lag) first."""
BURST_FRACTION = 0.25
"""Sample intervals shorter than this fraction of the median are bursts (``_tau_grid``)."""
DEADZONE_FRACTION = 0.5
"""The dead zone must stay below this fraction of the typical dR/dt while moving."""

def find_hold(segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray] | None:
    """The second half of the longest still stretch of the reference."""
    rates = [np.abs(np.gradient(seg.s, seg.t)) for seg in segments]
    moving = np.concatenate(rates)
    scale = float(np.percentile(moving, 99.5)) if moving.size else 0.0
    if scale <= 0.0:
        return None
    best: tuple[int, int, int] | None = None  # (length, segment index, start)
    for index, rate in enumerate(rates):
        for start, stop in zip(*still_stretches(rate, scale), strict=True):
            if best is None or stop - start > best[0]:
                best = (int(stop - start), index, int(start))
    if best is None or best[0] < MIN_HOLD_SAMPLES:
        return None
    length, index, start = best
    half = start + length // 2
    seg = segments[index]
    return seg.t[half:start + length], seg.r[half:start + length]


def _noise_sigma(segments: Sequence[Segment]) -> float:
    """Robust white-noise sigma of R [ohm] from second differences (smooth motion cancels)."""
    d2 = np.concatenate([np.diff(seg.r, 2) for seg in segments if seg.r.size >= 3])
    if d2.size == 0:
        return 0.0
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    return (sigma or float(np.std(d2))) / math.sqrt(6.0)


def movement_rate(segments: Sequence[Segment]) -> float:
    """Typical |dR/dt| while the reference moves: |dR/dS| of a line times the median |dS/dt|."""
    # through the clean reference, so resistance noise does not inflate it
    r = np.concatenate([seg.r for seg in segments])
    s = np.concatenate([seg.s for seg in segments])
    gradient = np.gradient if _bursts(segments) is None else _regular_gradient
    rates = np.concatenate([np.abs(gradient(seg.s, seg.t)) for seg in segments])
    scale = float(np.percentile(rates, 99.5))
    moving = rates > 10 * HOLD_RATE_FRACTION * scale
    if scale <= 0.0 or not moving.any():
        return 0.0
    gain = abs(float(np.polyfit(s, r, 1)[0]))
    return gain * float(np.median(rates[moving]))


def direction_settings(segments: Sequence[Segment], options: Mapping[str, Any]) -> tuple[
        DirectionSettings, str]:
    """Dead-zone settings and their source."""
    k_sigma = float(options.get("k_sigma", DEFAULT_K_SIGMA))
    if "deadzone" in options:
        deadzone = float(options["deadzone"])  # > 0: checked with every fit option
        tau = float(options.get("tau", 0.0))
        return DirectionSettings(deadzone=deadzone, tau=tau, k_sigma=None), "given"
    taus = [float(options["tau"])] if "tau" in options else _tau_grid(segments)
    hold = find_hold(segments)
    longest = max(segments, key=lambda seg: seg.t.size)
    if hold is not None and np.ptp(hold[1]) > 0:
        t_hold, r_hold, source = hold[0], hold[1], "hold"
    else:  # seeded white noise of R's robust sigma
        sigma = _noise_sigma(segments)
        if not (sigma > 0 and longest.t.size >= 12):
            # Noise-free data (a clean simulation): a dead zone far below any real motion,
            # 1e-6 of the training R span per second of the longest segment.
            t_span = float(longest.t[-1] - longest.t[0]) or 1.0
            r_span = float(np.ptp(np.concatenate([seg.r for seg in segments])))
            return DirectionSettings(deadzone=1e-6 * r_span / t_span, tau=taus[0],
                                     k_sigma=None), "floor"
        rng = np.random.default_rng(0)
        t_hold, source = longest.t, "noise"
        r_hold = float(np.median(longest.r)) + sigma * rng.standard_normal(longest.t.size)
    target = DEADZONE_FRACTION * movement_rate(segments)
    for tau in taus:
        settings = estimate_deadzone(t_hold, r_hold, k_sigma=k_sigma, tau=tau)
        if settings.deadzone <= target:
            break
    return settings, source


def _bursts(segments: Sequence[Segment]) -> float | None:
    """The median sample interval when over 1 % of the intervals are bursts, else None."""
    dt = np.concatenate([np.diff(seg.t) for seg in segments])
    if dt.size < 2:
        return None
    median = float(np.median(dt))
    return median if float(np.percentile(dt, 1)) < BURST_FRACTION * median else None


def _regular_gradient(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """dS/dt at the samples, from S interpolated onto a grid of the median interval."""
    if t.size < 3:
        return np.zeros(t.size)
    step = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * step, step)
    if grid.size < 2:
        return np.zeros(t.size)
    rate: np.ndarray = np.interp(t, grid, np.gradient(np.interp(grid, t, s), grid))
    return rate


def _tau_grid(segments: Sequence[Segment]) -> list[float]:
    """``TAU_GRID`` without the filters shorter than two median intervals when in bursts."""
    # a first difference over a burst's microseconds turns read-out noise into huge rates
    median = _bursts(segments)
    if median is None:
        return list(TAU_GRID)
    return [tau for tau in TAU_GRID if tau >= 2.0 * median] or [TAU_GRID[-1]]


def resistance_sign(r: np.ndarray, s: np.ndarray) -> int:
    """The sign of the correlation of R and S (0 counts as +1): ``DirectionSettings.sign``."""
    return -1 if float(np.mean((r - r.mean()) * (s - s.mean()))) < 0 else 1
