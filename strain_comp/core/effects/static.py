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
    checked,
    choice,
    number,
    param_readers,
)
from strain_comp.errors import ParameterError


class Offset(Regressor):
    """g = 1: a constant offset of the estimate (a zero shift between runs)."""

    kind = "offset"

    def run(self, batch: Batch) -> np.ndarray:
        return np.ones(batch.t.size)


TEMPERATURE_RANGE = (-273.15, 1000.0)
"""Temperatures [deg C] a temperature term reads; one outside is a bad reading (missing)."""


class Temperature(Regressor):
    """Temperature: g = T - t_ref (``form: offset``) or (T - t_ref) * S_hat (``form: strain``)."""

    kind = "temperature"
    readers = param_readers(form=choice(("offset", "strain"), "offset"), t_ref=number(20.0))
    initial = (math.nan,)
    form: str
    t_ref: float

    def run(self, batch: Batch) -> np.ndarray:
        temp = batch.temperature
        if temp is None:
            temp = np.full(batch.t.size, np.nan)
        valid = (temp >= TEMPERATURE_RANGE[0]) & (temp <= TEMPERATURE_RANGE[1])
        held = self._held(np.where(valid, temp, np.nan))
        dt = np.where(np.isnan(held), 0.0, held - self.t_ref)
        return dt * batch.s_hat if self.form == "strain" else dt


def _power(params: Mapping[str, Any], key: str) -> int:
    power = params.get(key, 1)
    if isinstance(power, bool) or power not in (1, 2, 3):
        raise ParameterError(f"params.{key}", f"must be 1, 2 or 3, got {power!r}")
    return int(power)


class StrainLevel(Regressor):
    """g = S_hat ** power: a gain (power 1) or curvature (2, 3) error of the static map."""

    kind = "strain_level"
    readers = param_readers(power=_power)
    power: int

    def run(self, batch: Batch) -> np.ndarray:
        return batch.s_hat ** self.power


class Crosstalk(Regressor):
    """Cross-talk in an array: g = the S_hat of the neighbour sensor ``neighbour``."""

    kind = "crosstalk"
    readers = param_readers(neighbour=checked(
        None, lambda name: isinstance(name, str) and bool(name), "a sensor name"))
    initial = (math.nan,)

    def run(self, batch: Batch) -> np.ndarray:
        assert self.neighbour is not None
        values = batch.neighbours.get(self.neighbour)
        if values is None:
            values = np.full(batch.t.size, np.nan)
        held = self._held(values)
        return np.where(np.isnan(held), 0.0, held)
