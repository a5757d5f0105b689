"""numba kernels of the APL / PL / MPI cells ([Electrolycra] eq. (1), (2), appendix eq. (6)):
one cell update (``advance_cells``) serves the run, array and fit kernels (docs/models.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from strain_comp._numba import njit
from strain_comp.models.pwa import finv

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # no nnan/ninf: NaN checks stay

KIND_APL = 0
KIND_PL = 1

P_MIN = 0.05  # smallest exponent p accepted (z^p for tiny z must stay negligible)
P_MAX = 20.0


_Codegen = Callable[[Any, Any, Any, Any], Any]


@intrinsic
def _bits(typingctx: Any, x: Any) -> tuple[Any, _Codegen]:
    """Reinterpret a float64 as int64 (a free bit cast, vectorisable)."""
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.bitcast(args[0], ir.IntType(64))
    return types.int64(types.float64), codegen


@intrinsic
def _float(typingctx: Any, x: Any) -> tuple[Any, _Codegen]:
    """Reinterpret an int64 as float64."""
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LG1, _LG2, _LG3, _LG4 = (6.666666666666735130e-01, 3.999999999940941908e-01,
                          2.857142874366239149e-01, 2.222219843214978396e-01)
_LG5, _LG6, _LG7 = 1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01
_TINY = 1e-300  # lower guard of z: tiny^p with p >= P_MIN is < 1e-15


@njit(fastmath=FASTMATH, error_model="numpy", inline="always")
def pow01(z: float, p: float) -> float:
    """z^p for a positive normal z <= ~1 and p > 0 (results below ~1e-304 flush to ~0)."""
    # numba passes the typing context of an intrinsic itself
    bits: int = _bits(z)  # type: ignore[call-arg]
    e = (bits >> 52) - 1023
    m = _float((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # z = m 2^e, m in [1, 2)
    big = m > 1.4142135623730951
    m = m * 0.5 if big else m
    ef = float(e + 1) if big else float(e)
    f = m - 1.0
    s = f / (2.0 + f)
    s2 = s * s
    s4 = s2 * s2
    r = s4 * (_LG2 + s4 * (_LG4 + s4 * _LG6)) + s2 * (_LG1 + s4 * (_LG3 + s4 * (_LG5 + s4 * _LG7)))
    hfsq = 0.5 * f * f
    log_z = ef * _LN2_HI - ((hfsq - (s * (hfsq + r) + ef * _LN2_LO)) - f)
    y = max(p * log_z, -700.0)
    nf = math.floor(y * 1.4426950408889634 + 0.5)
    q = (y - nf * _LN2_HI) - nf * _LN2_LO  # |q| <= ln2 / 2
    # degree-13 Taylor polynomial by Estrin's scheme (4 dependent steps instead of 13)
    q2 = q * q
    q4 = q2 * q2
    q8 = q4 * q4
    e0 = (1.0 + q) + q2 * (1 / 2 + q * (1 / 6))
    e4 = (1 / 24 + q * (1 / 120)) + q2 * (1 / 720 + q * (1 / 5040))
    e8 = (1 / 40320 + q * (1 / 362880)) + q2 * (1 / 3628800 + q * (1 / 39916800))
    e12 = 1 / 479001600 + q * (1 / 6227020800)
    ex = (e0 + q4 * e4) + q8 * (e8 + q4 * e12)
    return ex * _float((np.int64(nf) + 1023) << 52)


@njit(fastmath=FASTMATH, error_model="numpy")
def advance_cells(x: np.ndarray, xi: float, sdt: float, p: float, rho: np.ndarray,
                  inv_width: np.ndarray, kind: int) -> None:
    """One time step of all N cells in place. Branch-free inner loops (vectorised)."""
    n = x.size
    if kind == KIND_APL:
        hi = xi + 1.0
        if sdt > 0.0:
            for k in range(n):
                xk = min(max(x[k], xi - rho[k]), hi)
                z = max((hi - xk) * inv_width[k], _TINY)
                x[k] = min(xk + sdt * pow01(z, p), hi)
        else:
            for k in range(n):
                x[k] = min(max(x[k], xi - rho[k]), hi)
    else:
        if sdt > 0.0:
            for k in range(n):
                xk = min(max(x[k], xi - rho[k]), xi + rho[k])
                d = xi - xk
                step = sdt * pow01(max(abs(d) * inv_width[k], _TINY), p)
                x[k] = min(xk + step, xi) if d > 0.0 else max(xk - step, xi)
        else:
            for k in range(n):
                x[k] = min(max(x[k], xi - rho[k]), xi + rho[k])


@njit(fastmath=FASTMATH, error_model="numpy")
def relax_cells(x: np.ndarray, xi: float, kind: int) -> None:
    """Initial state at input xi: the creep equilibrium (xi + 1 for APL, xi for PL/MPI)."""
    value = xi + 1.0 if kind == KIND_APL else xi
    for k in range(x.size):
        x[k] = value


@njit(fastmath=FASTMATH, error_model="numpy")
def output(x: np.ndarray, xi: float, w: np.ndarray, b: np.ndarray, f_at_b: np.ndarray,
           inv_slopes: np.ndarray) -> float:
    """psi = f^-1(w_0 xi + sum_k w_k x_k + w_{N+1}) (eq. (2))."""
    n = x.size
    y = w[0] * xi + w[n + 1]
    for k in range(n):
        y += w[k + 1] * x[k]
    return finv(y, b, f_at_b, inv_slopes)


LANES = 4  # cells are advanced in groups of this many (the SIMD width of AVX2 doubles)


@njit(fastmath=FASTMATH, error_model="numpy")
def padded_cells(x: np.ndarray, rho: np.ndarray, inv_width: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, rho, inv_width padded to whole ``LANES`` by the last cell (no scalar remainder)."""
    n = x.size
    m = -(-n // LANES) * LANES
    xp = np.empty(m)
    rho_p = np.empty(m)
    inv_width_p = np.empty(m)
    xp[:n] = x
    rho_p[:n] = rho
    inv_width_p[:n] = inv_width
    for k in range(n, m):
        xp[k] = x[n - 1]
        rho_p[k] = rho[n - 1]
        inv_width_p[k] = inv_width[n - 1]
    return xp, rho_p, inv_width_p


@njit(fastmath=FASTMATH, error_model="numpy")
def run_kernel(t: np.ndarray, r: np.ndarray, x: np.ndarray, clock: np.ndarray,
               out: np.ndarray, kind: int, sigma: float, p: float, rho: np.ndarray,
               inv_width: np.ndarray, w: np.ndarray, norm: np.ndarray, b: np.ndarray,
               f_at_b: np.ndarray, inv_slopes: np.ndarray) -> None:
    """Advance one sensor over arrays (t, r)."""
    r0, alpha, s0, beta = norm[0], norm[1], norm[2], norm[3]
    n = x.size
    xp, rho_p, inv_width_p = padded_cells(x, rho, inv_width)
    cells = xp[:n]
    for i in range(t.size):
        ti = t[i]
        ri = r[i]
        if not (math.isfinite(ti) and math.isfinite(ri) and ri > 0.0):
            out[i] = np.nan
            continue
        xi = ri / r0 + alpha
        if clock[1] == 0.0:
            relax_cells(xp, xi, kind)
            clock[1] = 1.0
        else:
            dt = ti - clock[0]
            advance_cells(xp, xi, sigma * max(dt, 0.0), p, rho_p, inv_width_p, kind)
        clock[0] = ti
        out[i] = (output(cells, xi, w, b, f_at_b, inv_slopes) - beta) * s0
    x[:] = cells


@njit(fastmath=FASTMATH, error_model="numpy")
def step_sensor(s: int, t: float, ri: float, x: np.ndarray, clock: np.ndarray,
                kind: np.ndarray, sigma: np.ndarray, p: np.ndarray, w: np.ndarray,
                norm: np.ndarray, f_at_b: np.ndarray, inv_slopes: np.ndarray, rho: np.ndarray,
                inv_width: np.ndarray, b: np.ndarray) -> float:
    """Advance sensor s of an array by a good sample: row s, rho and inv_width by kind."""
    xi = ri / norm[s, 0] + norm[s, 1]
    ks = kind[s]
    xs = x[s]
    if clock[s, 1] == 0.0:
        relax_cells(xs, xi, ks)
        clock[s, 1] = 1.0
    else:
        dt = t - clock[s, 0]
        advance_cells(xs, xi, sigma[s] * max(dt, 0.0), p[s], rho[ks], inv_width[ks], ks)
    clock[s, 0] = t
    psi = output(xs, xi, w[s], b, f_at_b[s], inv_slopes[s])
    return float((psi - norm[s, 3]) * norm[s, 2])


@njit(fastmath=FASTMATH, error_model="numpy")
def states_kernel(t: np.ndarray, xi: np.ndarray, starts: np.ndarray, kind: int, sigma: float,
                  p: float, rho: np.ndarray, inv_width: np.ndarray) -> np.ndarray:
    """Cell states over concatenated training segments."""
    n = t.size
    x, rho_p, inv_width_p = padded_cells(np.zeros(rho.size), rho, inv_width)
    states = np.empty((n, rho.size))
    t_prev = 0.0
    for i in range(n):
        if starts[i]:
            relax_cells(x, xi[i], kind)
        else:
            advance_cells(x, xi[i], sigma * max(t[i] - t_prev, 0.0), p, rho_p, inv_width_p,
                          kind)
        t_prev = t[i]
        states[i, :] = x[:rho.size]
    return states


def thresholds(n: int, kind: int) -> np.ndarray:
    """rho_k, k = 1..N: 2k/(N+1) - 1 for APL (eq. (1)), k/(N+1) for PL (eq. (6))."""
    k = np.arange(1, n + 1, dtype=np.float64)
    return 2.0 * k / (n + 1) - 1.0 if kind == KIND_APL else k / (n + 1)


def inverse_widths(rho: np.ndarray, kind: int) -> np.ndarray:
    """1 / (rho_k + 1) for APL, 1 / rho_k for PL: the normalisers of the power law."""
    return 1.0 / (rho + 1.0) if kind == KIND_APL else 1.0 / rho
