"""Cubic baseline ([Electrolycra] eq. (4)): S = c3 R^3 + c2 R^2 + c1 R + c0, memoryless;
fitted on xi (better conditioned than powers of R in ohm), stored in ohm units as eq. (4).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import (
    Compensator,
    Normalisation,
    Segment,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.registry import register


@register
class Cubic(Compensator):
    """S = c3 R^3 + c2 R^2 + c1 R + c0 (eq. (4)); ``c`` = [c0, c1, c2, c3] in ohm units."""

    name = "cubic"
    param_names = ("c",)

    def __init__(self, c: npt.ArrayLike, normalisation: Normalisation) -> None:
        super().__init__(normalisation)
        self.c = np.asarray(c, dtype=np.float64)

    def reset(self) -> None:
        """Nothing to reset: the cubic has no memory."""

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        c0, c1, c2, c3 = self.c
        out[:] = ((c3 * r + c2) * r + c1) * r + c0

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> Cubic:
        return cls(require_vector(params, "c", length=4), normalisation)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, **options: Any) -> Cubic:
        r = np.concatenate([seg.r for seg in segments])
        s = np.concatenate([seg.s for seg in segments])
        xi = normalisation.xi(r)
        coef_xi = np.polynomial.polynomial.polyfit(xi, s, 3)
        # Substitute xi = R / r0 + alpha to express the polynomial in R (ohm).
        poly_r = np.polynomial.Polynomial(coef_xi)(
            np.polynomial.Polynomial([normalisation.alpha, 1.0 / normalisation.r0]))
        c = np.zeros(4)
        c[: poly_r.coef.size] = poly_r.coef
        return cls(c, normalisation)
