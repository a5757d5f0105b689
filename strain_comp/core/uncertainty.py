"""The standard deviation of every estimate (docs/design.md, "Uncertainty"): one kernel
(``features_one``) for the engine, the learner and the array tick."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from strain_comp._numba import njit
from strain_comp.core.stages import R_HI, R_LO, S_HI, S_LO

FEATURES = ("bias", "loading", "unloading", "hold", "outside", "elapsed", "level")
"""The regressors of log sigma^2, in order (docs/design.md, "Uncertainty")."""
N_FEATURES = len(FEATURES)
STATE_SIZE = 3
"""Per sensor: the previous direction, the time it last changed, the session's first time."""
_LAST_DIRECTION, _CHANGED_T, _START_T = range(STATE_SIZE)
WEIGHT_MAX = 100.0
"""The largest magnitude of a weight a calibration file may hold."""


@dataclass(frozen=True)
class Uncertainty:
    """A sensor's learned variance model: one weight per ``FEATURES`` entry."""

    weights: tuple[float, ...]
    runs: int = 0
    """Runs left out in turn to learn it."""
    samples: int = 0
    """Left-out samples it was fitted on."""

    def to_dict(self) -> dict[str, object]:
        return {"weights": dict(zip(FEATURES, self.weights, strict=True)),
                "runs": self.runs, "samples": self.samples}

    @classmethod
    def from_weights(cls, weights: Mapping[str, float], runs: int = 0, samples: int = 0
                     ) -> Uncertainty:
        """From a feature name -> weight mapping (missing features weigh 0)."""
        return cls(tuple(float(weights.get(name, 0.0)) for name in FEATURES), runs, samples)


def new_state() -> np.ndarray:
    """A sensor's state before its first used sample."""
    return np.full(STATE_SIZE, np.nan)


@njit(inline="always")
def features_one(t: float, direction: float, ohm: float, strain: float, state: np.ndarray,
                 row: np.ndarray, out: np.ndarray) -> None:
    """The features of one used sample into ``out``; ``state`` updated in place."""
    if math.isnan(state[_START_T]):
        state[_START_T] = t
    if math.isnan(state[_LAST_DIRECTION]) or direction != state[_LAST_DIRECTION]:
        state[_LAST_DIRECTION] = direction
        state[_CHANGED_T] = t
    r_lo, r_hi, s_lo, s_hi = row[R_LO], row[R_HI], row[S_LO], row[S_HI]
    out[0] = 1.0
    out[1] = 1.0 if direction > 0 else 0.0
    out[2] = 1.0 if direction < 0 else 0.0
    out[3] = math.log1p(max(t - state[_CHANGED_T], 0.0))
    out[4] = max(ohm - r_hi, r_lo - ohm, 0.0) / (r_hi - r_lo)
    out[5] = math.log1p(max(t - state[_START_T], 0.0) / 60.0)
    level = (min(max(strain, s_lo), s_hi) - s_lo) / (s_hi - s_lo)
    out[6] = 0.0 if math.isnan(level) else level


@njit(inline="always")
def sigma(x: np.ndarray, weights: np.ndarray) -> float:
    """sqrt(exp(w . x)): the standard deviation of features ``x``."""
    z = 0.0
    for i in range(x.size):
        z += weights[i] * x[i]
    return math.exp(0.5 * min(z, 700.0))


@njit
def features_run(t: np.ndarray, direction: np.ndarray, ohm: np.ndarray, strain: np.ndarray,
                 state: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``features_one`` over used samples in time order, (n, ``N_FEATURES``)."""
    out = np.empty((t.size, N_FEATURES))
    for i in range(t.size):
        features_one(t[i], float(direction[i]), ohm[i], strain[i], state, row, out[i])
    return out


@njit
def std_run(t: np.ndarray, direction: np.ndarray, ohm: np.ndarray, strain: np.ndarray,
            state: np.ndarray, row: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The standard deviation of used samples in time order (``sigma`` of each's features)."""
    x = features_run(t, direction, ohm, strain, state, row)
    out = np.empty(t.size)
    for i in range(t.size):
        out[i] = sigma(x[i], weights)
    return out
