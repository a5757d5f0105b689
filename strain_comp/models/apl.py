"""APL, PL and MPI inverse models ([Electrolycra] eq. (1)-(3), appendix eq. (6)) and their
array form; cells, orientation, output map and the fit: docs/models.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from strain_comp.base.compensator import (
    Compensator,
    Normalisation,
    Segment,
    require_float,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.lift import LiftedArray, lift
from strain_comp.base.registry import register, register_array
from strain_comp.errors import ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models import pwa
from strain_comp.models.apl_fit import fit_cells
from strain_comp.models.apl_kernels import P_MAX, inverse_widths, thresholds

N_MAX = 200
M_MAX = 201


def _require_int(params: Mapping[str, Any], key: str) -> int:
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(key, f"must be an integer, got {value!r}")
    return int(value)


class CellModel(Compensator):
    """Shared implementation of APL, PL and MPI; ``kind`` selects the cell law."""

    kind: ClassVar[int]
    rate_dependent: ClassVar[bool] = True
    param_names = ("N", "M", "sigma", "p", "w", "mu")

    def __init__(self, *, n: int, m: int, sigma: float, p: float, w: npt.ArrayLike,
                 mu: npt.ArrayLike, normalisation: Normalisation, orientation: int = 1
                 ) -> None:
        super().__init__(normalisation)
        if not 1 <= n <= N_MAX:
            raise ParameterError("N", f"must be in [1, {N_MAX}], got {n}")
        if not (1 <= m <= M_MAX and m % 2 == 1):
            raise ParameterError("M", f"must be odd and in [1, {M_MAX}], got {m}")
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
        self.b, self.f_at_b, self.inv_slopes = pwa.slope_tables(slopes)
        self.orientation = int(orientation)
        # The cells' input orientation * xi, as orientation * (R / r0 + alpha).
        self.norm = np.array([orientation * normalisation.r0, orientation * normalisation.alpha,
                               normalisation.s0, normalisation.beta])
        self.x = np.zeros(n)
        self._clock = np.zeros(2)
        self.reset()

    def reset(self) -> None:
        """Forget the state: the next good sample re-initialises the cells (relaxed)."""
        self.x[:] = 0.0
        self._clock[:] = 0.0

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        kern.run_kernel(t, r, self.x, self._clock, out, self.kind, self.sigma, self.p,
                        self.rho, self._inv_width, self.w, self.norm, self.b,
                        self.f_at_b, self.inv_slopes)

    def to_params(self) -> dict[str, Any]:
        params = super().to_params()
        if self.orientation != 1:
            params["orientation"] = self.orientation
        return params

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> CellModel:
        # the ranges and lengths are checked by the constructor
        sigma = require_float(params, "sigma") if cls.rate_dependent or "sigma" in params else 0.0
        p = require_float(params, "p") if cls.rate_dependent or "p" in params else 1.0
        orientation = _require_int(params, "orientation") if "orientation" in params else 1
        return cls(n=_require_int(params, "N"), m=_require_int(params, "M"), sigma=sigma, p=p,
                   w=require_vector(params, "w"), mu=require_vector(params, "mu"),
                   normalisation=normalisation, orientation=orientation)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, N: int = 11, M: int = 9, **options: Any
            ) -> CellModel:
        """``fit_cells`` with BLAS held to one thread (options checked by offline.options)."""
        with threadpool_limits(limits=1, user_api="blas"):
            best, orientation, report = fit_cells(cls.name, cls.kind, cls.rate_dependent,
                                                  segments, normalisation, n=N, m=M, **options)
        model = cls(n=N, m=M, sigma=best.sigma, p=best.p, w=best.w,
                    mu=pwa.mu_from_slopes(best.slopes), normalisation=normalisation,
                    orientation=orientation)
        model.fit_report = report
        return model


@register
class APL(CellModel):
    """Asymmetric power-law model (eq. (1)-(3))."""

    name = "apl"
    kind = kern.KIND_APL


@register
class PL(CellModel):
    """Power-law model of the paper's appendix (eq. (6), (2), (3))."""

    name = "pl"
    kind = kern.KIND_PL


@register
class MPI(CellModel):
    """Modified Prandtl-Ishlinskii model: PL with sigma = 0 (rate independent)."""

    name = "mpi"
    kind = kern.KIND_PL
    rate_dependent = False


@register_array
@lift(kern.step_sensor, fastmath=kern.FASTMATH)
class APLArray(LiftedArray):
    """K sensors of the APL family (same N and M) stepped together in one kernel call."""

    model_type = CellModel

    @staticmethod
    def rows(model: CellModel) -> tuple[tuple[np.ndarray, ...], tuple[Any, ...]]:
        return ((model.x, model._clock), (model.kind, model.sigma, model.p, model.w,
                                          model.norm, model.f_at_b, model.inv_slopes))

    @staticmethod
    def shared(model: CellModel) -> tuple[np.ndarray, ...]:
        rho = np.vstack([thresholds(model.N, kern.KIND_APL), thresholds(model.N, kern.KIND_PL)])
        inv_width = np.vstack([inverse_widths(rho[0], kern.KIND_APL),
                               inverse_widths(rho[1], kern.KIND_PL)])
        return rho, inv_width, model.b
