"""K sensors of the APL family stepped together: the array form of the per-sensor kernel
(``strain_comp.models.apl_kernels.step_sensor``), for the engine's array tick
(``strain_comp.core.array``) and ``APLArray.step`` on its own. It reads the models
through ``CellModel`` and needs none of their fit."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, cast

import numpy as np
import numpy.typing as npt

from strain_comp.errors import ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models.apl_kernels import inverse_widths, thresholds
from strain_comp.models.base import Compensator, tick_arrays


class CellModel(Protocol):
    """What the array reads of an APL, PL or MPI model (``strain_comp.models.apl``)."""

    N: int
    M: int
    kind: int
    sigma: float
    p: float
    w: np.ndarray

    def array_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(norm, b, f_at_b, inv_slopes)."""
        ...


class APLArray:
    """K sensors of the APL family (same N and M) stepped together in one kernel call.

    Built from per-sensor models (APL, PL or MPI, mixed allowed); each sensor keeps its own
    state and previous time. ``step(t, r)`` gives exactly what each model's own ``step``
    would give; a bad r[s] (not finite or <= 0) leaves sensor s untouched and gives NaN.
    """

    def __init__(self, models: Sequence[Compensator]) -> None:
        if not models:
            raise ParameterError("models", "an array needs at least one sensor")
        for i, model in enumerate(models):
            if not type(model).array_kernel:
                raise ParameterError(f"models.{i}", f"not an APL-family model: {model!r}")
        cells = [cast(CellModel, model) for model in models]
        n, m = cells[0].N, cells[0].M
        for i, model in enumerate(cells):
            if (model.N, model.M) != (n, m):
                raise ParameterError(f"models.{i}", f"N, M = {model.N}, {model.M} differ "
                                                    f"from the first sensor's {n}, {m}")
        self.models = cells
        k = len(cells)
        tables = [mdl.array_tables() for mdl in cells]
        self.kind = np.array([mdl.kind for mdl in cells], dtype=np.int64)
        self.sigma = np.array([mdl.sigma for mdl in cells])
        self.p = np.array([mdl.p for mdl in cells])
        self.rho = np.vstack([thresholds(n, kern.KIND_APL), thresholds(n, kern.KIND_PL)])
        self.inv_width = np.vstack([inverse_widths(self.rho[0], kern.KIND_APL),
                                    inverse_widths(self.rho[1], kern.KIND_PL)])
        self.w = np.vstack([mdl.w for mdl in cells])
        self.norm = np.vstack([norm for norm, _, _, _ in tables])
        self.b = tables[0][1]
        self.f_at_b = np.ascontiguousarray(np.vstack([f for _, _, f, _ in tables])
                                           .reshape(k, m - 1))
        self.inv_slopes = np.vstack([inv for _, _, _, inv in tables])
        self.x = np.zeros((k, n))
        self.clock = np.zeros((k, 2))
        self.reset()

    @classmethod
    def from_models(cls, models: Sequence[Compensator]) -> APLArray:
        """The array of ``models``; ParameterError if one is not of the APL family."""
        return cls(models)

    def __len__(self) -> int:
        return len(self.models)

    def reset(self) -> None:
        """Forget every sensor's state."""
        self.x[:] = 0.0
        self.clock[:] = 0.0

    def step(self, t: float, r: npt.ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
        """Advance all sensors by one tick at time t [s]; strain % per sensor."""
        r, out = tick_arrays(r, len(self.models), out)
        kern.step_array_kernel(float(t), r, self.x, self.clock, out, self.kind, self.sigma,
                               self.p, self.rho, self.inv_width, self.w, self.norm, self.b,
                               self.f_at_b, self.inv_slopes)
        return out
