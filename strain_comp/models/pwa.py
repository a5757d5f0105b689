"""Strictly increasing piecewise-affine output map f of the APL family ([Electrolycra]
eq. (3)); the basis (breakpoints, dead zones, ``mu``'s order): docs/models.md.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit


def breakpoints(m: int) -> np.ndarray:
    """The M - 1 breakpoints b_i = -1 + 2 i / M, i = 1 .. M-1."""
    return -1.0 + 2.0 * np.arange(1, m) / m


def slopes_from_mu(mu: npt.ArrayLike) -> np.ndarray:
    """Slopes of the M segments (left to right) of f with basis coefficients ``mu``."""
    mu = np.asarray(mu, dtype=np.float64)
    m = mu.size
    slopes = np.full(m, mu[0])
    for i, bi in enumerate(_breakpoint_paths(m)[0].tolist()):
        if bi > 0:
            slopes[i + 1:] += mu[1 + i]   # right of b_i
        else:
            slopes[: i + 1] += mu[1 + i]  # left of b_i
    return slopes


def mu_from_slopes(slopes: npt.ArrayLike) -> np.ndarray:
    slopes = np.asarray(slopes, dtype=np.float64)
    m = slopes.size
    c = (m - 1) // 2
    mu = np.empty(m)
    mu[0] = slopes[c]
    for i in range(m - 1):
        mu[1 + i] = slopes[i + 1] - slopes[i] if i >= c else slopes[i] - slopes[i + 1]
    return mu


def path_matrix(psi: npt.ArrayLike, m: int) -> np.ndarray:
    """G (n, M) with f(psi) = G @ slopes: signed length of segment j on the path 0 -> psi."""
    x = np.atleast_1d(np.asarray(psi, dtype=np.float64))
    edges = np.concatenate(([-np.inf], breakpoints(m), [np.inf]))
    lo, hi = edges[:-1], edges[1:]
    origin: npt.NDArray[np.float64] = np.clip(0.0, lo, hi)  # 0 clipped into each segment
    return np.clip(x[:, None], lo, hi) - origin


def slope_tables(slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tables ``finv`` reads, of f given by its M segment slopes (``slopes_from_mu``)."""
    b, paths = _breakpoint_paths(slopes.size)
    return b.copy(), paths @ slopes, 1.0 / slopes


@cache
def _breakpoint_paths(m: int) -> tuple[np.ndarray, np.ndarray]:
    """(breakpoints, ``path_matrix`` at them) of M segments, read-only, computed once per M."""
    b = breakpoints(m)
    paths = path_matrix(b, m)
    b.flags.writeable = False
    paths.flags.writeable = False
    return b, paths


@njit
def finv(y: float, b: np.ndarray, f_at_b: np.ndarray, inv_slopes: np.ndarray) -> float:
    """Exact inverse of the PWA f given its tables (see ``slope_tables``)."""
    j = 0
    nb = b.size
    while j < nb and f_at_b[j] < y:
        j += 1
    if j == 0:
        if nb == 0:
            return float(y * inv_slopes[0])
        return float(b[0] + (y - f_at_b[0]) * inv_slopes[0])
    return float(b[j - 1] + (y - f_at_b[j - 1]) * inv_slopes[j])


@njit
def finv_array(y: np.ndarray, b: np.ndarray, f_at_b: np.ndarray,
               inv_slopes: np.ndarray) -> np.ndarray:
    out = np.empty(y.size)
    for i in range(y.size):
        out[i] = finv(y[i], b, f_at_b, inv_slopes)
    return out
