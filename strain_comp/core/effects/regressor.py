"""The effect-term contract: the inputs a regressor reads (``Batch``), the ``Regressor`` base
class and the parameter readers every kind shares."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import require_float
from strain_comp.errors import ParameterError


@dataclass
class Batch:
    """Arrays of samples (inputs of ``Regressor.run``); all of one length n."""

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
        """Contiguous float64 arrays (the callers' are 1-D and of one length)."""
        t_, r_, s_hat_, direction_ = (np.ascontiguousarray(a, dtype=np.float64)
                                      for a in (t, r, s_hat, direction))
        temp = None if temperature is None else np.ascontiguousarray(temperature, np.float64)
        nbrs = {str(k): np.ascontiguousarray(v, np.float64) for k, v in (neighbours or {}).items()}
        return cls(t_, r_, s_hat_, direction_, temperature=temp, neighbours=nbrs)


Reader = Callable[[Mapping[str, Any], str], Any]
"""Reads ``params[key]`` (its default where missing) or raises ``ParameterError``."""


def number(default: float, **bounds: Any) -> Reader:
    """A finite float within ``bounds``."""

    def read(params: Mapping[str, Any], key: str) -> float:
        if key not in params:
            return default
        try:
            return require_float(params, key, **bounds)
        except ParameterError as err:
            raise ParameterError(f"params.{err.field}", err.problem) from None

    return read


def positive(default: float) -> Reader:
    """A finite float > 0."""
    return number(default, lo=0.0, strict=True)


def checked(default: Any, ok: Callable[[Any], bool], wanted: str) -> Reader:
    """``params[key]`` (``default`` where missing) if ``ok``; else it must be ``wanted``."""

    def read(params: Mapping[str, Any], key: str) -> Any:
        value = params.get(key, default)
        if not ok(value):
            raise ParameterError(f"params.{key}", f"must be {wanted}, got {value!r}")
        return value

    return read


def choice(options: Sequence[str], default: str) -> Reader:
    return checked(default, lambda value: value in options, f"one of {', '.join(options)}")


def flag(default: bool) -> Reader:
    return checked(default, lambda value: isinstance(value, bool), "true or false")


def param_readers(**readers: Reader) -> Mapping[str, Reader]:
    """A kind's parameters: each name's reader, in the order of the file's ``params``."""
    return MappingProxyType(readers)


def run_segments(run: Callable[[slice], np.ndarray], reset: Callable[[], None], n: int,
                 starts: Sequence[int]) -> np.ndarray:
    """``run`` over the n samples in segments cut at ``starts`` (gap resets), ``reset`` between."""
    out = np.empty(n)
    for k, (a, b) in enumerate(pairwise([0, *starts, n])):
        if k > 0:
            reset()
        if b > a:
            out[a:b] = run(slice(a, b))
    return out


class Regressor(ABC):
    """One effect regressor g(t) with explicit state; see the package docstring."""

    kind: ClassVar[str]
    readers: ClassVar[Mapping[str, Reader]] = MappingProxyType({})
    """Each parameter's reader, in the order of the calibration file's ``params``."""
    initial: ClassVar[tuple[float, ...]] = ()
    """The state at a start (``_state``, what ``run`` carries from one batch to the next)."""
    neighbour: str | None = None
    """Name of the array neighbour this regressor reads, if any."""
    _state: np.ndarray

    def __init__(self, params: Mapping[str, Any]) -> None:
        for key, read in self.readers.items():
            setattr(self, key, read(params, key))
        self.reset()

    def reset(self) -> None:
        self._state = np.array(self.initial, dtype=np.float64)

    @abstractmethod
    def run(self, batch: Batch) -> np.ndarray:
        """g over a batch, continuing from (and updating) the current state."""

    def params(self) -> dict[str, Any]:
        """The parameters as plain Python (the calibration file's ``params``)."""
        return {key: getattr(self, key) for key in self.readers}

    def rescale(self, factor: float) -> None:
        """The resistance it reads is ``factor`` x what it was (a tare): carry the state over."""
        return None

    def _held(self, values: np.ndarray) -> np.ndarray:
        """``values`` with the last finite one held, across batches in ``_state[0]``."""
        idx = np.where(np.isfinite(values), np.arange(values.size), -1)
        np.maximum.accumulate(idx, out=idx)
        held = np.where(idx >= 0, values[np.maximum(idx, 0)], float(self._state[0]))
        if held.size:
            self._state[0] = held[-1]
        return held
