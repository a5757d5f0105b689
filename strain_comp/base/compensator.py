"""What every compensator is: a streaming inverse model, resistance in, strain % out
(docs/design.md, "Models"); its parameters are the calibration file's ``model.params``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from strain_comp.base.direction import DirectionSettings
from strain_comp.errors import ParameterError


@dataclass(frozen=True)
class Normalisation:
    """Affine maps to dimensionless input and output ([Electrolycra] section II.C)."""

    r0: float
    alpha: float
    s0: float
    beta: float

    @classmethod
    def from_ranges(cls, r_lo: float, r_hi: float, s_lo: float, s_hi: float) -> Normalisation:
        """The normalisation that maps [r_lo, r_hi] and [s_lo, s_hi] onto [-1, 1]."""
        if not (r_hi > r_lo and s_hi > s_lo):
            raise ParameterError("normalisation", "the data span no range of resistance or strain")
        r0 = (r_hi - r_lo) / 2.0
        s0 = (s_hi - s_lo) / 2.0
        return cls(r0=r0, alpha=-(r_hi + r_lo) / (2.0 * r0),
                   s0=s0, beta=-(s_hi + s_lo) / (2.0 * s0))

    @classmethod
    def fit(cls, r: npt.ArrayLike, s: npt.ArrayLike) -> Normalisation:
        """The normalisation that maps the samples' ranges onto [-1, 1]."""
        r = np.asarray(r, dtype=np.float64)
        s = np.asarray(s, dtype=np.float64)
        return cls.from_ranges(float(r.min()), float(r.max()), float(s.min()), float(s.max()))

    def xi(self, r: npt.ArrayLike) -> np.ndarray:
        """Normalised input xi = R / r0 + alpha."""
        return np.asarray(r, dtype=np.float64) / self.r0 + self.alpha

    def psi(self, s: npt.ArrayLike) -> np.ndarray:
        """Normalised output psi = S / s0 + beta."""
        return np.asarray(s, dtype=np.float64) / self.s0 + self.beta

    def strain(self, psi: npt.ArrayLike) -> np.ndarray:
        """Strain from the normalised output, S = s0 (psi - beta)."""
        return (np.asarray(psi, dtype=np.float64) - self.beta) * self.s0

    def to_dict(self) -> dict[str, float]:
        return {"r0": self.r0, "alpha": self.alpha, "s0": self.s0, "beta": self.beta}


@dataclass(frozen=True)
class Segment:
    """One contiguous training recording: time [s], resistance [ohm], reference strain [%]."""

    t: np.ndarray
    r: np.ndarray
    s: np.ndarray

    def __post_init__(self) -> None:
        for name in ("t", "r", "s"):
            array = np.ascontiguousarray(getattr(self, name), dtype=np.float64)
            object.__setattr__(self, name, array)


class Compensator(ABC):
    """Base class of the inverse models; ``step`` is ``_run_into`` on a one-sample view."""

    name: ClassVar[str]  # as in calibration files and on the command line
    param_names: ClassVar[tuple[str, ...]] = ()  # what the default ``to_params`` writes
    # fit takes every sample in bounded memory, not the budget's low-passing reduction
    fit_full_rate: ClassVar[bool] = False
    fit_report: dict[str, Any] | None = None  # what the fit chose (a memory model's memory)

    def __init__(self, normalisation: Normalisation) -> None:
        self.normalisation = normalisation
        self._t1 = np.zeros(1)
        self._r1 = np.zeros(1)
        self._o1 = np.zeros(1)

    @abstractmethod
    def reset(self) -> None:
        """Restore the initial state (as after construction)."""

    @abstractmethod
    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        """Advance over contiguous float64 arrays of good samples, strain % into ``out``."""

    def step(self, t: float, r: float) -> float:
        """Advance by one good sample."""
        self._t1[0] = t
        self._r1[0] = r
        self._run_into(self._t1, self._r1, self._o1)
        return float(self._o1[0])

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        """Advance over arrays of good samples from the current state."""
        t, r = as_float_arrays(t, r)
        out = np.empty(t.size)
        self._run_into(t, r, out)
        return out

    def to_params(self) -> dict[str, Any]:
        """Every parameter, as the calibration file's ``model.params``."""
        values = {key: getattr(self, key) for key in self.param_names}
        return {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in values.items()}

    @classmethod
    @abstractmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> Compensator:
        """Build a model from ``to_params`` output."""

    def singular_in(self, r_lo: float, r_hi: float) -> float | None:
        """Where in a resistance range the model has no finite strain (a rational's pole)."""
        return None

    @classmethod
    @abstractmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, **options: Any) -> Compensator:
        """Fit the model to training segments."""


def require_float(params: Mapping[str, Any], key: str, *, lo: float | None = None,
                  hi: float | None = None, strict: bool = False) -> float:
    """Read ``params[key]`` as a finite float within [lo, hi]."""
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(key, f"must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise ParameterError(key, f"must be finite, got {value}")
    if lo is not None and (value < lo or (strict and value == lo)):
        raise ParameterError(key, f"must be {'>' if strict else '>='} {lo}, got {value}")
    if hi is not None and (value > hi or (strict and value == hi)):
        raise ParameterError(key, f"must be {'<' if strict else '<='} {hi}, got {value}")
    return value


def require_vector(params: Mapping[str, Any], key: str, *, length: int | None = None,
                   lo: float | None = None, hi: float | None = None, strict: bool = False
                   ) -> np.ndarray:
    """Read ``params[key]`` as a list of floats, each as ``require_float`` reads a number."""
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise ParameterError(key, f"must be a list of numbers, got {type(value).__name__}")
    array = np.array([require_float({f"{key}.{i}": item}, f"{key}.{i}", lo=lo, hi=hi,
                                    strict=strict) for i, item in enumerate(value)])
    if length is not None and array.size != length:
        raise ParameterError(key, f"must have {length} entries, got {array.size}")
    if array.size == 0:
        raise ParameterError(key, "must have at least 1 entries, got 0")
    return array


def as_float_arrays(t: npt.ArrayLike, r: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous float64 copies of (t, r)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    if t.ndim != 1 or t.shape != r.shape:
        raise ValueError("t and r must be 1-D arrays of one length")
    return t, r
