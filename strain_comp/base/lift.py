"""A model family's array form lifted from its per-sensor kernel ``kernel(s, t, r, *state,
*params) -> strain [%]``, which advances row ``s`` of each state array by one good sample
(a zeroed row is a sensor at rest; docs/models.md, "Arrays")."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt

from strain_comp._numba import specialise
from strain_comp.errors import ParameterError

if TYPE_CHECKING:
    from numba.core.dispatcher import Dispatcher

_Family = TypeVar("_Family", bound="LiftedArray")


def kernel(s: int, t: float, r: float, *arrays: np.ndarray) -> float:
    """The name templates call the family's kernel by; each specialisation binds its own."""
    raise TypeError("a template's kernel is bound by strain_comp._numba.specialise")


def array_step(t: float, r: np.ndarray, out: np.ndarray, state: tuple[np.ndarray, ...],
               params: tuple[Any, ...]) -> None:
    """Template: every sensor by one tick at ``t``; a bad r[s] or t gives NaN, state kept."""
    arrays = state + params
    for s in range(r.size):
        ri = r[s]
        if not (math.isfinite(t) and math.isfinite(ri) and ri > 0.0):
            out[s] = np.nan
            continue
        out[s] = kernel(s, t, ri, *arrays)


class LiftedArray(ABC):
    """K sensors of one family stepped together through the family's lifted kernel."""

    model_type: ClassVar[type]
    kernel: ClassVar[Dispatcher[Any]]
    array_step: ClassVar[Dispatcher[Any]]  # ``array_step`` bound to ``kernel``
    state: tuple[np.ndarray, ...]
    params: tuple[Any, ...]

    def __init__(self, models: Sequence[Any]) -> None:
        """The state rows at rest and the parameter rows of ``models`` (``accepts``), stacked."""
        self.models = list(models)
        rows = [self.rows(model) for model in models]
        shapes = [[np.shape(a) for a in state + params] for state, params in rows]
        for i, shape in enumerate(shapes):
            if shape != shapes[0]:
                raise ParameterError(f"models.{i}", "shapes differ from the first sensor's")
        state, params = rows[0]
        self.state = tuple(np.zeros((len(rows), *np.shape(a))) for a in state)
        self.params = tuple(np.array([row[1][j] for row in rows]) for j in range(len(params)))
        self.params += self.shared(models[0])

    @classmethod
    def accepts(cls, model: Any) -> bool:
        return isinstance(model, cls.model_type)

    @staticmethod
    @abstractmethod
    def rows(model: Any) -> tuple[tuple[np.ndarray, ...], tuple[Any, ...]]:
        """One sensor's state arrays (their shapes) and parameters, in the kernel's order."""

    @staticmethod
    def shared(model: Any) -> tuple[Any, ...]:
        """Parameters after the per-sensor ones, the same for every sensor (from the first)."""
        return ()

    def reset(self) -> None:
        for rows in self.state:
            rows[:] = 0.0

    def step(self, t: float, r: npt.ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
        """Advance all sensors by one tick at time t [s]; strain % per sensor."""
        k = len(self.models)
        r = np.ascontiguousarray(r, dtype=np.float64)
        if r.shape != (k,):
            raise ValueError(f"r must have shape ({k},), got {r.shape}")
        out = np.empty(k) if out is None else out
        type(self).array_step(float(t), r, out, self.state, self.params)
        return out


def lift(family_kernel: Dispatcher[Any], **options: Any
         ) -> Callable[[type[_Family]], type[_Family]]:
    """Class decorator: the family stepped by ``family_kernel``, compiled with its ``options``."""
    def decorate(cls: type[_Family]) -> type[_Family]:
        cls.kernel = family_kernel
        cls.array_step = specialise(array_step, {"kernel": family_kernel},
                                    error_model="numpy", **options)
        return cls
    return decorate
