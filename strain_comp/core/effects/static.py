"""Effect terms without memory: a function of the current sample only (offset,
temperature, strain level, cross-talk from an array neighbour)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from strain_comp.core.effects.regressor import (
    Batch,
    Regressor,
    Sample,
    choice_param,
    ffill,
    number_param,
)
from strain_comp.errors import ParameterError


class Offset(Regressor):
    """g = 1: a constant offset of the estimate (a zero shift between runs)."""

    kind = "offset"

    def reset(self) -> None:
        pass

    def step(self, sample: Sample) -> float:
        return 1.0

    def run(self, batch: Batch) -> np.ndarray:
        return np.ones(batch.t.size)

    def params(self) -> dict[str, Any]:
        return {}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Offset:
        return cls()




TEMPERATURE_RANGE = (-273.15, 1000.0)
"""Temperatures [deg C] a temperature term reads; one outside (below absolute zero, a
finite 1e308, NaN, inf) is a bad reading, treated as missing."""


def valid_temperature(temp: np.ndarray) -> np.ndarray:
    """Mask of readings inside ``TEMPERATURE_RANGE``."""
    return (temp >= TEMPERATURE_RANGE[0]) & (temp <= TEMPERATURE_RANGE[1])


class Temperature(Regressor):
    """Temperature dependence: g = T - t_ref (``form: offset``, a TCR shifting R) or
    g = (T - t_ref) * S_hat (``form: strain``, a temperature-dependent gauge factor)."""

    kind = "temperature"
    param_names = ("form", "t_ref")

    def __init__(self, form: str = "offset", t_ref: float = 20.0) -> None:
        self.form = form
        self.t_ref = t_ref
        self._last = math.nan

    def reset(self) -> None:
        self._last = math.nan

    def step(self, sample: Sample) -> float:
        if TEMPERATURE_RANGE[0] <= sample.temperature <= TEMPERATURE_RANGE[1]:
            self._last = float(sample.temperature)
        if math.isnan(self._last):
            return 0.0
        dt = self._last - self.t_ref
        return dt * sample.s_hat if self.form == "strain" else dt

    def run(self, batch: Batch) -> np.ndarray:
        temp = batch.temperature
        if temp is None:
            temp = np.full(batch.t.size, np.nan)
        temp = np.where(valid_temperature(temp), temp, np.nan)
        held = ffill(temp, self._last)
        if held.size:
            self._last = float(held[-1])
        dt = np.where(np.isnan(held), 0.0, held - self.t_ref)
        return dt * batch.s_hat if self.form == "strain" else dt

    def params(self) -> dict[str, Any]:
        return {"form": self.form, "t_ref": self.t_ref}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Temperature:
        return cls(choice_param(params, "form", ("offset", "strain"), "offset"),
                   number_param(params, "t_ref", 20.0))


class StrainLevel(Regressor):
    """g = S_hat ** power: a gain (power 1) or curvature (2, 3) error of the static map."""

    kind = "strain_level"
    param_names = ("power",)

    def __init__(self, power: int = 1) -> None:
        self.power = power

    def reset(self) -> None:
        pass

    def step(self, sample: Sample) -> float:
        return float(sample.s_hat) ** self.power

    def run(self, batch: Batch) -> np.ndarray:
        return batch.s_hat ** self.power

    def params(self) -> dict[str, Any]:
        return {"power": self.power}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> StrainLevel:
        power = params.get("power", 1)
        if isinstance(power, bool) or power not in (1, 2, 3):
            raise ParameterError("params.power", f"must be 1, 2 or 3, got {power!r}")
        return cls(int(power))




class Crosstalk(Regressor):
    """Cross-talk in an array: g = the S_hat of the neighbour sensor ``neighbour``."""

    kind = "crosstalk"
    param_names = ("neighbour",)

    def __init__(self, neighbour: str) -> None:
        self._neighbour = neighbour
        self._last = math.nan

    @property
    def neighbour(self) -> str | None:
        return self._neighbour

    def reset(self) -> None:
        self._last = math.nan

    def step(self, sample: Sample) -> float:
        value = (sample.neighbours or {}).get(self._neighbour, math.nan)
        if math.isfinite(value):
            self._last = float(value)
        return 0.0 if math.isnan(self._last) else self._last

    def run(self, batch: Batch) -> np.ndarray:
        values = batch.neighbours.get(self._neighbour)
        if values is None:
            values = np.full(batch.t.size, np.nan)
        held = ffill(values, self._last)
        if held.size:
            self._last = float(held[-1])
        return np.where(np.isnan(held), 0.0, held)

    def params(self) -> dict[str, Any]:
        return {"neighbour": self._neighbour}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Crosstalk:
        neighbour = params.get("neighbour")
        if not isinstance(neighbour, str) or not neighbour:
            raise ParameterError("params.neighbour", f"must be a sensor name, got {neighbour!r}")
        return cls(neighbour)
