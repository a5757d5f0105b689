"""numba kernels of the creep_pi model: one state update (``advance``) serves the streaming
and the fitting kernels, so both compute the same states (docs/models.md).
"""

from __future__ import annotations

import math

import numpy as np

from strain_comp._numba import njit
from strain_comp.models.apl_kernels import FASTMATH as FASTMATH

DT_TOLERANCE = 1e-6  # share of the cached dt within which a step reuses its decays
N_FIXED = 5  # features besides the play and creep ones: xi, xi^2, xi^3, d, d xi


@njit(fastmath=FASTMATH, error_model="numpy", inline="always")
def advance(ti: float, xi: float, z: np.ndarray, play: np.ndarray, clock: np.ndarray,
            decay: np.ndarray, tau: np.ndarray, widths: np.ndarray) -> None:
    """One sample's state update in place."""
    if clock[1] == 0.0:
        for k in range(z.size):
            z[k] = xi
        for j in range(play.size):
            play[j] = xi
        clock[1] = 1.0
        clock[2] = -1.0  # the cached decays are of no dt yet (a reset may zero the clock)
    else:
        dt = max(ti - clock[0], 0.0)
        if abs(dt - clock[2]) > DT_TOLERANCE * dt:
            for k in range(z.size):
                decay[k] = -math.expm1(-dt / tau[k])
            clock[2] = dt
        for k in range(z.size):
            z[k] += decay[k] * (xi - z[k])
        for j in range(play.size):
            play[j] = min(max(play[j], xi - widths[j]), xi + widths[j])
    clock[0] = ti


@njit(fastmath=FASTMATH, error_model="numpy", inline="always")
def features(row: np.ndarray, xi: float, z: np.ndarray, play: np.ndarray) -> None:
    """The feature vector of the current state into ``row``."""
    n_play = play.size - 1
    row[0] = xi
    row[1] = xi * xi
    row[2] = xi * xi * xi
    for j in range(n_play):
        row[3 + j] = xi - play[j]
    for k in range(z.size):
        row[3 + n_play + k] = xi - z[k]
    d = xi - play[n_play]
    row[3 + n_play + z.size] = d
    row[4 + n_play + z.size] = d * xi


def folded(w: np.ndarray, n_play: int, n_tau: int) -> np.ndarray:
    """``w`` regrouped for ``output``: every memory feature's xi folded into c1, states -w."""
    coef = np.empty(w.size)
    coef[0] = w[0] + w[3:3 + n_play + n_tau].sum()
    coef[1:3] = w[1:3]
    coef[3:3 + n_play + n_tau] = -w[3:3 + n_play + n_tau]
    coef[3 + n_play + n_tau:] = w[3 + n_play + n_tau:]
    return coef


@njit(fastmath=FASTMATH, error_model="numpy", inline="always")
def output(xi: float, z: np.ndarray, play: np.ndarray, coef: np.ndarray, bias: float
           ) -> float:
    """psi = bias + w . features, through the ``folded`` weights."""
    n_play = play.size - 1
    psi = bias + xi * (coef[0] + xi * (coef[1] + xi * coef[2]))
    for j in range(n_play):
        psi += coef[3 + j] * play[j]
    for k in range(z.size):
        psi += coef[3 + n_play + k] * z[k]
    return float(psi + (xi - play[n_play]) * (coef[3 + n_play + z.size]
                                              + coef[4 + n_play + z.size] * xi))


@njit(fastmath=FASTMATH, error_model="numpy")
def run_kernel(t: np.ndarray, r: np.ndarray, z: np.ndarray, play: np.ndarray,
               clock: np.ndarray, decay: np.ndarray, out: np.ndarray, norm: np.ndarray,
               tau: np.ndarray, widths: np.ndarray, coef: np.ndarray, bias: float) -> None:
    """Advance one sensor over arrays (t, r)."""
    r0, alpha, s0, beta = norm[0], norm[1], norm[2], norm[3]
    for i in range(t.size):
        ti = t[i]
        ri = r[i]
        if not (math.isfinite(ti) and math.isfinite(ri) and ri > 0.0):
            out[i] = np.nan
            continue
        xi = ri / r0 + alpha
        advance(ti, xi, z, play, clock, decay, tau, widths)
        out[i] = (output(xi, z, play, coef, bias) - beta) * s0


@njit(fastmath=FASTMATH, error_model="numpy")
def step_sensor(s: int, t: float, ri: float, z: np.ndarray, play: np.ndarray,
                clock: np.ndarray, decay: np.ndarray, norm: np.ndarray, tau: np.ndarray,
                widths: np.ndarray, coef: np.ndarray, bias: np.ndarray) -> float:
    """Advance sensor s of an array by a good sample (row s of every argument)."""
    xi = ri / norm[s, 0] + norm[s, 1]
    advance(t, xi, z[s], play[s], clock[s], decay[s], tau[s], widths[s])
    return float((output(xi, z[s], play[s], coef[s], bias[s]) - norm[s, 3]) * norm[s, 2])


@njit(fastmath=FASTMATH, error_model="numpy")
def features_kernel(t: np.ndarray, xi: np.ndarray, z: np.ndarray, play: np.ndarray,
                    clock: np.ndarray, decay: np.ndarray, tau: np.ndarray,
                    widths: np.ndarray, rows: np.ndarray) -> None:
    """Features of good samples from the given state, left as ``run_kernel`` would leave it."""
    for i in range(t.size):
        advance(t[i], xi[i], z, play, clock, decay, tau, widths)
        features(rows[i], xi[i], z, play)
