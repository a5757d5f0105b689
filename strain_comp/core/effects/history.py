"""Effect terms of the run's history: direction, elapsed time, Mullins softening,
stretch travel and the run's baseline."""

from __future__ import annotations

import math

import numpy as np

from strain_comp._numba import njit
from strain_comp.core.effects.regressor import (
    Batch,
    Regressor,
    choice,
    flag,
    number,
    param_readers,
    positive,
)


class Direction(Regressor):
    """The detector's direction d ([EGaIn] section V.E) as a regressor."""

    kind = "direction"
    readers = param_readers(mode=choice(("sign", "strain"), "sign"), hold=flag(False))
    initial = (0.0, 0.0)
    """The last moving direction (hold) up to the previous sample, and the previous one's."""
    mode: str
    hold: bool

    def run(self, batch: Batch) -> np.ndarray:
        last, prev = float(self._state[0]), float(self._state[1])
        d = np.concatenate(([prev], batch.direction[:-1]))
        if batch.direction.size:
            self._state[1] = batch.direction[-1]
        if self.hold:
            held = self._held(np.where(batch.direction != 0.0, batch.direction, np.nan))
            d = np.concatenate(([last], held[:-1]))[:batch.t.size]
        return d * batch.s_hat if self.mode == "strain" else d


class Elapsed(Regressor):
    """Slow drift: a function of the time since the first sample, x = (t - t0) / scale."""

    kind = "elapsed"
    readers = param_readers(form=choice(("linear", "sqrt", "log", "linear_strain"), "linear"),
                            scale=positive(100.0))
    initial = (math.nan,)
    """The time of the first sample."""
    form: str
    scale: float

    def run(self, batch: Batch) -> np.ndarray:
        if batch.t.size and math.isnan(self._state[0]):
            self._state[0] = batch.t[0]
        g: np.ndarray = np.maximum((batch.t - self._state[0]) / self.scale, 0.0)
        if self.form == "sqrt":
            g = np.sqrt(g)
        elif self.form == "log":
            g = np.log1p(g)
        return g * batch.s_hat if self.form == "linear_strain" else g


_MULLINS_FORMS = ("gap", "gap_strain", "cycles_log", "cycles_exp", "peak_strain")


@njit
def _mullins_kernel(s: np.ndarray, d: np.ndarray, form: int, n0: float,
                    state: np.ndarray) -> np.ndarray:
    """Running peak of S_hat and count of completed load cycles -> softening regressor."""
    peak, cycles, last = state[0], state[1], state[2]
    out = np.empty(s.size)
    for k in range(s.size):
        if s[k] > peak:
            peak = s[k]
        if d[k] != 0:
            if last < 0 and d[k] > 0:
                cycles += 1.0
            last = d[k]
        if form == 0:
            out[k] = peak - s[k]
        elif form == 1:
            out[k] = s[k] * (peak - s[k])
        elif form == 2:
            out[k] = s[k] * math.log1p(cycles)
        elif form == 3:
            out[k] = s[k] * math.exp(-cycles / n0)
        else:
            out[k] = s[k] * peak
    state[0], state[1], state[2] = peak, cycles, last
    return out


class Mullins(Regressor):
    """Mullins-type softening: a response set by the strain's peak so far and the load cycles."""

    kind = "mullins"
    readers = param_readers(form=choice(_MULLINS_FORMS, "cycles_exp"), n0=positive(1.0))
    initial = (-math.inf, 0.0, 0.0)
    form: str
    n0: float

    def run(self, batch: Batch) -> np.ndarray:
        return _mullins_kernel(batch.s_hat, batch.direction, _MULLINS_FORMS.index(self.form),
                               self.n0, self._state)


STRETCH_FORMS = ("rest", "rest_log", "gain", "gain_log")
"""The forms of ``Stretch``, in the order of the kernel's codes."""


@njit
def _stretch_kernel(s: np.ndarray, band: float, scale: float, form: int,
                    state: np.ndarray) -> np.ndarray:
    """Stretch travel (|movement| of S_hat through a play of +-band) -> history regressor."""
    play, travel, started = state[0], state[1], state[2]
    out = np.empty(s.size)
    for k in range(s.size):
        if not math.isfinite(s[k]):
            out[k] = math.nan
            continue
        if started == 0.0:
            play, started = s[k], 1.0
        moved = min(max(play, s[k] - band), s[k] + band)
        travel += abs(moved - play)
        play = moved
        h = 1.0 - math.exp(-travel / scale) if form in (0, 2) else math.log1p(travel / scale)
        out[k] = h * s[k] if form >= 2 else h
    state[0], state[1], state[2] = play, travel, started
    return out


class Stretch(Regressor):
    """Stretch history: the strain travel sum |dS_hat| since the start, through a play of +-band."""

    kind = "stretch"
    readers = param_readers(form=choice(STRETCH_FORMS, "rest"), scale=positive(1000.0),
                            band=number(0.5, lo=0.0))
    initial = (0.0, 0.0, 0.0)
    form: str
    scale: float
    band: float

    def run(self, batch: Batch) -> np.ndarray:
        return _stretch_kernel(batch.s_hat, self.band, self.scale, STRETCH_FORMS.index(self.form),
                               self._state)


@njit
def _baseline_kernel(t: np.ndarray, s: np.ndarray, window: float,
                     state: np.ndarray) -> np.ndarray:
    """Running mean of S_hat over the first ``window`` seconds after (re)start, then held."""
    t0, total, count = state[0], state[1], state[2]
    out = np.empty(t.size)
    for k in range(t.size):
        if count == 0.0:
            t0 = t[k]
        if t[k] - t0 <= window:
            total += s[k]
            count += 1.0
        out[k] = total / count
    state[0], state[1], state[2] = t0, total, count
    return out


class Baseline(Regressor):
    """Run-to-run baseline: g = mean S_hat over the first ``window`` s after a start, - ``rest``."""

    kind = "baseline"
    readers = param_readers(window=positive(5.0), rest=number(0.0))
    initial = (0.0, 0.0, 0.0)
    window: float
    rest: float

    def run(self, batch: Batch) -> np.ndarray:
        return _baseline_kernel(batch.t, batch.s_hat, self.window, self._state) - self.rest
