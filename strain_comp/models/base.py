"""What every compensator is: a streaming inverse model, resistance in, strain % out.

The contract (explicit state, ``step`` and ``run`` through one kernel) is docs/design.md,
"Models"; the parameters are the calibration file's ``model.params`` (docs/design.md,
"Calibration file").
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from strain_comp.core.direction import DirectionSettings
from strain_comp.errors import ParameterError


@dataclass(frozen=True)
class Normalisation:
    """Affine maps to dimensionless input and output ([Electrolycra] section II.C).

    xi = R / r0 + alpha and psi = S / s0 + beta, chosen so that the training data span
    [-1, 1] in both.
    """

    r0: float
    alpha: float
    s0: float
    beta: float

    @classmethod
    def from_ranges(cls, r_lo: float, r_hi: float, s_lo: float, s_hi: float) -> Normalisation:
        """The normalisation that maps [r_lo, r_hi] and [s_lo, s_hi] onto [-1, 1].

        Args:
            r_lo: Lowest resistance [ohm].
            r_hi: Highest resistance [ohm].
            s_lo: Lowest strain [%].
            s_hi: Highest strain [%].

        Returns:
            The normalisation.

        Raises:
            ParameterError: Either range is empty (``r_hi <= r_lo`` or ``s_hi <= s_lo``).

        """
        if not (r_hi > r_lo and s_hi > s_lo):
            raise ParameterError("normalisation", "the data span no range of resistance or strain")
        r0 = (r_hi - r_lo) / 2.0
        s0 = (s_hi - s_lo) / 2.0
        return cls(r0=r0, alpha=-(r_hi + r_lo) / (2.0 * r0),
                   s0=s0, beta=-(s_hi + s_lo) / (2.0 * s0))

    @classmethod
    def fit(cls, r: npt.ArrayLike, s: npt.ArrayLike) -> Normalisation:
        """The normalisation that maps the finite samples' ranges onto [-1, 1].

        Args:
            r: Resistances [ohm].
            s: Reference strains [%], same length; pairs with a non-finite value are
                left out.

        Returns:
            The normalisation.

        Raises:
            ParameterError: The finite samples span no range of resistance or strain.
            ValueError: No pair is finite.

        """
        r = np.asarray(r, dtype=np.float64)
        s = np.asarray(s, dtype=np.float64)
        ok = np.isfinite(r) & np.isfinite(s)
        return cls.from_ranges(float(r[ok].min()), float(r[ok].max()),
                               float(s[ok].min()), float(s[ok].max()))

    def xi(self, r: npt.ArrayLike) -> np.ndarray:
        """Normalised input xi = R / r0 + alpha.

        Args:
            r: Resistance [ohm].

        Returns:
            xi, dimensionless.

        """
        return np.asarray(r, dtype=np.float64) / self.r0 + self.alpha

    def psi(self, s: npt.ArrayLike) -> np.ndarray:
        """Normalised output psi = S / s0 + beta.

        Args:
            s: Strain [%].

        Returns:
            psi, dimensionless.

        """
        return np.asarray(s, dtype=np.float64) / self.s0 + self.beta

    def strain(self, psi: npt.ArrayLike) -> np.ndarray:
        """Strain from the normalised output, S = s0 (psi - beta).

        Args:
            psi: Normalised output.

        Returns:
            Strain [%].

        """
        return (np.asarray(psi, dtype=np.float64) - self.beta) * self.s0

    def to_dict(self) -> dict[str, float]:
        """The four coefficients.

        Returns:
            The calibration file's ``normalisation`` mapping.

        """
        return {"r0": self.r0, "alpha": self.alpha, "s0": self.s0, "beta": self.beta}


@dataclass(frozen=True)
class Segment:
    """One contiguous training recording: time [s], resistance [ohm], reference strain [%].

    Model state is reset at the start of every segment; samples must be finite, R > 0 and
    t strictly increasing (``strain_comp.core.samples`` cleans raw data into this form).
    """

    t: np.ndarray
    r: np.ndarray
    s: np.ndarray

    def __post_init__(self) -> None:
        for name in ("t", "r", "s"):
            array = np.ascontiguousarray(getattr(self, name), dtype=np.float64)
            object.__setattr__(self, name, array)
        if not (self.t.shape == self.r.shape == self.s.shape and self.t.ndim == 1):
            raise ValueError("Segment: t, r and s must be 1-D arrays of one length")


class Compensator(ABC):
    """Base class of the eight inverse models; see the module docstring for the contract."""

    name: ClassVar[str]
    """Model name as written in calibration files and on the command line."""
    array_kernel: ClassVar[bool] = False
    """True when sensors of this model can be stepped together in one array kernel
    (``strain_comp.models.apl_array.APLArray``; the engine's fused array tick)."""
    fit_full_rate: ClassVar[bool] = False
    """True when ``fit`` takes every sample of any number of them in bounded memory
    (creep_pi): the fit then skips the budget's reduction (``strain_comp.offline.reduce``),
    which would low-pass and decimate what its states are computed from."""

    def __init__(self, normalisation: Normalisation) -> None:
        """A model mapping through ``normalisation``.

        Args:
            normalisation: The affine maps to the model's dimensionless input and output.

        """
        self.normalisation = normalisation

    @abstractmethod
    def reset(self) -> None:
        """Restore the initial state (as after construction)."""

    @abstractmethod
    def step(self, t: float, r: float) -> float:
        """Advance by one good sample.

        Args:
            t: Time [s].
            r: Resistance [ohm].

        Returns:
            Strain [%].

        """

    @abstractmethod
    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        """Advance over arrays of good samples from the current state.

        Args:
            t: Times [s].
            r: Resistances [ohm], same length.

        Returns:
            Strain [%] per sample; the state is left where ``step`` would leave it.

        """

    @abstractmethod
    def to_params(self) -> dict[str, Any]:
        """Every parameter, as the calibration file's ``model.params``.

        Returns:
            YAML-safe plain Python (floats, ints, lists, dicts).

        """

    @classmethod
    @abstractmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> Compensator:
        """Build a model from ``to_params`` output.

        Args:
            params: The parameters (``model.params`` of a calibration file).
            normalisation: The sensor's normalisation.
            direction: The sensor's detector settings; models that switch on the movement
                direction (rational, spike_decay) run their own detector with them.

        Returns:
            The model, in its initial state.

        Raises:
            ParameterError: A parameter is missing or out of range (naming the field).

        """

    def singular_in(self, r_lo: float, r_hi: float) -> float | None:
        """Where in a resistance range the model has no finite strain (a rational's pole).

        The loader refuses a calibration singular in its range.

        Args:
            r_lo: Lower end of the range [ohm].
            r_hi: Upper end of the range [ohm].

        Returns:
            A resistance [ohm] in [r_lo, r_hi] without a finite strain, or None.

        """
        return None

    @classmethod
    @abstractmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, **options: Any) -> Compensator:
        """Fit the model to training segments.

        Args:
            segments: The training recordings (state reset at each one's start).
            normalisation: The normalisation of the training data.
            direction: The sensor's detector settings.
            **options: Model-specific options (N, M, search grids, ...).

        Returns:
            The fitted model, in its initial state.

        Raises:
            FitError: The data cannot be fitted (too few samples, no excitation, ...).
            ParameterError: An option is out of range (models differ in which error an
                unknown option raises).

        """


class KernelCompensator(Compensator):
    """A compensator whose ``run`` and ``step`` are one numba kernel over arrays
    (``_run_into``): ``step`` runs it on a one-sample view, so both paths share every
    floating-point operation."""

    def __init__(self, normalisation: Normalisation) -> None:
        super().__init__(normalisation)
        self._t1 = np.zeros(1)
        self._r1 = np.zeros(1)
        self._o1 = np.zeros(1)

    @abstractmethod
    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        """Advance over contiguous float64 arrays of good samples, writing strain % to
        ``out``."""

    def step(self, t: float, r: float) -> float:
        self._t1[0] = t
        self._r1[0] = r
        self._run_into(self._t1, self._r1, self._o1)
        return float(self._o1[0])

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        t, r = as_float_arrays(t, r)
        out = np.empty(t.size)
        self._run_into(t, r, out)
        return out


def require_float(params: Mapping[str, Any], key: str, *, lo: float | None = None,
                  hi: float | None = None, strict: bool = False) -> float:
    """Read ``params[key]`` as a finite float within [lo, hi].

    Args:
        params: The parameter mapping.
        key: The field to read.
        lo: Lowest allowed value (None: no bound).
        hi: Highest allowed value (None: no bound).
        strict: The bounds are open.

    Returns:
        The value as a float.

    Raises:
        ParameterError: The field is missing, not a number, not finite or out of bounds.

    """
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
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
                   min_length: int = 1) -> np.ndarray:
    """Read ``params[key]`` as a list of finite floats.

    Args:
        params: The parameter mapping.
        key: The field to read.
        length: The number of entries required (None: any).
        min_length: The fewest entries allowed.

    Returns:
        The values as a float64 array.

    Raises:
        ParameterError: The field is missing, not a list of finite numbers, or of the
            wrong length.

    """
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise ParameterError(key, f"must be a list of numbers, got {type(value).__name__}")
    for i, item in enumerate(value):
        if isinstance(item, bool) or not isinstance(item, (int, float, np.floating, np.integer)):
            raise ParameterError(f"{key}.{i}", f"must be a number, got {item!r}")
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ParameterError(key, "must hold finite numbers only")
    if length is not None and array.size != length:
        raise ParameterError(key, f"must have {length} entries, got {array.size}")
    if array.size < min_length:
        raise ParameterError(key, f"must have at least {min_length} entries, got {array.size}")
    return array


def as_float_arrays(t: npt.ArrayLike, r: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous float64 copies of (t, r).

    Args:
        t: Times [s].
        r: Resistances [ohm].

    Returns:
        ``t`` and ``r`` as contiguous float64 arrays.

    Raises:
        ValueError: They are not 1-D arrays of one length.

    """
    t = np.ascontiguousarray(t, dtype=np.float64)
    r = np.ascontiguousarray(r, dtype=np.float64)
    if t.ndim != 1 or t.shape != r.shape:
        raise ValueError("t and r must be 1-D arrays of one length")
    return t, r
