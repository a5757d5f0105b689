"""A sensor's effect terms as the engine runs them (S_corrected = S_hat - sum_j c_j
g_j), the registry of kinds and the calibration-file entries."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import require_float
from strain_comp.core.effects.history import Baseline, Direction, Elapsed, Mullins, Stretch
from strain_comp.core.effects.memory import Rate, Relaxation, ResistanceMemory
from strain_comp.core.effects.regressor import Batch, Regressor
from strain_comp.core.effects.static import Crosstalk, Offset, StrainLevel, Temperature
from strain_comp.errors import ParameterError

KINDS: dict[str, type[Regressor]] = {cls.kind: cls for cls in (
    Offset, Rate, Direction, Relaxation, ResistanceMemory, Elapsed, Temperature, StrainLevel,
    Mullins, Stretch, Crosstalk, Baseline)}


def regressor_from_dict(effect: Mapping[str, Any]) -> Regressor:
    """The regressor of one calibration-file effect entry."""
    if not isinstance(effect, Mapping):
        raise ParameterError("(effect)", f"must be a mapping, got {type(effect).__name__}")
    name = effect.get("name")
    if not isinstance(name, str) or not name:
        raise ParameterError("name", "missing or not a string")
    kind = effect.get("kind")
    if not isinstance(kind, str) or kind not in KINDS:
        raise ParameterError("kind", f"must be one of {', '.join(KINDS)}; got {kind!r}")
    params = effect.get("params", {})
    if params is None:
        params = {}
    if not isinstance(params, Mapping):
        raise ParameterError("params", f"must be a mapping, got {type(params).__name__}")
    cls = KINDS[kind]
    unknown = sorted(str(k) for k in params if k not in cls.readers)
    if unknown:
        raise ParameterError(f"params.{unknown[0]}", f"unknown parameter of kind {kind!r}")
    return cls(params)


def validate_effect_dict(effect: Mapping[str, Any]) -> None:
    regressor_from_dict(effect)
    require_float(effect, "coef")


def effect_dict(name: str, regressor: Regressor, coef: float) -> dict[str, Any]:
    """The calibration-file entry of a regressor with its coefficient."""
    return {"name": name, "kind": regressor.kind, "params": regressor.params(),
            "coef": float(coef)}


class EffectTerms:
    """The effect terms of one sensor: S_corrected = S_hat - sum_j coef_j g_j."""

    def __init__(self, regressors: Sequence[Regressor], coefs: Sequence[float]) -> None:
        self.regressors = list(regressors)
        self.coefs = np.asarray(coefs, dtype=np.float64).reshape(-1)

    @classmethod
    def from_dicts(cls, effects: Sequence[Mapping[str, Any]]) -> EffectTerms:
        """From a calibration's ``effects`` list."""
        regressors, coefs = [], []
        for i, effect in enumerate(effects):
            try:
                regressors.append(regressor_from_dict(effect))
                coefs.append(require_float(effect, "coef"))
            except ParameterError as err:
                raise ParameterError(f"{i}.{err.field}", err.problem) from None
        return cls(regressors, coefs)

    @property
    def neighbours(self) -> list[str]:
        """Names of the array neighbours whose S_hat these terms read."""
        return [g.neighbour for g in self.regressors if g.neighbour is not None]

    def reset(self) -> None:
        for g in self.regressors:
            g.reset()

    def rescale(self, factor: float) -> None:
        """The resistance these terms read is ``factor`` x what it was (``Regressor.rescale``)."""
        for g in self.regressors:
            g.rescale(factor)

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike, s_hat: npt.ArrayLike,
            direction: npt.ArrayLike, temperature: npt.ArrayLike | None = None,
            neighbours: Mapping[str, npt.ArrayLike] | None = None) -> np.ndarray:
        """Corrected strain over arrays, continuing from (and updating) the terms' state."""
        batch = Batch.of(t, r, s_hat, direction, temperature, neighbours)
        out = np.copy(batch.s_hat, order="C")
        for g, c in zip(self.regressors, self.coefs, strict=True):
            out -= c * g.run(batch)
        return out
