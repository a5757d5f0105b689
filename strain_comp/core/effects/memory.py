"""Effect terms with a fading memory: exponentially weighted rate, relaxation after
strain steps, and the memory of the resistance itself."""

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
    """Rate: y' = (du/dt - y) / tau, exact for piecewise-constant du/dt (``branch`` 1: d y).
    Relaxation: h_k = h_{k-1} exp(-dt/tau) + du_k [d_k in branch]: decaying memory of steps."""
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
    """Signed strain rate dS_hat/dt [%/s], low-passed with time constant ``tau`` [s].

    Viscoelastic sensors lag or lead the strain by an amount proportional to its rate
    (rate-dependent hysteresis, [Electrolycra] section I). ``mode: direction`` gives
    d * rate (the detector's direction times the rate): an error of one sign whenever the
    sensor moves, whatever the direction (e.g. self-heating or a rate-dependent gain)."""

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
    """Exponentially decaying memory of recent strain change: relaxation after steps.

    The first-order filter x' = (S_hat - x) / tau gives the regressor h = S_hat - x, which
    jumps with every change of S_hat and decays with time constant ``tau`` [s] once the
    strain is held. A sensor that overshoots after a step and relaxes back (the
    Electrolycra's creep, [Electrolycra] section III; the spike-and-decay of
    [Nanocomposite] eq. (1)) leaves a residual c * h. ``branch: loading``
    (or ``unloading``) accumulates only the changes made while the detector says loading
    (unloading), since relaxation is often strong on loading and weak on unloading.
    Discretised exactly for a piecewise-constant input: h_k = h_{k-1} e^{-dt/tau} + dS_k."""

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
    """y = 100 ln R, held between samples; m relaxes towards it with ``tau`` (``peak``:
    m = max(m, y); ``trough``: m = min(m, y)); g = y - m (``peak``: m - y)."""
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
    """Fading memory of the resistance itself: the part of R still relaxing, or how far R
    stands from a recent spike. It reads R (the resistance the model sees), not S_hat,
    because where R is not monotone in strain (the carbon-black shoulder) or a step's
    overshoot runs past the calibrated range, S_hat has lost what R still shows.

    * ``relaxation``: g = y - m, m' = (y - m) / tau, the share of R [%] above its recent
      average: a relaxation that follows every step of R, whatever its sign;
    * ``peak``: g = p - y, p the peak of y relaxing towards y with ``tau`` and never below
      it: how far R [%] has fallen from a recent spike, the decaying spike of
      [Nanocomposite] eq. (3), read without knowing the step that caused it;
    * ``trough``: g = y - q, the mirror of ``peak`` for sensors whose steps undershoot."""

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
