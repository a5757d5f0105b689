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
The current held-out figures of every model are in docs/results.md
(``studies/compare_models.py``, ``studies/measured.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from strain_comp.base.compensator import (
    KernelCompensator,
    Normalisation,
    Segment,
    require_float,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.registry import register
from strain_comp.errors import FitError, ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models import pwa
from strain_comp.models.apl_fit import CELL_WEIGHTS, CellFamily, fit_cells
from strain_comp.models.apl_kernels import P_MAX, inverse_widths, thresholds

N_MAX = 200
M_MAX = 201

_F = TypeVar("_F", bound=Callable[..., Any])


def _one_blas_thread(function: _F) -> _F:
    """``function`` with BLAS held to one thread while it runs: threadpoolctl's
    ``threadpool_limits.wrap``, which keeps the signature (threadpoolctl ships no types)."""
    wrapped: _F = threadpool_limits.wrap(limits=1, user_api="blas")(function)
    return wrapped


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


class _CellModel(KernelCompensator):
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
        self._b, self._f_at_b, self._inv_slopes = pwa.slope_tables(slopes)
        self.orientation = int(orientation)
        # The cells' input orientation * xi, as orientation * (R / r0 + alpha).
        self._norm = np.array([orientation * normalisation.r0, orientation * normalisation.alpha,
                               normalisation.s0, normalisation.beta])
        self.x = np.zeros(n)
        self._clock = np.zeros(2)
        self.fit_report: dict[str, Any] | None = None
        self.reset()

    def array_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(norm, b, f_at_b, inv_slopes): the per-sensor tables the array kernel reads
        (``strain_comp.models.apl_array``)."""
        return self._norm, self._b, self._f_at_b, self._inv_slopes

    def reset(self) -> None:
        """Forget the state: the next good sample re-initialises the cells (relaxed)."""
        self.x[:] = 0.0
        self._clock[:] = 0.0

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        kern.run_kernel(t, r, self.x, self._clock, out, self.kind, self.sigma, self.p,
                        self.rho, self._inv_width, self.w, self._norm, self._b,
                        self._f_at_b, self._inv_slopes)

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
    @_one_blas_thread
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, N: int = 11, M: int = 9,
            sigma_grid: npt.ArrayLike | None = None, p_grid: npt.ArrayLike | None = None,
            refine: bool = True, cell_weights: str = "signed", eps: float = 1e-3,
            ridge: float = 1e-6, output_nfev: int = 100, search_nfev: int = 10,
            search_top: int = 5, workers: int | None = None,
            progress: bool | Callable[[str], None] = True, **options: Any) -> _CellModel:
        """Fit w, mu by the QP and the output-error refinement, searching sigma and p (module
        docstring)."""
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
        family: CellFamily[_CellModel] = cls
        return fit_cells(family, segments, normalisation, n=N, m=M, sigma_grid=sigma_grid,
                         p_grid=p_grid, refine=refine, cell_weights=cell_weights, eps=eps,
                         ridge=ridge, output_nfev=output_nfev, search_nfev=search_nfev,
                         search_top=search_top, workers=workers, progress=progress)


@register
class APL(_CellModel):
    """Asymmetric power-law model (eq. (1)-(3))."""

    name = "apl"
    kind = kern.KIND_APL


@register
class PL(_CellModel):
    """Power-law model of the paper's appendix (eq. (6), (2), (3))."""

    name = "pl"
    kind = kern.KIND_PL


@register
class MPI(_CellModel):
    """Modified Prandtl-Ishlinskii model: PL with sigma = 0 (rate independent)."""

    name = "mpi"
    kind = kern.KIND_PL
    rate_dependent = False
