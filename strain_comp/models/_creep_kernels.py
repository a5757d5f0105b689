"""numba kernels of the creep_pi model (``strain_comp.models.creep_pi``).

One state update (``advance``) serves the streaming kernel (``run_kernel``: ``run`` and
``step``) and the fitting kernel (``features_kernel``, with the feature map ``features``),
so the fitted and the streamed model compute the same states.

State of one sensor: ``z`` (K,) the low-pass states of xi, ``play`` (J + 1,) the play
operators (the last one the direction play of width ``widths[J]``), ``clock`` =
[t_prev, started, dt of the cached decays], ``decay`` (K,) = 1 - exp(-dt / tau_k) for that
dt (recomputed only when dt changes: at a fixed sample rate the exponentials are paid once).

Per good sample xi at time t (dt = t - t_prev, a negative dt taken as 0):

* first sample after construction or ``reset`` (the sensor at rest): z_k = xi, every play
  operator at its rest value xi; no update;
* else z_k <- z_k + (1 - exp(-dt / tau_k)) (xi - z_k) (the exact solution of
  tau dz/dt = xi - z for an input held over the step), and each play operator
  p_j <- clip(p_j, xi - r_j, xi + r_j) ([Electrolycra] appendix eq. (6) with sigma = 0).

Features (``N_FIXED + J + K`` per sample, in this order): xi, xi^2, xi^3; xi - p_j for the J
play operators; xi - z_k for the K time constants; d = xi - p_dir in [-r_dir, r_dir] (r_dir
times the movement direction: r_dir once xi has risen by 2 r_dir since its last fall,
-r_dir once it has fallen so far; between, linear in xi) and d xi.

Bad samples (r not finite or <= 0, t not finite) advance nothing and give NaN.
"""

from __future__ import annotations

import math

import numpy as np

from strain_comp._numba import njit
from strain_comp.models._apl_kernels import FASTMATH

N_FIXED = 5
"""Features besides the play and creep ones: xi, xi^2, xi^3, d, d xi."""


@njit(fastmath=FASTMATH, error_model="numpy", inline="always")
def advance(ti: float, xi: float, z: np.ndarray, play: np.ndarray, clock: np.ndarray,
            decay: np.ndarray, tau: np.ndarray, widths: np.ndarray) -> None:
    """One sample's state update in place (module docstring)."""
    if clock[1] == 0.0:
        for k in range(z.size):
            z[k] = xi
        for j in range(play.size):
            play[j] = xi
        clock[1] = 1.0
    else:
        dt = max(ti - clock[0], 0.0)
        if dt != clock[2]:
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
    """The feature vector of the current state into ``row`` (module docstring)."""
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


@njit(fastmath=FASTMATH, error_model="numpy")
def run_kernel(t: np.ndarray, r: np.ndarray, z: np.ndarray, play: np.ndarray,
               clock: np.ndarray, decay: np.ndarray, out: np.ndarray, norm: np.ndarray,
               tau: np.ndarray, widths: np.ndarray, w: np.ndarray, bias: float) -> None:
    """Advance one sensor over arrays (t, r); strain % into ``out``.

    ``norm`` = [r0, alpha, s0, beta]; psi = bias + w . features (``w`` the weights of the
    raw features, the standardisation folded in), summed as a polynomial in xi minus the
    weighted states (the same sum, regrouped: ``features`` is not built per sample).
    """
    r0, alpha, s0, beta = norm[0], norm[1], norm[2], norm[3]
    n_play = play.size - 1
    n_tau = z.size
    # w . features regrouped: the memory features' xi parts join the linear coefficient
    c1 = w[0]
    for j in range(n_play + n_tau):
        c1 += w[3 + j]
    c2, c3 = w[1], w[2]
    w_play = w[3:3 + n_play]
    w_creep = w[3 + n_play:3 + n_play + n_tau]
    w_d, w_dx = w[3 + n_play + n_tau], w[4 + n_play + n_tau]
    for i in range(t.size):
        ti = t[i]
        ri = r[i]
        if not (math.isfinite(ti) and math.isfinite(ri) and ri > 0.0):
            out[i] = np.nan
            continue
        xi = ri / r0 + alpha
        advance(ti, xi, z, play, clock, decay, tau, widths)
        psi = bias + xi * (c1 + xi * (c2 + xi * c3))
        for j in range(n_play):
            psi -= w_play[j] * play[j]
        for k in range(n_tau):
            psi -= w_creep[k] * z[k]
        psi += (xi - play[n_play]) * (w_d + w_dx * xi)
        out[i] = (psi - beta) * s0


@njit(fastmath=FASTMATH, error_model="numpy")
def features_kernel(t: np.ndarray, xi: np.ndarray, z: np.ndarray, play: np.ndarray,
                    clock: np.ndarray, decay: np.ndarray, tau: np.ndarray,
                    widths: np.ndarray, rows: np.ndarray) -> None:
    """Features (n, N_FIXED + J + K) of good samples (t, xi) from the given state, which is
    left where ``run_kernel`` would leave it (a segment is fed in chunks)."""
    for i in range(t.size):
        advance(t[i], xi[i], z, play, clock, decay, tau, widths)
        features(rows[i], xi[i], z, play)
