"""Measurement-chain effects found from the resistance alone (no reference needed):
alternation, isolated spikes, baseline steps, quantisation; how each is found and
corrected: docs/models.md, "The measurement chain".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from strain_comp.core.chain_kernels import HELD as HELD
from strain_comp.core.chain_kernels import (
    LEVELS,
    OFFSET,
    REFERENCES,
    STATE_SIZE,
    TREND,
    WINDOW,
    correct_samples,
)
from strain_comp.core.chain_kernels import SPIKE as SPIKE
from strain_comp.core.chain_kernels import STEP as STEP
from strain_comp.core.chain_kernels import STEP_SAMPLES as STEP_SAMPLES

ALTERNATION_Z = 5.0
"""Significance (binomial z) of the sign agreement for an alternation to be present."""
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


def _finite(r: npt.ArrayLike) -> npt.NDArray[np.float64]:
    x = np.asarray(r, dtype=np.float64)
    return x[np.isfinite(x) & (x > 0)]


def _robust_sigma(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def alternation(r: npt.ArrayLike) -> Alternation:
    """The alternation statistics of a resistance series (docs/models.md)."""
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


PAIR_BRANCHES = ("mean", "upper", "lower")
"""The pair statistics an alternating input can be read through (``pair_values``)."""


def pair_values(r: npt.NDArray[np.float64], previous: float = math.nan, branch: str = "mean",
                ) -> np.ndarray:
    """The pair statistic ``branch`` of R[i] and R[i-1] (mean, upper: max, lower: min), the
    first one with ``previous`` (itself when NaN)."""
    before = np.concatenate(([previous], r[:-1])) if r.size else r
    if branch == "mean":
        return np.where(np.isfinite(before), 0.5 * (r + before), r)
    # fmax/fmin: a NaN previous is skipped
    return np.fmax(r, before) if branch == "upper" else np.fmin(r, before)


def pair_branch(r: npt.ArrayLike, still: npt.ArrayLike) -> str:
    """The pair statistic (``PAIR_BRANCHES``) to read an alternating ``r`` through, from the
    steps of its size between windows where ``still`` (bool per sample: the strain is known
    to be constant) holds (docs/models.md); ``mean`` when fewer than ``PAIR_MIN_STEPS``."""
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


# ------------------------------------------------------------------ online input correction

DESPIKE_K = 8.0
"""Default spike threshold of the online corrector: robust sigmas of its innovation."""
STEP_K = 12.0
"""Default least size of a baseline step, in robust sigmas of the innovation (1.5 times the
spike threshold: a measured carbon-black run, v19, shows a change of 8-12 sigmas that stays
while loading, which is strain, not a step; ``studies/measured_chain.py``)."""
@dataclass(frozen=True)
class BaselineStep:
    """A confirmed baseline step: time of confirmation [s] and size [ohm]."""

    t: float
    size: float

    def reading(self) -> str:
        size = (f"{self.size / 1000.0:+.3g} kohm" if abs(self.size) >= 1000.0
                else f"{self.size:+.3g} ohm")
        return f"baseline step {size} at t={self.t:.4g} s, connector re-seated?"


class ChainCorrector:
    """Online, causal correction of isolated spikes and baseline steps of one sensor."""

    def __init__(self, *, k: float = DESPIKE_K, alternating: bool = False,
                 step_k: float = 0.0) -> None:
        self.k = float(k)
        self.width = 2 if alternating else 1
        self.step_k = float(step_k)
        self.state = np.zeros(STATE_SIZE)
        self.window = np.zeros(WINDOW)
        self.trend = np.zeros(TREND)
        self.buffer = np.zeros(STEP_SAMPLES)
        self.pre = np.zeros(STEP_SAMPLES)
        self.n_spikes = 0
        self.steps: list[BaselineStep] = []

    @property
    def offset(self) -> float:
        """The baseline correction so far [ohm] (subtracted from every sample)."""
        return float(self.state[OFFSET])

    def restart(self) -> None:
        """Forget the references (after a gap): the next sample passes unjudged."""
        for column in REFERENCES:
            self.state[column] = 0.0

    def rescale(self, factor: float) -> None:
        """Carry the state over to samples ``factor`` x as large (a new tare gain), so the
        gain change itself is neither a spike nor a baseline step."""
        for column in LEVELS:
            self.state[column] *= factor
        for values in (self.window, self.trend, self.buffer, self.pre):
            values *= factor

    def run(self, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(corrected samples, event codes) of consecutive used samples ``x`` [ohm] at
        times ``t`` [s]; spikes and steps are counted in ``n_spikes`` and ``steps``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        events = np.zeros(x.size, np.int8)
        offsets = np.empty(x.size)
        before = self.offset
        y = correct_samples(np.ascontiguousarray(t, dtype=np.float64), x, self.state,
                            self.window, self.trend, self.buffer, self.pre, self.k,
                            self.width, self.step_k, events, offsets)
        self.n_spikes += int(np.count_nonzero(events == SPIKE))
        for i in np.flatnonzero(events == STEP).tolist():
            previous = offsets[i - 1] if i > 0 else before
            self.steps.append(BaselineStep(float(t[i]), float(offsets[i] - previous)))
        return y, events


def correct(t: npt.ArrayLike, r: npt.ArrayLike, *, k: float = DESPIKE_K,
            step_k: float = 0.0, alternating: bool | None = None, pair: str = "mean",
            ) -> tuple[np.ndarray, np.ndarray, ChainCorrector]:
    """A whole run through a fresh ``ChainCorrector`` as the engine feeds its models
    (``alternating`` None: found from the data): (what the models see, events, corrector)."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    good = np.isfinite(r) & (r > 0)
    if alternating is None:
        alternating = alternation(r).present
    corrector = ChainCorrector(k=k, alternating=alternating, step_k=step_k)
    seen = pair_values(r[good], branch=pair) if alternating else r[good]
    out = np.full(r.size, np.nan)
    events = np.zeros(r.size, np.int8)
    out[good], events[good] = corrector.run(t[good], seen)
    return out, events, corrector
