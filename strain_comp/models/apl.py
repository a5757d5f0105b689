"""APL, PL and MPI inverse models ([Electrolycra] eq. (1)-(3),
appendix eq. (6)).

Normalised input xi = R / r0 + alpha drives N cells with states x_k:

* ``APL`` (eq. (1)): asymmetric power-law cells, thresholds rho_k = 2k/(N+1) - 1, band
  -1 <= xi - x_k <= rho_k, creep xdot = sigma ((xi - x_k + 1) / (rho_k + 1))^p; the cells
  creep only upwards, so relaxation shows after rising input steps only.
* ``PL`` (eq. (6)): symmetric power-law cells, rho_k = k/(N+1), band |x_k - xi| <= rho_k,
  xdot = sigma (|xi - x_k| / rho_k)^p sgn(xi - x_k).
* ``MPI``: PL with sigma = 0, i.e. play operators (rate independent).

The paper's sensors rise in resistance with strain. For one whose resistance falls with
strain (a negative gauge factor) the APL cells are driven by -xi (parameter
``orientation: -1``, chosen by ``fit`` from the sign of the training data's correlation of
R and S), so that they still creep after *strain* loading steps, as the material does; the
PL and MPI cells are symmetric (eq. (6)), for them the orientation changes nothing and is
not set.

Output (eq. (2)): psi = f^-1(w_0 xi + sum_k w_k x_k + w_{N+1}), strain S = s0 (psi - beta),
f the strictly increasing piecewise-affine map of eq. (3) (basis: ``strain_comp.models.pwa``).
Time stepping, initial state and bad-sample handling: ``strain_comp.models.apl_kernels``.
sigma is in normalised units per second, t in seconds.

Fitting, step 1 (the paper's QP, done as bounded linear least squares): for fixed sigma,
p the cell states do not depend on w, mu, and f(psi_meas) = w . [xi, x_1..x_N, 1] is linear
in (w, segment slopes of f). The scale is fixed by the central slope of f = 1, the other
slopes are bounded below by ``eps`` (f strictly increasing), the cell weights w_1..w_N
take one sign (the inverse of a Prandtl-Ishlinskii operator with a positive density has
weights of one sign), and a small ridge pulls slopes to 1 and weights to 0 where the data
say nothing. Which sign is the sensor's loop: the gauge's sign when the resistance leads
the strain (higher on loading than on unloading: a clockwise S-R loop, the paper's sensor,
Table I, and the rig), the opposite sign when it lags (a counter-clockwise loop, e.g. a
viscoelastic silver-nylon thread). Held to the wrong sign the QP sets every cell to zero
and the model is a static map. ``cell_weights="signed"`` (default) chooses the sign from
the training data (``_FitProblem.loop_sign``), ``"lead"`` / ``"lag"`` fix it, ``"free"``
drops the constraint. The fit reports the share of the output its cells give and
``memoryless`` when it is below 1 % (``_FitProblem.memory_report``).

Step 2 (a choice beyond the paper): output-error refinement. The QP minimises the
*equation* error f(psi_meas) - w . z; with a noisy resistance the regressors z (xi and the
cell states) are noisy while f(psi_meas) is not, and the QP trades the fit of psi against
the shape of f: on a noisy measured sensor the QP solution fits worse than the cubic, its
output collapsing toward the mean on held-out runs.
So from the QP solution (w, slopes) are refined, same bounds and ridge, to minimise the
*output* error sum (f^-1(w . z) - psi_meas)^2 with the cell states fixed for the given
sigma, p, by a bounded Levenberg-Marquardt (``strain_comp.models.apl_refine``; analytic
Jacobian, since f^-1 is piecewise affine). A refined point is kept only if its output RMSE
is not above the QP's. ``output_nfev=0`` gives the paper's QP alone.

Step 3: sigma (log grid) and p (grid) are searched by the output RMSE of the strain of
the model run on the training data: every grid point by its QP solution, the
``search_top`` best of them again after ``search_nfev`` refinement evaluations, then a
short Nelder-Mead from the best (each point scored after ``search_nfev`` refinement
evaluations), and the final sigma, p get the full ``output_nfev`` refinement.
(``search_nfev=0`` scores the whole search by the QP; refining every grid point instead
costs ~3.5x the fit time for the same result on the rig bags.)

Both choices (output-error refinement, signed cell weights) were made on held-out error,
on the bundled rig bags and the measured recordings: compare them with
``strain-comp fit ... --option output_nfev=0`` (the QP alone) or ``--option
cell_weights=free|lead|lag`` and ``strain-comp evaluate`` on a held-out bag. Signed weights are
never much worse than free ones and keep free weights from overfitting a noisy sensor.
The current held-out figures of every model are in docs/measured.md
(``scripts/compare_models.py``, ``scripts/measured.py``).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
from scipy.optimize import lsq_linear, minimize
from threadpoolctl import threadpool_limits

from strain_comp.core.direction import DirectionSettings
from strain_comp.errors import FitError, ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models import pwa
from strain_comp.models.apl_refine import bounded_lm, output_jacobian
from strain_comp.models.base import (
    Compensator,
    Normalisation,
    Segment,
    as_float_arrays,
    require_float,
    require_vector,
)

N_MAX = 200
M_MAX = 201
P_MAX = 20.0
CELL_WEIGHTS = ("signed", "lead", "lag", "free")
"""Constraints on the cell weights: one sign, the loop's orientation chosen from the
training data (``_FitProblem.loop_sign``); one sign, for a resistance that leads the strain
(the paper's orientation) or lags it; none."""
LOOP_SWITCH_GAIN = 0.05
"""``signed`` holds the cells to a lagging loop only when that lowers the training output
RMSE by more than this share against the paper's leading loop (docs/hysteresis_fit.md)."""
MEMORYLESS_SHARE = 0.01
"""Below this share of the output from the cells (``memory_report``) a fit is memoryless."""
P_GRID = (0.3, 0.45, 0.6, 0.8, 1.0, 1.3, 1.7, 2.2, 3.0)
"""The default grid of p searched by the fit."""


def thresholds(n: int, kind: int) -> np.ndarray:
    """rho_k, k = 1..N: 2k/(N+1) - 1 for APL (eq. (1)), k/(N+1) for PL (eq. (6))."""
    k = np.arange(1, n + 1, dtype=np.float64)
    return 2.0 * k / (n + 1) - 1.0 if kind == kern.KIND_APL else k / (n + 1)


def inverse_widths(rho: np.ndarray, kind: int) -> np.ndarray:
    """1 / (rho_k + 1) for APL, 1 / rho_k for PL: the normalisers of the power law."""
    return 1.0 / (rho + 1.0) if kind == kern.KIND_APL else 1.0 / rho


def _require_int(params: Mapping[str, Any], key: str, lo: int, hi: int) -> int:
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(key, f"must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ParameterError(key, f"must be in [{lo}, {hi}], got {value}")
    return int(value)


def _check_shape(n: int, m: int) -> None:
    if not 1 <= n <= N_MAX:
        raise ParameterError("N", f"must be in [1, {N_MAX}], got {n}")
    if not (1 <= m <= M_MAX and m % 2 == 1):
        raise ParameterError("M", f"must be odd and in [1, {M_MAX}], got {m}")


class _CellModel(Compensator):
    """Shared implementation of APL, PL and MPI; ``kind`` selects the cell law."""

    kind: ClassVar[int]
    rate_dependent: ClassVar[bool] = True
    array_kernel: ClassVar[bool] = True

    def __init__(self, *, n: int, m: int, sigma: float, p: float, w: npt.ArrayLike,
                 mu: npt.ArrayLike, normalisation: Normalisation, orientation: int = 1
                 ) -> None:
        super().__init__(normalisation)
        _check_shape(n, m)
        if orientation not in (1, -1) or isinstance(orientation, bool):
            raise ParameterError("orientation", f"must be 1 or -1, got {orientation!r}")
        if not (math.isfinite(sigma) and sigma >= 0.0):
            raise ParameterError("sigma", f"must be >= 0, got {sigma}")
        if not self.rate_dependent and sigma != 0.0:
            raise ParameterError("sigma", f"must be 0 for {self.name}, got {sigma}")
        if not (math.isfinite(p) and kern.P_MIN <= p <= P_MAX):
            raise ParameterError("p", f"must be in [{kern.P_MIN}, {P_MAX}], got {p}")
        self.N = n
        self.M = m
        self.sigma = float(sigma)
        self.p = float(p)
        self.w = np.ascontiguousarray(w, dtype=np.float64)
        self.mu = np.ascontiguousarray(mu, dtype=np.float64)
        if self.w.shape != (n + 2,) or not np.all(np.isfinite(self.w)):
            raise ParameterError("w", f"must be {n + 2} finite numbers")
        if self.mu.shape != (m,) or not np.all(np.isfinite(self.mu)):
            raise ParameterError("mu", f"must be {m} finite numbers")
        slopes = pwa.slopes_from_mu(self.mu)
        if not np.all(slopes > 0.0):
            j = int(np.argmin(slopes))
            raise ParameterError("mu", f"f must be strictly increasing; segment {j} has "
                                       f"slope {slopes[j]:.6g}")
        self.rho = thresholds(n, self.kind)
        self._inv_width = inverse_widths(self.rho, self.kind)
        self._b, self._f_at_b, self._inv_slopes = pwa.inverse_tables(self.mu)
        self.orientation = int(orientation)
        # The cells' input orientation * xi, as orientation * (R / r0 + alpha).
        self._norm = np.array([orientation * normalisation.r0, orientation * normalisation.alpha,
                               normalisation.s0, normalisation.beta])
        self.x = np.zeros(n)
        self._clock = np.zeros(2)
        self._t1 = np.zeros(1)
        self._r1 = np.zeros(1)
        self._o1 = np.zeros(1)
        self.fit_report: dict[str, Any] | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the state: the next good sample re-initialises the cells (relaxed)."""
        self.x[:] = 0.0
        self._clock[:] = 0.0

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        kern.run_kernel(t, r, self.x, self._clock, out, self.kind, self.sigma, self.p,
                        self.rho, self._inv_width, self.w, self._norm, self._b,
                        self._f_at_b, self._inv_slopes)

    def step(self, t: float, r: float) -> float:
        self._t1[0] = t
        self._r1[0] = r
        self._run_into(self._t1, self._r1, self._o1)
        return float(self._o1[0])

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        t, r = as_float_arrays(t, r)
        out = np.empty(t.size)
        self._run_into(t, r, out)
        return out

    def f(self, psi: npt.ArrayLike) -> np.ndarray:
        """The output map f(psi) of eq. (3)."""
        return pwa.evaluate(psi, self.mu)

    def f_inverse(self, y: npt.ArrayLike) -> np.ndarray:
        """f^-1(y), exact (piecewise affine, linear beyond the outer breakpoints)."""
        y = np.ascontiguousarray(np.atleast_1d(y), dtype=np.float64)
        return pwa.finv_array(y, self._b, self._f_at_b, self._inv_slopes)

    def to_params(self) -> dict[str, Any]:
        params: dict[str, Any] = {"N": self.N, "M": self.M, "sigma": self.sigma, "p": self.p,
                                  "w": [float(v) for v in self.w],
                                  "mu": [float(v) for v in self.mu]}
        if self.orientation != 1:
            params["orientation"] = self.orientation
        return params

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> _CellModel:
        n = _require_int(params, "N", 1, N_MAX)
        m = _require_int(params, "M", 1, M_MAX)
        if m % 2 == 0:
            raise ParameterError("M", f"must be odd, got {m}")
        if cls.rate_dependent:
            sigma = require_float(params, "sigma", lo=0.0)
            p = require_float(params, "p", lo=kern.P_MIN, hi=P_MAX)
        else:
            sigma = require_float(params, "sigma", lo=0.0, hi=0.0) if "sigma" in params else 0.0
            p = require_float(params, "p", lo=kern.P_MIN, hi=P_MAX) if "p" in params else 1.0
        w = require_vector(params, "w", length=n + 2)
        mu = require_vector(params, "mu", length=m)
        orientation = _require_int(params, "orientation", -1, 1) if "orientation" in params else 1
        if orientation == 0:
            raise ParameterError("orientation", "must be 1 or -1, got 0")
        return cls(n=n, m=m, sigma=sigma, p=p, w=w, mu=mu, normalisation=normalisation,
                   orientation=orientation)

    @classmethod
    @threadpool_limits.wrap(limits=1, user_api="blas")
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, N: int = 11, M: int = 9,
            sigma_grid: npt.ArrayLike | None = None, p_grid: npt.ArrayLike | None = None,
            refine: bool = True, cell_weights: str = "signed", eps: float = 1e-3,
            ridge: float = 1e-6, output_nfev: int = 100, search_nfev: int = 10,
            search_top: int = 5, workers: int | None = None,
            progress: bool | Callable[[str], None] = True, **options: Any) -> _CellModel:
        """Fit w, mu by the QP and the output-error refinement, searching sigma and p
        (module docstring).

        ``sigma_grid`` [1/s] defaults to 13 log-spaced values between 0.02 / (longest
        segment duration) and 0.2 / (median sample interval); ``p_grid`` to 0.3 .. 3.
        ``output_nfev``: residual evaluations of the final output-error refinement (0: the
        paper's QP only); ``search_nfev``: those per scored point of the search (0: the
        search scores the QP solutions); ``search_top``: grid points re-scored with it.
        ``workers``: threads scoring the sigma/p grid (default ``grid_workers``: one per
        available core, serial for a small problem; the result does not depend on it;
        ``bench/bench_fit.py`` times the grid against ``workers=1``). ``progress``:
        True prints a line per grid row to stderr once the fit has run for more than 2 s;
        a callable receives those lines instead; False is silent.

        BLAS is held to one thread during the fit: its matrices (samples x N + M + 2, and
        the reduced QP) are too small to gain from BLAS threads, and BLAS threads spinning
        on a machine with other work, or started from several grid threads at once, made
        the same fit many times slower (``bench/bench_fit.py`` times both).
        """
        if options:
            raise FitError(f"{cls.name}: unknown fit options {sorted(options)}")
        try:
            _check_shape(N, M)
        except ParameterError as exc:
            raise FitError(f"{cls.name}: {exc}") from None
        if workers is not None and not (isinstance(workers, int) and workers >= 1):
            raise FitError(f"{cls.name}: workers must be an integer >= 1")
        if cell_weights not in CELL_WEIGHTS:
            raise FitError(f"{cls.name}: cell_weights must be one of {', '.join(CELL_WEIGHTS)}")
        counts = (output_nfev, search_nfev, search_top)
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in counts):
            raise FitError(f"{cls.name}: output_nfev, search_nfev and search_top must be "
                           "integers >= 0")
        problem = _FitProblem(cls, segments, normalisation, n=N, m=M, eps=eps, ridge=ridge,
                              cell_weights=cell_weights, search_nfev=search_nfev)
        if cls.kind == kern.KIND_APL and problem.gauge < 0:
            problem.orient(-1)
        problem.set_weight_sign()
        if not cls.rate_dependent:
            result = problem.solve(0.0, 1.0, output_nfev=output_nfev)
            model = problem.build(result)
            model.fit_report = {"rmse": result.rmse, "evaluations": 1,
                                **problem.memory_report(result)}
            return model
        sigmas = (problem.default_sigma_grid() if sigma_grid is None
                  else np.asarray(sigma_grid, dtype=np.float64))
        ps = np.asarray(P_GRID if p_grid is None else p_grid, dtype=np.float64)
        if sigmas.size == 0 or ps.size == 0 or np.any(sigmas <= 0) or np.any(ps < kern.P_MIN):
            raise FitError(f"{cls.name}: sigma_grid must be > 0 and p_grid >= {kern.P_MIN}")
        say = _progress_printer(progress, cls.name)
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
        model = problem.build(best)
        model.fit_report = {"rmse": best.rmse, "evaluations": problem.evaluations,
                            "seconds": time.monotonic() - problem.started,
                            **problem.memory_report(best)}
        return model


class APL(_CellModel):
    """Asymmetric power-law model (eq. (1)-(3))."""

    name = "apl"
    kind = kern.KIND_APL


class PL(_CellModel):
    """Power-law model of the paper's appendix (eq. (6), (2), (3))."""

    name = "pl"
    kind = kern.KIND_PL


class MPI(_CellModel):
    """Modified Prandtl-Ishlinskii model: PL with sigma = 0 (rate independent)."""

    name = "mpi"
    kind = kern.KIND_PL
    rate_dependent = False


def _by_rmse(solution: _Solution) -> float:
    return solution.rmse


MIN_THREADED_SAMPLES = 2000
"""Below this many training samples a grid point takes well under a millisecond and the
grid is scored serially: thread hand-offs would cost more than they save."""


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def grid_workers(requested: int | None, points: int, samples: int) -> int:
    """Threads to score a sigma/p grid of ``points`` points on ``samples`` training samples:
    ``requested``, else one per available core; never more than half the points (each
    thread gets two or more), and 1 (serial, no thread pool) on one core or below
    ``MIN_THREADED_SAMPLES`` samples unless requested."""
    if requested is not None:
        return max(1, min(requested, points))
    if samples < MIN_THREADED_SAMPLES:
        return 1
    return max(1, min(available_cores(), points // 2))


def score_grid(problem: _FitProblem, sigmas: np.ndarray, ps: np.ndarray, *, workers: int,
               say: Callable[[str], None]) -> list[_Solution]:
    """Every (sigma, p) of the grid scored by its QP solution, in ``workers`` threads
    (the points are independent; the cell-state kernel, numpy's array operations and BLAS
    release the GIL). ``APL.fit`` calls it with BLAS held to one thread, so the grid
    threads do not start BLAS threads of their own. The result does not depend on
    ``workers``."""
    grid: list[_Solution] = []
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


def _say_row(say: Callable[[str], None], grid: list[_Solution], i: int, rows: int,
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


class _Solution:
    """One solved point of the search: sigma, p, parameter vector and output RMSE [%]."""

    def __init__(self, sigma: float, p: float, w: np.ndarray, slopes: np.ndarray,
                 rmse: float) -> None:
        self.sigma, self.p, self.w, self.slopes, self.rmse = sigma, p, w, slopes, rmse


class _FitProblem:
    """The training data prepared once; ``solve(sigma, p)`` is one QP + output error."""

    def __init__(self, cls: type[_CellModel], segments: Sequence[Segment],
                 normalisation: Normalisation, *, n: int, m: int, eps: float, ridge: float,
                 cell_weights: str, search_nfev: int) -> None:
        self.cls, self.norm, self.n, self.m = cls, normalisation, n, m
        self.search_nfev = search_nfev
        self.eps, self.started, self.evaluations = eps, time.monotonic(), 0
        self._lock = threading.Lock()
        segments = [seg for seg in segments if seg.t.size > 0]
        if not segments:
            raise FitError(f"{cls.name}: no training samples")
        self.t = np.concatenate([seg.t for seg in segments])
        r = np.concatenate([seg.r for seg in segments])
        s = np.concatenate([seg.s for seg in segments])
        if not (np.all(np.isfinite(self.t)) and np.all(np.isfinite(r)) and np.all(r > 0)
                and np.all(np.isfinite(s))):
            raise FitError(f"{cls.name}: training samples must be finite with R > 0")
        n_params = n + m + 1
        if self.t.size < max(50, 5 * n_params):
            raise FitError(f"{cls.name}: needs at least {max(50, 5 * n_params)} samples for "
                           f"N={n}, M={m}, got {self.t.size}")
        self.xi = normalisation.xi(r)
        self.psi = normalisation.psi(s)
        if np.ptp(self.xi) < 1e-6 or np.ptp(self.psi) < 1e-6:
            raise FitError(f"{cls.name}: no excitation (resistance or strain is constant)")
        self.starts = np.zeros(self.t.size, dtype=np.bool_)
        self.starts[np.cumsum([0] + [seg.t.size for seg in segments[:-1]])] = True
        self.durations = [float(seg.t[-1] - seg.t[0]) for seg in segments]
        self.median_dt = float(np.median(np.concatenate(
            [np.diff(seg.t) for seg in segments if seg.t.size > 1] or [np.array([1.0])])))
        self.rho = thresholds(n, cls.kind)
        self.inv_width = inverse_widths(self.rho, cls.kind)
        # f(psi) = G @ slopes; the central slope is fixed to 1 (scale of the problem).
        g = pwa.path_matrix(self.psi, m)
        self.c = (m - 1) // 2
        self.free = np.array([j for j in range(m) if j != self.c], dtype=np.int64)
        self.rhs = g[:, self.c]
        self.neg_g = -g[:, self.free]
        self.orientation = 1
        self.cell_weights = cell_weights
        self.gauge = float(np.sign(np.corrcoef(self.xi, self.psi)[0, 1]) or 1.0)
        self.weight_sign = self.gauge
        self._set_bounds()
        # Ridge rows: weights (cells only) -> 0, slopes -> 1, scaled with the sample count.
        lam = math.sqrt(ridge * self.t.size)
        k, n_w = n + m - 1, n + 2
        self.ridge_a = np.zeros((k, n_w + m - 1))
        self.ridge_b = np.zeros(k)
        self.ridge_a[np.arange(n), 1 + np.arange(n)] = lam
        self.ridge_a[n + np.arange(m - 1), n_w + np.arange(m - 1)] = lam
        self.ridge_b[n:] = lam

    def _set_bounds(self) -> None:
        """Bounds of [w, free slopes]: slopes >= eps, cell weights of ``weight_sign``
        (unless free)."""
        n_w = self.n + 2
        lo = np.full(n_w + self.m - 1, -np.inf)
        hi = np.full(n_w + self.m - 1, np.inf)
        if self.cell_weights != "free":
            (lo if self.weight_sign > 0 else hi)[1:self.n + 1] = 0.0
        lo[n_w:] = self.eps
        self.bounds = (lo, hi)

    def orient(self, orientation: int) -> None:
        """Drive the cells by orientation * xi (module docstring); before any solve."""
        if orientation != self.orientation:
            self.xi = -self.xi
            self.gauge = -self.gauge
            self.weight_sign = self.gauge
            self.orientation = orientation
            self._set_bounds()

    def loop_sign(self) -> int:
        """The sign the training loop asks of the cell weights (as a multiple of the
        gauge's sign: 1 a leading, -1 a lagging resistance).

        Positive cell weights (for a rising gauge) put the strain lower, at a given
        resistance, while the input rises: the resistance is higher on loading than on
        unloading, it leads the strain (a clockwise S-R loop, as the paper's sensor and the
        rig have it). Negative ones: the resistance lags the strain (counter-clockwise,
        e.g. a viscoelastic thread). The inverse of a Prandtl-Ishlinskii operator with
        positive weights has weights of one sign, so one sign for all cells is the right
        constraint, but which sign is the sensor's. The loop is the sensor's, not the
        model's: both signs are fitted with the MPI's cells (symmetric play operators, no
        creep) for every model of the family, and the lagging loop is taken when it lowers
        the output RMSE by more than ``LOOP_SWITCH_GAIN``, else the paper's."""
        scores = {}
        for loop in (1, -1):
            self.weight_sign = loop * self.gauge
            self._set_bounds()
            scores[loop] = self.solve(0.0, 1.0, output_nfev=self.search_nfev, play=True).rmse
        return -1 if scores[-1] < (1.0 - LOOP_SWITCH_GAIN) * scores[1] else 1

    def set_weight_sign(self) -> None:
        """The cell weights' sign for ``cell_weights`` (``CELL_WEIGHTS``)."""
        loop = {"lead": 1, "lag": -1}.get(self.cell_weights)
        if loop is None:
            loop = self.loop_sign() if self.cell_weights == "signed" else 1
        self.weight_sign = loop * self.gauge
        self._set_bounds()

    def memory_report(self, result: _Solution) -> dict[str, Any]:
        """How much of the fitted output comes from the cells' memory: ``memory_share``,
        the RMS over the training data of what the cells' term sum_k w_k x_k adds beyond
        any cubic in xi (its least-squares residual on 1, xi, xi^2, xi^3: a cell that
        follows the input, or sits at a constant offset from it, is no memory) over the
        RMS of w . z about its mean; ``memoryless`` when it is below
        ``MEMORYLESS_SHARE``; ``loop`` the S-R loop orientation the cell weights were
        held to (``lead``: resistance higher on loading, ``lag``: lower, ``free``: not
        held)."""
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
        """z = [xi, x_1..x_N, 1] per training sample (rows) for this sigma, p; with
        ``play`` the cells are the MPI's symmetric play operators whatever the model."""
        if play:
            rho = thresholds(self.n, kern.KIND_PL)
            states = kern.states_kernel(self.t, self.xi, self.starts, kern.KIND_PL, 0.0, 1.0,
                                        rho, inverse_widths(rho, kern.KIND_PL))
        else:
            states = kern.states_kernel(self.t, self.xi, self.starts, self.cls.kind, sigma,
                                        p, self.rho, self.inv_width)
        z = np.empty((self.t.size, self.n + 2))
        z[:, 0] = self.xi
        z[:, 1:self.n + 1] = states
        z[:, self.n + 1] = 1.0
        return z

    def equation_error(self, z: np.ndarray) -> np.ndarray:
        """The paper's QP: theta = [w, free slopes] minimising ||f(psi) - w . z||^2 + ridge."""
        a = np.hstack([z, self.neg_g, self.rhs[:, None]])
        # Reduce the tall problem to its triangular factor: [A b] = QR, so ||A theta - b||
        # = ||R_A theta - r_b|| + const. R from the Cholesky factor of the Gram matrix
        # (tall-skinny QR is ten times slower here); the jitter keeps exactly collinear
        # columns (a cell pinned to xi + 1 over all data) factorable, the ridge rows below
        # then decide them.
        gram = a.T @ a
        gram[np.diag_indices_from(gram)] += 1e-12 * np.trace(gram) / gram.shape[0]
        r_full = np.linalg.cholesky(gram).T
        a_red = np.vstack([r_full[:-1, :-1], self.ridge_a])
        b_red = np.concatenate([r_full[:-1, -1], self.ridge_b])
        theta = lsq_linear(a_red, b_red, bounds=self.bounds, method="bvls").x
        return np.clip(theta, *self.bounds)

    def predict(self, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """psi_hat = f^-1(w . z) (eq. (2)) for the parameter vector theta."""
        b, f_at_b, inv_slopes = pwa.inverse_tables(pwa.mu_from_slopes(self.slopes(theta)))
        return pwa.finv_array(z @ theta[:self.n + 2], b, f_at_b, inv_slopes)

    def slopes(self, theta: np.ndarray) -> np.ndarray:
        return np.insert(theta[self.n + 2:], self.c, 1.0)

    def rmse(self, psi_hat: np.ndarray) -> float:
        value = float(self.norm.s0 * np.sqrt(np.mean((psi_hat - self.psi) ** 2)))
        return value if math.isfinite(value) else math.inf

    def output_error(self, z: np.ndarray, theta: np.ndarray, *,
                     max_nfev: int) -> tuple[np.ndarray, np.ndarray]:
        """Minimise sum (f^-1(w . z) - psi)^2 + ridge over theta from ``theta`` (bounded
        Levenberg-Marquardt, same bounds as the QP); returns (theta, psi_hat), the start
        when the refinement does not lower the output RMSE.

        Jacobian: with y = w . z and f(psi_hat) = G(psi_hat) . slopes = y, implicit
        differentiation gives d psi_hat / d w = z / f'(psi_hat) and d psi_hat / d slope_j =
        -G_j(psi_hat) / f'(psi_hat) (G: the path matrix, f' the slope of the segment
        psi_hat lies in).
        """
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
              play: bool = False) -> _Solution:
        """QP at (sigma, p), then ``output_nfev`` > 0 output-error evaluations from it;
        ``play``: with the MPI's cells (``design``)."""
        with self._lock:
            self.evaluations += 1
        z = self.design(sigma, p, play=play)
        theta = self.equation_error(z)
        psi_hat = self.predict(z, theta)
        if output_nfev > 0 and math.isfinite(self.rmse(psi_hat)):
            theta, psi_hat = self.output_error(z, theta, max_nfev=output_nfev)
        return _Solution(sigma, p, theta[:self.n + 2].copy(), self.slopes(theta),
                         self.rmse(psi_hat))

    def refine(self, best: _Solution, *, max_evaluations: int = 30) -> _Solution:
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

    def build(self, result: _Solution) -> _CellModel:
        return self.cls(n=self.n, m=self.m, sigma=result.sigma, p=result.p, w=result.w,
                        mu=pwa.mu_from_slopes(result.slopes), normalisation=self.norm,
                        orientation=self.orientation)


class APLArray:
    """K sensors of the APL family (same N and M) stepped together in one kernel call.

    Built from per-sensor models (APL, PL or MPI, mixed allowed); each sensor keeps its own
    state and previous time. ``step(t, r)`` gives exactly what each model's own ``step``
    would give; a bad r[s] (not finite or <= 0) leaves sensor s untouched and gives NaN.
    """

    def __init__(self, models: Sequence[_CellModel]) -> None:
        if not models:
            raise ParameterError("models", "an array needs at least one sensor")
        n, m = models[0].N, models[0].M
        for i, model in enumerate(models):
            if not isinstance(model, _CellModel):
                raise ParameterError(f"models.{i}", f"not an APL-family model: {model!r}")
            if (model.N, model.M) != (n, m):
                raise ParameterError(f"models.{i}", f"N, M = {model.N}, {model.M} differ "
                                                    f"from the first sensor's {n}, {m}")
        self.models = list(models)
        k = len(models)
        self.kind = np.array([mdl.kind for mdl in models], dtype=np.int64)
        self.sigma = np.array([mdl.sigma for mdl in models])
        self.p = np.array([mdl.p for mdl in models])
        self.rho = np.vstack([thresholds(n, kern.KIND_APL), thresholds(n, kern.KIND_PL)])
        self.inv_width = np.vstack([inverse_widths(self.rho[0], kern.KIND_APL),
                                    inverse_widths(self.rho[1], kern.KIND_PL)])
        self.w = np.vstack([mdl.w for mdl in models])
        self.norm = np.vstack([mdl._norm for mdl in models])
        self.b = models[0]._b
        self.f_at_b = np.ascontiguousarray(np.vstack([mdl._f_at_b for mdl in models])
                                           .reshape(k, m - 1))
        self.inv_slopes = np.vstack([mdl._inv_slopes for mdl in models])
        self.x = np.zeros((k, n))
        self.clock = np.zeros((k, 2))
        self.reset()

    @classmethod
    def from_models(cls, models: Sequence[Compensator]) -> APLArray:
        """The array of ``models``; ParameterError if one is not of the APL family."""
        cells = [model for model in models if isinstance(model, _CellModel)]
        if len(cells) != len(models):
            i = next(i for i, model in enumerate(models) if not isinstance(model, _CellModel))
            raise ParameterError(f"models.{i}", f"not an APL-family model: {models[i]!r}")
        return cls(cells)

    def __len__(self) -> int:
        return len(self.models)

    def reset(self) -> None:
        """Forget every sensor's state."""
        self.x[:] = 0.0
        self.clock[:] = 0.0

    def step(self, t: float, r: npt.ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
        """Advance all sensors by one tick at time t [s]; strain % per sensor."""
        r = np.ascontiguousarray(r, dtype=np.float64)
        if r.shape != (len(self.models),):
            raise ValueError(f"r must have shape ({len(self.models)},), got {r.shape}")
        if out is None:
            out = np.empty(r.size)
        kern.step_array_kernel(float(t), r, self.x, self.clock, out, self.kind, self.sigma,
                               self.p, self.rho, self.inv_width, self.w, self.norm, self.b,
                               self.f_at_b, self.inv_slopes)
        return out


__all__ = ["APL", "MPI", "PL", "APLArray", "grid_workers", "score_grid", "thresholds"]
