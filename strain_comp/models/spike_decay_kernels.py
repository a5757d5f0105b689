"""numba kernels of the spike-and-decay model ([Nanocomposite] eq. (3), (4)): the
quasi-static curve and its inverse, the (rate x strain) table lookup, and the online
inversion; docs/models.md gives the method."""

from __future__ import annotations

import math

import numpy as np

from strain_comp._numba import njit
from strain_comp.base.direction import STATE_SIZE, direction_update

# kernel state layout after the detector's STATE_SIZE entries
(_STARTED, _MOVING, _T_MOVE, _EPS_MOVE, _TS, _S, _LAM, _EPS, _T_LAST, _T_EXT, _R_EXT,
 _RC_EXT) = range(STATE_SIZE, STATE_SIZE + 12)
STATE_LEN = STATE_SIZE + 12
_BISECT = 60


@njit
def f_eval(knots: np.ndarray, c: np.ndarray, eps: float) -> float:
    """Quasi-static curve eq. (4): the piece whose knot is the last one <= eps."""
    i = 0
    while i + 1 < knots.size and eps >= knots[i + 1]:
        i += 1
    d = eps - knots[i]
    return float(((c[i, 3] * d + c[i, 2]) * d + c[i, 1]) * d + c[i, 0])


@njit
def f_invert(knots: np.ndarray, c: np.ndarray, lo: float, hi: float, r: float) -> float:
    """eps in [lo, hi] with f(eps) = r on the monotone branch, clamped at the ends."""
    f_lo = f_eval(knots, c, lo)
    f_hi = f_eval(knots, c, hi)
    rising = f_hi > f_lo
    if (r <= f_lo) == rising:
        return lo
    if (r >= f_hi) == rising:
        return hi
    a, b = lo, hi
    for _ in range(_BISECT):
        m = 0.5 * (a + b)
        if (f_eval(knots, c, m) < r) == rising:
            a = m
        else:
            b = m
        if b - a <= 1e-13 * (1.0 + abs(m)):
            break
    return 0.5 * (a + b)


@njit
def _axis(grid: np.ndarray, x: float) -> tuple[int, float]:
    """Cell index and weight for linear interpolation on ``grid``, clamped at the edges."""
    if grid.size == 1 or x <= grid[0]:
        return 0, 0.0
    if x >= grid[-1]:
        return grid.size - 2, 1.0
    i = 0
    while x >= grid[i + 1]:
        i += 1
    return i, (x - grid[i]) / (grid[i + 1] - grid[i])


@njit
def table_lookup(table: np.ndarray, log_rates: np.ndarray, strains: np.ndarray, rate: float,
                 eps: float) -> float:
    """Bilinear interpolation in (log10 rate, strain), clamped; rate <= 0 -> lowest rate."""
    x = math.log10(rate) if rate > 0.0 else -1e300
    i, u = _axis(log_rates, x)
    j, v = _axis(strains, eps)
    i1 = min(i + 1, log_rates.size - 1)
    j1 = min(j + 1, strains.size - 1)
    return float((1 - u) * (1 - v) * table[i, j] + u * (1 - v) * table[i1, j]
                 + (1 - u) * v * table[i, j1] + u * v * table[i1, j1])


@njit
def spike_decay_kernel(state: np.ndarray, t: np.ndarray, r: np.ndarray, knots: np.ndarray,
                       c: np.ndarray, lo: float, hi: float, log_rates: np.ndarray,
                       strains: np.ndarray, s_tab: np.ndarray, lam_tab: np.ndarray,
                       min_step: float, deadzone: float, tau: float) -> np.ndarray:
    """Online inversion of eq. (3) (docs/models.md, "spike_decay")."""
    out = np.empty(t.size)
    for n in range(t.size):
        tn = t[n]
        rn = r[n]
        if state[_STARTED] == 0.0:
            state[_STARTED] = 1.0
            direction_update(state, tn, rn, deadzone, tau)
            eps = f_invert(knots, c, lo, hi, rn)
        else:
            factor = 1.0
            if state[_S] != 0.0:
                factor = 1.0 + state[_S] * math.exp(-state[_LAM] * max(tn - state[_TS], 0.0))
            r_c = rn / factor
            d = direction_update(state, tn, r_c, deadzone, tau)
            moving = int(state[_MOVING])
            if moving == 0 and d != 0:  # a movement starts
                moving = d
                state[_MOVING] = float(d)
                state[_T_MOVE] = state[_T_LAST]
                state[_EPS_MOVE] = state[_EPS]
                state[_T_EXT] = tn
                state[_R_EXT] = rn
                state[_RC_EXT] = r_c
            elif moving != 0 and (r_c - state[_RC_EXT]) * moving > 0.0:
                state[_T_EXT] = tn  # furthest point of the movement so far
                state[_R_EXT] = rn
                state[_RC_EXT] = r_c
            eps = f_invert(knots, c, lo, hi, r_c)
            if moving != 0 and d != moving:  # the movement ended: ts = its furthest point
                t_end = state[_T_EXT]
                duration = max(t_end - state[_T_MOVE], 1e-9)
                eps_end = f_invert(knots, c, lo, hi, state[_RC_EXT])
                if abs(eps_end - state[_EPS_MOVE]) >= min_step:
                    s_new = 0.0
                    lam = 1.0
                    for _ in range(3):
                        change = eps_end - state[_EPS_MOVE]
                        k = 0 if change >= 0.0 else 1
                        rate = abs(change) / duration
                        s_new = table_lookup(s_tab[k], log_rates, strains, rate, eps_end)
                        lam = table_lookup(lam_tab[k], log_rates, strains, rate, eps_end)
                        eps_end = f_invert(knots, c, lo, hi, state[_R_EXT] / (1.0 + s_new))
                    state[_TS] = t_end
                    state[_S] = s_new
                    state[_LAM] = lam
                    r_c = rn / (1.0 + s_new * math.exp(-lam * (tn - t_end)))
                    eps = f_invert(knots, c, lo, hi, r_c)
                state[_MOVING] = 0.0
                # the detector restarts on the compensated resistance
                state[1] = tn
                state[2] = r_c
                state[3] = 0.0
                state[4] = 0.0
        state[_EPS] = eps
        state[_T_LAST] = tn
        out[n] = eps
    return out
