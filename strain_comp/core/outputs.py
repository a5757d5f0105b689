"""What the engine returns: one sample, one array tick, one batch (docs/design.md,
"Outputs")."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import TypeVar

import numpy as np

from strain_comp.base.samples import Status


@dataclass(frozen=True)
class SensorOutput:
    """One sample's result: strain [%] (held if bad), direction (+1/0/-1), status, flag."""

    strain: float
    direction: int
    status: Status
    out_of_range: bool
    resistance: float = math.nan
    """The resistance [ohm] the model read; NaN for a bad sample."""
    std: float = math.nan
    """The estimate's standard deviation; NaN where the calibration holds no uncertainty."""


@dataclass(frozen=True)
class ArrayOutput:
    """One array tick's result, in the array's sensor order."""

    strain: np.ndarray
    direction: np.ndarray
    status: np.ndarray
    out_of_range: np.ndarray
    std: np.ndarray | None = None
    """The standard deviation per sensor; None when no sensor of the array has one."""


@dataclass(frozen=True)
class BatchOutput:
    """``run``'s result: one entry per input sample."""

    strain: np.ndarray
    direction: np.ndarray
    status: np.ndarray
    out_of_range: np.ndarray
    resistance: np.ndarray
    """[ohm] the model read at used samples, else the input (read-only: may be the caller's)."""
    reset: np.ndarray | None = None
    """True where a gap reset the state before the sample; None: not known."""
    corrections: np.ndarray | None = None
    """``chain.SPIKE`` or ``chain.STEP`` where the input corrector acted, else 0; None: none."""
    std: np.ndarray | None = None
    """The estimate's standard deviation per sample; None without an uncertainty."""


_Out = TypeVar("_Out", BatchOutput, ArrayOutput)


def concatenate(outs: Sequence[_Out]) -> _Out:
    """One ``BatchOutput`` (or ``ArrayOutput``) of consecutive ones (pieces of a stream)."""
    def join(key: str) -> np.ndarray | None:
        values = [getattr(o, key) for o in outs]
        return None if any(v is None for v in values) else np.concatenate(values)

    return type(outs[0])(*(join(f.name) for f in fields(outs[0])))  # type: ignore[arg-type]

