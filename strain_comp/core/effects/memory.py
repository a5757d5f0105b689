"""Effect terms with a fading memory: rate, relaxation after strain steps, and the memory of
the resistance itself."""

from __future__ import annotations

import math

import numpy as np

from strain_comp._numba import njit
from strain_comp.core.effects.regressor import (
    Batch,
    Regressor,
    choice,
    param_readers,
    positive,
)


@njit
def _step_kernel(t: np.ndarray, u: np.ndarray, d: np.ndarray, tau: float, rate: bool,
                 branch: int, state: np.ndarray) -> np.ndarray:
    """Rate y' = (du/dt - y) / tau, or relaxation h_k = h_{k-1} exp(-dt/tau) + du_k [in branch]."""
    y, u_prev, t_prev, started = state[0], state[1], state[2], state[3]
    out = np.empty(t.size)
    for k in range(t.size):
        if started > 0.0:
            dt = t[k] - t_prev
            if rate and dt > 0.0:
                y += (1.0 - math.exp(-dt / tau)) * ((u[k] - u_prev) / dt - y)
            elif not rate:
                y *= math.exp(-dt / tau)
                if branch == 0 or (branch == 1 and d[k] > 0) or (branch == 2 and d[k] < 0):
                    y += u[k] - u_prev
        started = 1.0
        u_prev = u[k]
        t_prev = t[k]
        out[k] = d[k] * y if rate and branch == 1 else y
    state[0], state[1], state[2], state[3] = y, u_prev, t_prev, started
    return out


class Rate(Regressor):
    """Strain rate dS_hat/dt low-passed with ``tau`` [s] (``mode: direction``: times d)."""

    kind = "rate"
    readers = param_readers(tau=positive(1.0), mode=choice(("signed", "direction"), "signed"))
    initial = (0.0, 0.0, 0.0, 0.0)
    tau: float
    mode: str

    def run(self, batch: Batch) -> np.ndarray:
        return _step_kernel(batch.t, batch.s_hat, batch.direction, self.tau, True,
                            int(self.mode == "direction"), self._state)


_BRANCHES = ("both", "loading", "unloading")


class Relaxation(Regressor):
    """Decaying memory h = S_hat - x of strain changes (x' = (S_hat - x) / tau), per ``branch``."""

    kind = "relaxation"
    readers = param_readers(tau=positive(10.0), branch=choice(_BRANCHES, "both"))
    initial = (0.0, 0.0, 0.0, 0.0)
    tau: float
    branch: str

    def run(self, batch: Batch) -> np.ndarray:
        return _step_kernel(batch.t, batch.s_hat, batch.direction, self.tau, False,
                            _BRANCHES.index(self.branch), self._state)


_MEMORY_FORMS = ("relaxation", "peak", "trough")


@njit
def _resistance_memory_kernel(t: np.ndarray, r: np.ndarray, tau: float, form: int,
                              state: np.ndarray) -> np.ndarray:
    """g = y - m (peak: m - y); y = 100 ln R, m relaxing to it (peak: >= y, trough: <= y)."""
    m, y_prev, t_prev, started = state[0], state[1], state[2], state[3]
    out = np.empty(t.size)
    for k in range(t.size):
        y = 100.0 * math.log(max(r[k], 1e-300))
        if started > 0.0:
            m = y_prev + (m - y_prev) * math.exp(-(t[k] - t_prev) / tau)
        else:
            m = y
        if form == 1:
            m = max(m, y)
        elif form == 2:
            m = min(m, y)
        started = 1.0
        y_prev = y
        t_prev = t[k]
        out[k] = m - y if form == 1 else y - m
    state[0], state[1], state[2], state[3] = m, y_prev, t_prev, started
    return out


class ResistanceMemory(Regressor):
    """Fading memory of 100 ln R: the part still relaxing, or the fall from a spike (or dip)."""
    # R, not S_hat: where R is not monotone in strain or overshoots the range, S_hat lost it

    kind = "resistance_memory"
    readers = param_readers(tau=positive(10.0), form=choice(_MEMORY_FORMS, "relaxation"))
    initial = (0.0, 0.0, 0.0, 0.0)
    tau: float
    form: str

    def rescale(self, factor: float) -> None:
        """y and its memory shift by 100 ln(factor): g is unchanged."""
        self._state[:2] += 100.0 * math.log(factor)

    def run(self, batch: Batch) -> np.ndarray:
        return _resistance_memory_kernel(batch.t, batch.r, self.tau,
                                         _MEMORY_FORMS.index(self.form), self._state)
