"""The array lift (``strain_comp.base.lift``): a family that writes only its per-sensor
kernel gets an array step equal to a plain Python loop over its sensors, bad samples
leaving a sensor untouched, ``reset`` returning every sensor to rest; the compile-time
binding (``strain_comp._numba.specialise``) gives each binding its own dispatcher, once."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from strain_comp._numba import njit, specialise
from strain_comp.base.lift import LiftedArray, array_step, lift


@dataclass
class Lag:
    """A toy model: strain = gain * y, y a first-order lag of R with time constant tau."""

    gain: float
    tau: float


@njit(error_model="numpy")
def lag_kernel(s: int, t: float, ri: float, y: np.ndarray, clock: np.ndarray,
               gain: np.ndarray, tau: np.ndarray) -> float:
    """Sensor s: y <- y + (1 - exp(-dt / tau)) (R - y); at rest (clock[s, 1] == 0) y = R."""
    if clock[s, 1] == 0.0:
        y[s, 0] = ri
        clock[s, 1] = 1.0
    else:
        y[s, 0] += -math.expm1(-max(t - clock[s, 0], 0.0) / tau[s]) * (ri - y[s, 0])
    clock[s, 0] = t
    return gain[s] * y[s, 0]


@lift(lag_kernel)
class LagArray(LiftedArray):
    """The lifted family of ``Lag``: nothing written but its tables."""

    model_type = Lag

    @staticmethod
    def rows(model: Lag) -> tuple[tuple[np.ndarray, ...], tuple[float, ...]]:
        return (np.zeros(1), np.zeros(2)), (model.gain, model.tau)


def python_lag(model: Lag, t: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The same law, one sensor, in Python; NaN and the state kept on a bad sample."""
    out = np.full(t.size, np.nan)
    y, t_prev = None, 0.0
    for i, (ti, ri) in enumerate(zip(t, r, strict=True)):
        if not (math.isfinite(ri) and ri > 0):
            continue
        y = ri if y is None else y + (1 - math.exp(-max(ti - t_prev, 0.0) / model.tau)) * (ri - y)
        t_prev = ti
        out[i] = model.gain * y
    return out


def test_a_lifted_family_steps_as_each_sensor_alone() -> None:
    rng = np.random.default_rng(3)
    models = [Lag(gain=rng.uniform(0.1, 2.0), tau=rng.uniform(0.01, 1.0)) for _ in range(7)]
    t = np.cumsum(rng.exponential(0.02, 300))
    r = 100 + 20 * np.sin(np.outer(t, np.arange(1, 8))) + rng.normal(0, 0.5, (300, 7))
    r[40, 2] = np.nan
    r[41:45, 5] = -1.0
    array = LagArray(models)
    got = np.array([array.step(ti, row) for ti, row in zip(t, r, strict=True)])
    for s, model in enumerate(models):
        np.testing.assert_allclose(got[:, s], python_lag(model, t, r[:, s]), rtol=1e-12)
    array.reset()
    np.testing.assert_array_equal(array.step(t[0], r[0]), got[0])


def test_a_binding_is_specialised_once() -> None:
    name = LagArray.array_step.py_func.__name__
    assert name.startswith("array_step__kernel_") and name.endswith("test_lift_lag_kernel")
    with pytest.raises(ValueError, match="specialised already"):
        specialise(array_step, {"kernel": lag_kernel})
