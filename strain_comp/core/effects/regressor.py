"""The effect-term contract: the inputs a regressor reads (``Sample``, ``Batch``),
the ``Regressor`` base class and the parameter readers every kind shares
(docs/design.md, "The residual loop")."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import require_float
from strain_comp.errors import ParameterError


@dataclass
class Sample:
    """One sample as the online path sees it (inputs of ``Regressor.step``)."""

    t: float
    r: float
    s_hat: float
    direction: int
    temperature: float = math.nan
    neighbours: Mapping[str, float] | None = None


@dataclass
class Batch:
    """Whole arrays of samples (inputs of ``Regressor.run``); all of one length n."""

    t: np.ndarray
    r: np.ndarray
    s_hat: np.ndarray
    direction: np.ndarray
    temperature: np.ndarray | None = None
    neighbours: Mapping[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, t: npt.ArrayLike, r: npt.ArrayLike, s_hat: npt.ArrayLike,
           direction: npt.ArrayLike, temperature: npt.ArrayLike | None = None,
           neighbours: Mapping[str, npt.ArrayLike] | None = None) -> Batch:
        """Contiguous float64 copies, checked to be 1-D and of one length."""
        arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (t, r, s_hat, direction)]
        n = arrays[0].size
        temp = None if temperature is None else np.ascontiguousarray(temperature, np.float64)
        nbrs = {str(k): np.ascontiguousarray(v, np.float64) for k, v in (neighbours or {}).items()}
        for a in [*arrays, *([temp] if temp is not None else []), *nbrs.values()]:
            if a.ndim != 1 or a.size != n:
                raise ValueError("effects: every input array must be 1-D and of one length")
        t_, r_, s_hat_, direction_ = arrays
        return cls(t_, r_, s_hat_, direction_, temperature=temp, neighbours=nbrs)


def choice_param(params: Mapping[str, Any], key: str, options: Sequence[str], default: str
                 ) -> str:
    """``params[key]``, one of ``options``."""
    value = params.get(key, default)
    if value not in options:
        raise ParameterError(f"params.{key}", f"must be one of {', '.join(options)}; got {value!r}")
    return str(value)


def number_param(params: Mapping[str, Any], key: str, default: float, **bounds: Any) -> float:
    """``params[key]`` as a finite float within ``bounds``."""
    if key not in params:
        return default
    try:
        return require_float(params, key, **bounds)
    except ParameterError as err:
        raise ParameterError(f"params.{err.field}", err.problem) from None


def positive_param(params: Mapping[str, Any], key: str, default: float) -> float:
    """``params[key]`` as a finite float > 0."""
    return number_param(params, key, default, lo=0.0, strict=True)


def ffill(values: np.ndarray, last: float) -> np.ndarray:
    """Hold the last finite value."""
    ok = np.isfinite(values)
    idx = np.where(ok, np.arange(values.size), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], last)


def run_segments(run: Callable[[slice], np.ndarray], reset: Callable[[], None], n: int,
                 starts: Sequence[int]) -> np.ndarray:
    """``run`` over the n samples in segments cut at ``starts`` (where the engine reset after
    a gap), calling ``reset`` between segments, as the engine resets effect state there."""
    out = np.empty(n)
    for k, (a, b) in enumerate(pairwise([0, *starts, n])):
        if k > 0:
            reset()
        if b > a:
            out[a:b] = run(slice(a, b))
    return out


class Regressor(ABC):
    """One effect regressor g(t) with explicit state; see the module docstring."""

    kind: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]] = ()

    @abstractmethod
    def reset(self) -> None:
        """Restore the initial state."""

    def step(self, sample: Sample) -> float:
        """Advance by one sample: ``run`` on a batch of one, so a regressor with a compiled
        kernel has that one implementation."""
        neighbours = {n: [v] for n, v in (sample.neighbours or {}).items()}
        return float(self.run(Batch.of([sample.t], [sample.r], [sample.s_hat],
                                       [sample.direction], [sample.temperature],
                                       neighbours))[0])

    @abstractmethod
    def run(self, batch: Batch) -> np.ndarray:
        """g over a batch, continuing from (and updating) the current state."""

    @abstractmethod
    def params(self) -> dict[str, Any]:
        """The parameters as plain Python (the calibration file's ``params``)."""

    @classmethod
    @abstractmethod
    def from_params(cls, params: Mapping[str, Any]) -> Regressor:
        """Build from ``params``."""

    @property
    def neighbour(self) -> str | None:
        """Name of the array neighbour this regressor reads, if any."""
        return None

    def rescale(self, factor: float) -> None:
        """The resistance it reads is ``factor`` x what it was (a tare): carry the state
        over, as if that scale had held from the first sample. Terms that do not read the
        resistance keep no state in its scale: nothing to do."""
        return None
