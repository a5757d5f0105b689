"""Measurement-chain effects found from the resistance alone (no reference needed).

These belong to the instrument, not the material: an excitation whose polarity alternates
every sample (a source-measure unit reversing its current: R_meas[i] = R[i] + A (-1)^i),
isolated spikes (one-sample read glitches) and quantisation (an ADC's resistance step).
Smooth strain motion cancels in the second difference d2[i] = R[i+1] - 2 R[i] + R[i-1],
which all three statistics read:

* alternation: the d2 centred on sample i of A (-1)^i is -4 A (-1)^i, so
  A = -median((-1)^i d2) / 4 (d2 indexed by its centre), and the share of (-1)^i d2
  with the sign of -A is 0.5 without alternation. It is *present*
  when that share is significant (z > ``ALTERNATION_Z``) and A is at least the white noise
  sigma left after removing it (smaller alternations are a minor part of the noise).
  Correction (online, phase-free, half a sample of delay): the models see pair means
  (R[i] + R[i-1]) / 2 (``pair_means``), which cancel A exactly whatever its phase.
  An alternation can also sit on one side of the signal: every other sample reads low by
  an amount that switches on and off with the sensor's state (the carbon-black strip reads
  steadily under load, then every other sample drops 680 ohm in the middle of a hold while
  the other half continue the level). The pair mean then steps by half that amount, which
  a model with memory takes for movement; the pair maximum does not. ``pair_branch``
  reads the side from the steps of the alternation's size while the strain is known to be
  still (a fit has the reference): per window of ``PAIR_WINDOW`` pairs the medians of the
  upper (U) and lower (L) value of each pair, and at every step of U - L larger than
  ``PAIR_STEP_K`` robust sigmas between two still windows the share k = -dL / d(U - L)
  of it that the lower side took: median k near 1 means the lower side moves and the
  upper one holds the level (``upper``), near 0 the reverse (``lower``), near 1/2 a
  symmetric alternation (``mean``). Without such a step the side cannot be told and the
  mean, exact for a symmetric alternation and the quietest, is kept. Movement is excluded
  because it changes the level and the alternation's size together.
* spikes: samples whose |d2| exceeds ``SPIKE_K`` robust sigmas at a sign pattern of one
  sample (counted; the engine's screen and the pair mean bound their effect).
* quantisation: the smallest common step of the nonzero |R[i+1] - R[i]|, if most
  differences are integer multiples of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

ALTERNATION_Z = 5.0
"""Significance (binomial z) of the sign agreement for an alternation to be present."""
SPIKE_K = 8.0
"""A spike's second difference exceeds this many robust sigmas."""
PAIR_WINDOW = 5
"""Pairs per window of the medians ``pair_branch`` compares."""
PAIR_STEP_K = 8.0
"""A step of the alternation's size exceeds this many robust sigmas of its changes."""
PAIR_MIN_STEPS = 3
"""Fewest steps ``pair_branch`` needs to read a side."""


@dataclass(frozen=True)
class Alternation:
    """Alternation every other sample: amplitude A [ohm], noise sigma [ohm], sign share."""

    amplitude: float
    noise: float
    agreement: float
    z: float

    @property
    def present(self) -> bool:
        return self.z > ALTERNATION_Z and abs(self.amplitude) >= self.noise

    def reading(self) -> str:
        return (f"alternation +-{abs(self.amplitude):.3g} ohm every other sample "
                f"(white noise {self.noise:.3g} ohm)")


def _finite(r: npt.ArrayLike) -> np.ndarray:
    r = np.asarray(r, dtype=np.float64)
    return r[np.isfinite(r) & (r > 0)]


def _robust_sigma(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def alternation(r: npt.ArrayLike) -> Alternation:
    """The alternation statistics of a resistance series (module docstring)."""
    r = _finite(r)
    if r.size < 8:
        return Alternation(0.0, 0.0, 0.5, 0.0)
    d2 = np.diff(r, 2)
    m = d2 * (-1.0) ** np.arange(1, d2.size + 1)  # d2[i] is centred on sample i + 1
    amplitude = -float(np.median(m)) / 4.0
    noise = _robust_sigma(m + 4.0 * amplitude) / math.sqrt(6.0)
    nonzero = m[m != 0]
    if amplitude == 0.0 or nonzero.size == 0:
        return Alternation(amplitude, noise, 0.5, 0.0)
    agreement = float(np.mean(np.sign(nonzero) == -np.sign(amplitude)))
    z = (agreement - 0.5) * 2.0 * math.sqrt(nonzero.size)
    return Alternation(amplitude, noise, agreement, z)


def pair_means(r: np.ndarray, previous: float = math.nan) -> np.ndarray:
    """(R[i] + R[i-1]) / 2, the first one with ``previous`` (itself when NaN)."""
    before = np.concatenate(([previous], r[:-1])) if r.size else r
    return np.where(np.isfinite(before), 0.5 * (r + before), r)


PAIR_BRANCHES = ("mean", "upper", "lower")
"""The pair statistics an alternating input can be read through (``pair_values``)."""


def pair_values(r: np.ndarray, previous: float = math.nan, branch: str = "mean",
                ) -> np.ndarray:
    """The pair statistic ``branch`` of R[i] and R[i-1] (mean, upper: max, lower: min), the
    first one with ``previous`` (itself when NaN)."""
    if branch == "mean":
        return pair_means(r, previous)
    before = np.concatenate(([previous], r[:-1])) if r.size else r
    pick = np.fmax if branch == "upper" else np.fmin  # fmax/fmin: a NaN previous is skipped
    return pick(r, before)


def pair_branch(r: npt.ArrayLike, still: npt.ArrayLike) -> str:
    """The pair statistic (``PAIR_BRANCHES``) to read an alternating ``r`` through, from the
    steps of its size between windows where ``still`` (bool per sample: the strain is known
    to be constant) holds (module docstring); ``mean`` when fewer than ``PAIR_MIN_STEPS``."""
    ra = np.asarray(r, dtype=np.float64)
    ok = np.isfinite(ra) & (ra > 0)
    ra, sa = ra[ok], np.asarray(still, dtype=bool)[ok]
    n = (ra.size // (2 * PAIR_WINDOW)) * 2 * PAIR_WINDOW
    if n < 4 * PAIR_WINDOW:
        return "mean"
    pairs = ra[:n].reshape(-1, 2)
    upper = np.median(pairs.max(axis=1).reshape(-1, PAIR_WINDOW), axis=1)
    lower = np.median(pairs.min(axis=1).reshape(-1, PAIR_WINDOW), axis=1)
    quiet = np.all(sa[:n].reshape(-1, 2 * PAIR_WINDOW), axis=1)
    d_size, d_lower = np.diff(upper - lower), np.diff(lower)
    sigma = _robust_sigma(d_size)
    steps = (np.abs(d_size) > PAIR_STEP_K * sigma) & quiet[1:] & quiet[:-1]
    if sigma <= 0 or np.sum(steps) < PAIR_MIN_STEPS:
        return "mean"
    share = float(np.median(-d_lower[steps] / d_size[steps]))
    return "upper" if share > 0.75 else "lower" if share < 0.25 else "mean"


def spikes(r: npt.ArrayLike) -> int:
    """Number of isolated one-sample spikes (module docstring)."""
    r = _finite(r)
    if r.size < 8:
        return 0
    d2 = np.diff(pair_means(r) if alternation(r).present else r, 2)
    sigma = _robust_sigma(d2)
    if not sigma > 0:
        return 0
    big = np.abs(d2) > SPIKE_K * sigma
    # a spike at i gives d2 of one sign at i-1 and i+1 and twice the opposite at i
    peak = big[1:-1] & (np.abs(d2[1:-1]) >= np.abs(d2[:-2])) & (np.abs(d2[1:-1])
                                                              >= np.abs(d2[2:]))
    return int(np.count_nonzero(peak))


def quantisation(r: npt.ArrayLike) -> float | None:
    """The resistance step [ohm] of a quantised series, or None when R is not quantised."""
    r = _finite(r)
    steps = np.abs(np.diff(r))
    steps = steps[steps > 0]
    if steps.size < 20:
        return None
    q = float(np.percentile(steps, 5))
    if not q > 0:
        return None
    ratio = steps / q
    on_grid = np.abs(ratio - np.round(ratio)) < 0.05
    return q if float(np.mean(on_grid)) > 0.9 and np.mean(np.diff(r) == 0) > 0.05 else None
