"""Bounded Levenberg-Marquardt for the output-error refinement of the APL family's fit
([Electrolycra] eq. (2), (3)); why not scipy's least_squares: docs/models.md.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear

from strain_comp._numba import njit

Residuals = Callable[[np.ndarray], np.ndarray]
NormalEquations = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def bounded_lm(residuals: Residuals, normal_equations: NormalEquations, theta: np.ndarray,
               lo: np.ndarray, hi: np.ndarray, *, max_nfev: int, ftol: float = 1e-9,
               lam: float = 1e-3) -> np.ndarray:
    """theta (within [lo, hi]) with sum residuals(theta)^2 no larger than at the start; a
    bounded Levenberg-Marquardt. Stops when a step lowers the cost by less than ``ftol``
    times the cost, or when the damping cannot find a lower cost."""
    theta = np.clip(np.asarray(theta, dtype=np.float64), lo, hi)
    res = residuals(theta)
    cost = float(res @ res)
    nfev = 1
    while nfev < max_nfev and np.isfinite(cost) and cost > 0.0:
        gram, grad = normal_equations(theta, res)
        scale = np.maximum(np.diag(gram), 1e-12 * max(float(np.max(np.diag(gram))), 1e-300))
        improved = False
        while nfev < max_nfev and lam < 1e12:
            damped = gram + np.diag(lam * scale)
            try:
                factor = np.linalg.cholesky(damped).T
            except np.linalg.LinAlgError:
                lam *= 4.0
                continue
            target = -solve_triangular(factor, grad, trans="T")
            step = lsq_linear(factor, target, bounds=(lo - theta, hi - theta),
                              method="bvls").x
            trial = np.clip(theta + step, lo, hi)
            trial_res = residuals(trial)
            nfev += 1
            trial_cost = float(trial_res @ trial_res)
            if trial_cost < cost:
                gain = cost - trial_cost
                theta, res, cost = trial, trial_res, trial_cost
                lam = max(lam / 3.0, 1e-12)
                improved = gain > ftol * cost
                break
            lam *= 4.0
        if not improved:
            break
    return theta


@njit(fastmath=True)
def output_jacobian(z: np.ndarray, psi_hat: np.ndarray, res: np.ndarray, slopes: np.ndarray,
                    edges: np.ndarray, c: int, out: np.ndarray) -> None:
    """Rows [z_i / f'(psi_hat_i), -G_j(psi_hat_i) / f'(psi_hat_i) for j != c, res_i]: the
    Jacobian of psi_hat = f^-1(w . z) with respect to (w, slopes of f except the fixed
    central one ``c``), plus the residuals as a last column, so that one matrix product gives
    J^T J and J^T res. G_j is the signed length of segment j on the path 0 -> psi
    (``pwa.path_matrix``)."""
    n_w = z.shape[1]
    m = slopes.size
    last = out.shape[1] - 1
    for i in range(z.shape[0]):
        ph = psi_hat[i]
        seg = 0
        while seg < m - 1 and edges[seg] < ph:
            seg += 1
        inv = 1.0 / slopes[seg]
        for q in range(n_w):
            out[i, q] = z[i, q] * inv
        col = n_w
        for j in range(m):
            if j == c:
                continue
            g = 0.0
            if j < c:  # left of 0: segment j spans [edges[j - 1], edges[j]]
                if ph < edges[j]:
                    g = max(ph, edges[j - 1]) - edges[j] if j > 0 else ph - edges[j]
            elif ph > edges[j - 1]:
                g = min(ph, edges[j]) - edges[j - 1] if j < m - 1 else ph - edges[j - 1]
            out[i, col] = -g * inv
            col += 1
        out[i, last] = res[i]
