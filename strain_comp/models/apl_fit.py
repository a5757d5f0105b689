"""The fit of the APL, PL and MPI models ([Electrolycra] section III): the paper's QP on
the cell states, a search over sigma and p, and the output-error refinement (a bounded
Levenberg-Marquardt); docs/models.md gives the method."""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear, minimize

from strain_comp._numba import njit
from strain_comp.base.compensator import Normalisation, Segment
from strain_comp.errors import FitError
from strain_comp.models import apl_kernels as kern
from strain_comp.models import pwa
from strain_comp.models.apl_kernels import P_MAX, inverse_widths, thresholds

LOOP_SWITCH_GAIN = 0.05  # least RMSE share a lagging loop must win by (docs/results.md)
MEMORYLESS_SHARE = 0.01  # below this share of the output from the cells a fit is memoryless
P_GRID = (0.3, 0.45, 0.6, 0.8, 1.0, 1.3, 1.7, 2.2, 3.0)


def fit_cells(name: str, kind: int, rate_dependent: bool, segments: Sequence[Segment],
              normalisation: Normalisation, *, n: int, m: int,
              sigma_grid: npt.ArrayLike | None = None, p_grid: npt.ArrayLike | None = None,
              refine: bool = True, cell_weights: str = "signed", eps: float = 1e-3,
              ridge: float = 1e-6, output_nfev: int = 100, search_nfev: int = 10,
              search_top: int = 5, workers: int | None = None,
              progress: bool | Callable[[str], None] = True
              ) -> tuple[Solution, int, dict[str, Any]]:
    """The fit of an APL, PL or MPI model (docs/models.md): solution, orientation, report."""
    problem = _FitProblem(name, kind, segments, normalisation, n=n, m=m, eps=eps, ridge=ridge,
                          cell_weights=cell_weights, search_nfev=search_nfev)
    if not rate_dependent:
        result = problem.solve(0.0, 1.0, output_nfev=output_nfev)
        return result, problem.orientation, {"rmse": result.rmse, "evaluations": 1,
                                             **problem.memory_report(result)}
    sigmas = (problem.default_sigma_grid() if sigma_grid is None
              else np.asarray(sigma_grid, dtype=np.float64))
    ps = np.asarray(P_GRID if p_grid is None else p_grid, dtype=np.float64)
    say = _progress_printer(progress, name)
    grid = score_grid(problem, sigmas, ps,
                      workers=grid_workers(workers, sigmas.size * ps.size, problem.t.size),
                      say=say)
    best = min(grid, key=_by_rmse)
    if search_nfev > 0:
        ranked = sorted(grid, key=_by_rmse)[:search_top]
        best = min((problem.solve(g.sigma, g.p, output_nfev=search_nfev) for g in ranked),
                   key=_by_rmse)
        say(f"output error on the best {len(ranked)} grid points: rmse {best.rmse:.4g} % "
            f"at sigma={best.sigma:.3g}/s, p={best.p:.3g}")
    if refine:
        best = problem.refine(best)
        say(f"refined: rmse {best.rmse:.4g} % at sigma={best.sigma:.3g}/s, p={best.p:.3g}")
    if output_nfev > search_nfev:
        final = problem.solve(best.sigma, best.p, output_nfev=output_nfev)
        best = min(final, best, key=_by_rmse)
        say(f"output error: rmse {best.rmse:.4g} %")
    return best, problem.orientation, {"rmse": best.rmse, "evaluations": problem.evaluations,
                                       "seconds": time.monotonic() - problem.started,
                                       **problem.memory_report(best)}


def _by_rmse(solution: Solution) -> float:
    return solution.rmse


MIN_THREADED_SAMPLES = 2000  # below: a grid point takes < 1 ms, thread hand-offs cost more


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def grid_workers(requested: int | None, points: int, samples: int) -> int:
    """Threads to score a grid: ``requested``, else a core each but two points per thread."""
    if requested is not None:
        return max(1, min(requested, points))
    if samples < MIN_THREADED_SAMPLES:
        return 1
    return max(1, min(available_cores(), points // 2))


def score_grid(problem: _FitProblem, sigmas: np.ndarray, ps: np.ndarray, *,
               workers: int, say: Callable[[str], None]) -> list[Solution]:
    """Every (sigma, p) of the grid scored by its QP solution, in ``workers`` threads."""
    grid: list[Solution] = []
    if workers <= 1:
        for i, sigma in enumerate(sigmas):
            grid.extend(problem.solve(float(sigma), float(p)) for p in ps)
            _say_row(say, grid, i, sigmas.size, sigma)
        return grid
    with ThreadPoolExecutor(max_workers=workers) as pool:
        jobs = [[pool.submit(problem.solve, float(sigma), float(p)) for p in ps]
                for sigma in sigmas]
        for i, (sigma, row) in enumerate(zip(sigmas, jobs, strict=True)):
            grid.extend(job.result() for job in row)
            _say_row(say, grid, i, sigmas.size, sigma)
    return grid


def _say_row(say: Callable[[str], None], grid: list[Solution], i: int, rows: int,
             sigma: float) -> None:
    best = min(grid, key=_by_rmse)
    say(f"grid row {i + 1}/{rows} (sigma={sigma:.3g}/s): best rmse {best.rmse:.4g} % at "
        f"sigma={best.sigma:.3g}/s, p={best.p:.3g}")


def _progress_printer(progress: bool | Callable[[str], None], name: str) -> Callable[[str], None]:
    started = time.monotonic()

    def say(line: str) -> None:
        if callable(progress):
            progress(f"{name} fit: {line}")
        elif progress and time.monotonic() - started > 2.0:
            print(f"{name} fit: {line}", file=sys.stderr, flush=True)

    return say


@dataclass
class Solution:
    """One solved point of the search: sigma, p, parameter vector and output RMSE [%]."""

    sigma: float
    p: float
    w: np.ndarray
    slopes: np.ndarray
    rmse: float


class _FitProblem:
    """The training data prepared once; ``solve(sigma, p)`` is one QP + output error."""

    def __init__(self, name: str, kind: int, segments: Sequence[Segment],
                 normalisation: Normalisation, *, n: int, m: int, eps: float, ridge: float,
                 cell_weights: str, search_nfev: int) -> None:
        self.name, self.kind, self.norm, self.n, self.m = name, kind, normalisation, n, m
        self.search_nfev = search_nfev
        self.eps, self.started, self.evaluations = eps, time.monotonic(), 0
        self._lock = threading.Lock()
        self.t = np.concatenate([seg.t for seg in segments])
        r = np.concatenate([seg.r for seg in segments])
        s = np.concatenate([seg.s for seg in segments])
        n_params = n + m + 1
        if self.t.size < max(50, 5 * n_params):
            raise FitError(f"{name}: needs at least {max(50, 5 * n_params)} samples for "
                           f"N={n}, M={m}, got {self.t.size}")
        self.xi = normalisation.xi(r)
        self.psi = normalisation.psi(s)
        self.starts = np.zeros(self.t.size, dtype=np.bool_)
        self.starts[np.cumsum([0] + [seg.t.size for seg in segments[:-1]])] = True
        self.durations = [float(seg.t[-1] - seg.t[0]) for seg in segments]
        self.median_dt = float(np.median(np.concatenate(
            [np.diff(seg.t) for seg in segments if seg.t.size > 1] or [np.array([1.0])])))
        self.rho = thresholds(n, kind)
        self.inv_width = inverse_widths(self.rho, kind)
        # f(psi) = G @ slopes; the central slope is fixed to 1 (scale of the problem).
        g = pwa.path_matrix(self.psi, m)
        self.c = (m - 1) // 2
        self.free = np.array([j for j in range(m) if j != self.c], dtype=np.int64)
        self.rhs = g[:, self.c]
        self.neg_g = -g[:, self.free]
        self.orientation = 1
        self.cell_weights = cell_weights
        self.gauge = float(np.sign(np.corrcoef(self.xi, self.psi)[0, 1]) or 1.0)
        # Ridge rows: weights (cells only) -> 0, slopes -> 1, scaled with the sample count.
        lam = math.sqrt(ridge * self.t.size)
        k, n_w = n + m - 1, n + 2
        self.ridge_a = np.zeros((k, n_w + m - 1))
        self.ridge_b = np.zeros(k)
        self.ridge_a[np.arange(n), 1 + np.arange(n)] = lam
        self.ridge_a[n + np.arange(m - 1), n_w + np.arange(m - 1)] = lam
        self.ridge_b[n:] = lam
        if kind == kern.KIND_APL and self.gauge < 0:  # drive the cells by -xi (docs/models.md)
            self.xi, self.gauge, self.orientation = -self.xi, -self.gauge, -1
        self.set_weight_sign()

    def _set_bounds(self) -> None:
        """Bounds of [w, free slopes]: slopes >= eps, cell weights of ``weight_sign`` or free."""
        n_w = self.n + 2
        lo = np.full(n_w + self.m - 1, -np.inf)
        hi = np.full(n_w + self.m - 1, np.inf)
        if self.cell_weights != "free":
            (lo if self.weight_sign > 0 else hi)[1:self.n + 1] = 0.0
        lo[n_w:] = self.eps
        self.bounds = (lo, hi)

    def set_weight_sign(self) -> None:
        """The cell weights' sign (docs/design.md, "Loop orientation"); ``signed`` tries both."""
        loop = {"lag": -1}.get(self.cell_weights, 1)
        if self.cell_weights == "signed":
            scores = {}
            for loop in (1, -1):
                self.weight_sign = loop * self.gauge
                self._set_bounds()
                scores[loop] = self.solve(0.0, 1.0, output_nfev=self.search_nfev,
                                          play=True).rmse
            loop = -1 if scores[-1] < (1.0 - LOOP_SWITCH_GAIN) * scores[1] else 1
        self.weight_sign = loop * self.gauge
        self._set_bounds()

    def memory_report(self, result: Solution) -> dict[str, Any]:
        """``memory_share``, ``memoryless`` and ``loop`` (docs/design.md, "Loop orientation")."""
        z = self.design(result.sigma, result.p)
        term = z[:, 1:self.n + 1] @ result.w[1:self.n + 1]
        static = np.column_stack([np.ones_like(self.xi), self.xi, self.xi ** 2, self.xi ** 3])
        cells = term - static @ np.linalg.lstsq(static, term, rcond=None)[0]
        y = z @ result.w
        spread = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
        share = float(np.sqrt(np.mean(cells ** 2))) / spread if spread > 0 else 0.0
        loop = ("free" if self.cell_weights == "free"
                else "lead" if self.weight_sign * self.gauge > 0 else "lag")
        return {"memory_share": share, "memoryless": share < MEMORYLESS_SHARE, "loop": loop}

    def default_sigma_grid(self) -> np.ndarray:
        lo = 0.02 / max(max(self.durations), 1e-9)
        hi = 0.2 / max(self.median_dt, 1e-9)
        if hi <= lo:
            hi = lo * 1e3
        return np.geomspace(lo, hi, 13)

    def design(self, sigma: float, p: float, *, play: bool = False) -> np.ndarray:
        """z = [xi, x_1..x_N, 1] per sample at sigma, p; ``play``: the MPI's cells, any model."""
        if play:
            rho = thresholds(self.n, kern.KIND_PL)
            states = kern.states_kernel(self.t, self.xi, self.starts, kern.KIND_PL, 0.0, 1.0,
                                        rho, inverse_widths(rho, kern.KIND_PL))
        else:
            states = kern.states_kernel(self.t, self.xi, self.starts, self.kind, sigma,
                                        p, self.rho, self.inv_width)
        z = np.empty((self.t.size, self.n + 2))
        z[:, 0] = self.xi
        z[:, 1:self.n + 1] = states
        z[:, self.n + 1] = 1.0
        return z

    def equation_error(self, z: np.ndarray) -> np.ndarray:
        """The paper's QP: theta = [w, free slopes] minimising ||f(psi) - w . z||^2 + ridge."""
        a = np.hstack([z, self.neg_g, self.rhs[:, None]])
        # [A b] reduced to its triangular factor R by Cholesky of the Gram matrix (tall-skinny
        # QR is ten times slower); the jitter keeps exactly collinear columns factorable.
        gram = a.T @ a
        gram[np.diag_indices_from(gram)] += 1e-12 * np.trace(gram) / gram.shape[0]
        r_full = np.linalg.cholesky(gram).T
        a_red = np.vstack([r_full[:-1, :-1], self.ridge_a])
        b_red = np.concatenate([r_full[:-1, -1], self.ridge_b])
        # scipy ships no types: the solution of lsq_linear is a float64 vector
        theta: npt.NDArray[np.float64] = lsq_linear(a_red, b_red, bounds=self.bounds,
                                                    method="bvls").x
        return np.clip(theta, *self.bounds)

    def predict(self, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """psi_hat = f^-1(w . z) (eq. (2)) for the parameter vector theta."""
        # the slopes as the model holds them: through mu (``CellModel``)
        slopes = pwa.slopes_from_mu(pwa.mu_from_slopes(self.slopes(theta)))
        b, f_at_b, inv_slopes = pwa.slope_tables(slopes)
        return pwa.finv_array(z @ theta[:self.n + 2], b, f_at_b, inv_slopes)

    def slopes(self, theta: np.ndarray) -> np.ndarray:
        return np.insert(theta[self.n + 2:], self.c, 1.0)

    def rmse(self, psi_hat: np.ndarray) -> float:
        value = float(self.norm.s0 * np.sqrt(np.mean((psi_hat - self.psi) ** 2)))
        return value if math.isfinite(value) else math.inf

    def output_error(self, z: np.ndarray, theta: np.ndarray, *,
                     max_nfev: int) -> tuple[np.ndarray, np.ndarray]:
        """(theta, psi_hat) of ``bounded_lm`` on the output error from ``theta``, unless worse."""
        n_w = self.n + 2
        edges = pwa.breakpoints(self.m)
        cache: dict[str, np.ndarray] = {}

        def psi_of(x: np.ndarray) -> np.ndarray:
            if "x" not in cache or not np.array_equal(cache["x"], x):
                cache["x"], cache["psi"] = x.copy(), self.predict(z, x)
            return cache["psi"]

        def residuals(x: np.ndarray) -> np.ndarray:
            return np.concatenate([psi_of(x) - self.psi, self.ridge_a @ x - self.ridge_b])

        jac = np.empty((self.t.size, n_w + self.m))
        ridge_gram = self.ridge_a.T @ self.ridge_a

        def normal_equations(x: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            output_jacobian(z, psi_of(x), res, self.slopes(x), edges, self.c, jac)
            both = jac.T @ jac
            return (both[:-1, :-1] + ridge_gram,
                    both[:-1, -1] + self.ridge_a.T @ res[self.t.size:])

        start = self.predict(z, theta)
        found = bounded_lm(residuals, normal_equations, theta, *self.bounds, max_nfev=max_nfev)
        if not self.rmse(psi_of(found)) <= self.rmse(start):
            return theta, start
        return found, psi_of(found)

    def solve(self, sigma: float, p: float, *, output_nfev: int = 0,
              play: bool = False) -> Solution:
        """QP at (sigma, p), then ``output_nfev`` output-error evaluations; ``play``: see design."""
        with self._lock:
            self.evaluations += 1
        z = self.design(sigma, p, play=play)
        theta = self.equation_error(z)
        psi_hat = self.predict(z, theta)
        if output_nfev > 0 and math.isfinite(self.rmse(psi_hat)):
            theta, psi_hat = self.output_error(z, theta, max_nfev=output_nfev)
        return Solution(sigma, p, theta[:self.n + 2].copy(), self.slopes(theta),
                         self.rmse(psi_hat))

    def refine(self, best: Solution, *, max_evaluations: int = 30) -> Solution:
        """A short Nelder-Mead in (log10 sigma, p) from the best grid point."""
        found = {"best": best}

        def objective(v: np.ndarray) -> float:
            p = float(np.clip(v[1], kern.P_MIN, P_MAX))
            result = self.solve(float(10.0 ** v[0]), p, output_nfev=self.search_nfev)
            if result.rmse < found["best"].rmse:
                found["best"] = result
            return result.rmse

        start = np.array([math.log10(best.sigma), best.p])
        simplex = start + np.array([[0.0, 0.0], [0.15, 0.0], [0.0, 0.1 * best.p]])
        minimize(objective, start, method="Nelder-Mead",
                 options={"maxfev": max_evaluations, "initial_simplex": simplex,
                          "xatol": 1e-3, "fatol": 1e-6})
        return found["best"]


Residuals = Callable[[np.ndarray], np.ndarray]
NormalEquations = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def bounded_lm(residuals: Residuals, normal_equations: NormalEquations, theta: np.ndarray,
               lo: np.ndarray, hi: np.ndarray, *, max_nfev: int, ftol: float = 1e-9,
               lam: float = 1e-3) -> np.ndarray:
    """A bounded Levenberg-Marquardt: theta in [lo, hi] with no larger cost than the start."""
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
    """The Jacobian of f^-1(w . z) by (w, free slopes) with the residuals as a last column."""
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
