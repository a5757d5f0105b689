"""Dead-zone direction detector ([EGaIn] section V.E, Fig. 7): loading / hold / unloading;
one numba update serves it and the models that switch on direction (docs/models.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.errors import InputError, ParameterError

# Detector state vector layout (float64): started flag, last t, last r, filtered dR/dt, output.
STATE_SIZE = 5
_STARTED, _T, _R, _FILT, _OUT = range(STATE_SIZE)


@dataclass(frozen=True)
class DirectionSettings:
    deadzone: float
    tau: float = 0.0
    k_sigma: float | None = None
    sign: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.deadzone) and self.deadzone >= 0.0):
            raise ParameterError("direction.deadzone", f"must be finite and >= 0, got "
                                 f"{self.deadzone}")
        if not (math.isfinite(self.tau) and self.tau >= 0.0):
            raise ParameterError("direction.tau", f"must be finite and >= 0, got {self.tau}")
        if self.sign not in (1, -1) or isinstance(self.sign, bool):
            raise ParameterError("direction.sign", f"must be +1 or -1, got {self.sign!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"deadzone": self.deadzone, "tau": self.tau, "k_sigma": self.k_sigma,
                "sign": self.sign}


@njit
def direction_update(state: np.ndarray, t: float, r: float, deadzone: float,
                     tau: float) -> int:
    if state[0] == 0.0:
        state[0] = 1.0
        state[1] = t
        state[2] = r
        state[3] = 0.0
        state[4] = 0.0
        return 0
    dt = t - state[1]
    if not dt > 0.0:
        return int(state[4])
    d = (r - state[2]) / dt
    if tau > 0.0:
        alpha = 1.0 - math.exp(-dt / tau)
        state[3] += alpha * (d - state[3])
    else:
        state[3] = d
    state[1] = t
    state[2] = r
    out = 0
    if state[3] > deadzone:
        out = 1
    elif state[3] < -deadzone:
        out = -1
    state[4] = float(out)
    return out


@njit
def _direction_run(state: np.ndarray, t: np.ndarray, r: np.ndarray, deadzone: float,
                   tau: float) -> tuple[np.ndarray, np.ndarray]:
    """The direction and the filtered derivative after each sample."""
    out = np.empty(t.size, dtype=np.int8)
    filtered = np.empty(t.size)
    for n in range(t.size):
        out[n] = direction_update(state, t[n], r[n], deadzone, tau)
        filtered[n] = state[_FILT]
    return out, filtered


class DirectionDetector:
    """Streaming dead-zone direction detector (``direction_update`` over arrays)."""

    def __init__(self, settings: DirectionSettings) -> None:
        self.settings = settings
        self.state = np.zeros(STATE_SIZE)

    def reset(self) -> None:
        """Forget everything seen (the next sample primes the detector again)."""
        self.state[:] = 0.0

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        """Advance over whole arrays, continuing from the current state."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        r = np.ascontiguousarray(r, dtype=np.float64)
        return _direction_run(self.state, t, r, self.settings.deadzone, self.settings.tau)[0]


def derivative_noise(t: npt.ArrayLike, r: npt.ArrayLike, tau: float = 0.0) -> float:
    """Robust sigma [ohm/s] (1.4826 MAD, linear drift removed) of the filtered dR/dt on a hold."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    d = _direction_run(np.zeros(STATE_SIZE), t, r, np.inf, float(tau))[1][1:]  # none at 0
    td = t[1:]
    if tau > 0.0:
        keep = td >= t[0] + 5.0 * tau
        if keep.sum() >= 10:
            d, td = d[keep], td[keep]
    coef = np.polyfit(td - td.mean(), d, 1)
    resid = d - np.polyval(coef, td - td.mean())
    return float(1.4826 * np.median(np.abs(resid - np.median(resid))))


def estimate_deadzone(t: npt.ArrayLike, r: npt.ArrayLike, *, k_sigma: float = 4.0,
                      tau: float = 0.0) -> DirectionSettings:
    """Dead zone = k_sigma * sigma of the filtered derivative on a hold segment (section V.E)."""
    sigma = derivative_noise(t, r, tau)
    if not sigma > 0.0:
        raise InputError("estimate_deadzone: the hold segment shows no derivative noise "
                         "(constant readings); give the dead zone in ohm/s instead")
    return DirectionSettings(deadzone=float(k_sigma * sigma), tau=float(tau),
                             k_sigma=float(k_sigma))
