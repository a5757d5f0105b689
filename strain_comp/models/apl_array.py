"""K sensors of the APL family stepped together: the array form of the per-sensor kernel
(``strain_comp.models.apl_kernels.step_sensor``), for the engine's array tick
(``strain_comp.core.array``) and ``APLArray.step`` on its own."""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np

from strain_comp.base.compensator import Compensator
from strain_comp.base.lift import LiftedArray, lift
from strain_comp.base.registry import register_array
from strain_comp.errors import ParameterError
from strain_comp.models import apl_kernels as kern
from strain_comp.models.apl import CellModel
from strain_comp.models.apl_kernels import inverse_widths, thresholds


@register_array
@lift(kern.step_sensor, fastmath=kern.FASTMATH)
class APLArray(LiftedArray):
    """K sensors of the APL family (same N and M) stepped together in one kernel call."""

    family = "an APL-family"

    def __init__(self, models: Sequence[Compensator]) -> None:
        super().__init__(models)
        cells = [cast(CellModel, model) for model in models]
        n, m = cells[0].N, cells[0].M
        for i, model in enumerate(cells):
            if (model.N, model.M) != (n, m):
                raise ParameterError(f"models.{i}", f"N, M = {model.N}, {model.M} differ "
                                                    f"from the first sensor's {n}, {m}")
        k = len(cells)
        self.kind = np.array([mdl.kind for mdl in cells], dtype=np.int64)
        self.sigma = np.array([mdl.sigma for mdl in cells])
        self.p = np.array([mdl.p for mdl in cells])
        self.rho = np.vstack([thresholds(n, kern.KIND_APL), thresholds(n, kern.KIND_PL)])
        self.inv_width = np.vstack([inverse_widths(self.rho[0], kern.KIND_APL),
                                    inverse_widths(self.rho[1], kern.KIND_PL)])
        self.w = np.vstack([mdl.w for mdl in cells])
        self.norm = np.vstack([mdl.norm for mdl in cells])
        self.b = cells[0].b
        self.f_at_b = np.ascontiguousarray(np.vstack([mdl.f_at_b for mdl in cells])
                                           .reshape(k, m - 1))
        self.inv_slopes = np.vstack([mdl.inv_slopes for mdl in cells])
        self.x = np.zeros((k, n))
        self.clock = np.zeros((k, 2))
        self.state = (self.x, self.clock)
        self.params = (self.kind, self.sigma, self.p, self.rho, self.inv_width, self.w,
                       self.norm, self.b, self.f_at_b, self.inv_slopes)

    @classmethod
    def accepts(cls, model: Compensator) -> bool:
        """True for the APL family (APL, PL, MPI)."""
        return isinstance(model, CellModel)
