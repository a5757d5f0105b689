"""Voltage-divider readings to resistance ([Electrolycra] section II.A): the sensor in series
with R1 under a supply Vin, the voltage across R1 measured, R = R1 (Vin - V_R1) / V_R1.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit
from strain_comp.base import samples as sc


@njit(error_model="numpy")
def divider_ohm(v: float, r1: float, vin: float) -> tuple[float, int]:
    """(R, forced status): NaN and open (short) circuit at V <= 0 (V >= Vin)."""
    if v <= 0.0:
        return np.nan, sc.OPEN_CIRCUIT
    if v >= vin:
        return np.nan, sc.SHORT_CIRCUIT
    return r1 * (vin - v) / v, sc.GOOD


@njit
def divider_all(v: np.ndarray, r1: float, vin: float) -> tuple[np.ndarray, np.ndarray]:
    """``divider_ohm`` over a batch."""
    ohm = np.empty(v.size)
    forced = np.empty(v.size, np.int8)
    for i in range(v.size):
        ohm[i], forced[i] = divider_ohm(v[i], r1, vin)
    return ohm, forced


def divider_to_resistance(v_r1: npt.ArrayLike, r1: float, vin: float) -> np.ndarray:
    """Sensor resistance from the voltage across the series resistor (NaN outside (0, Vin))."""
    v = np.asarray(v_r1, dtype=np.float64)
    ohm, _ = divider_all(np.ascontiguousarray(v.ravel()), float(r1), float(vin))
    return ohm.reshape(v.shape)


def resistance_to_divider(r: npt.ArrayLike, r1: float, vin: float) -> np.ndarray:
    """Voltage across the series resistor for a sensor resistance, V_R1 = Vin R1 / (R1 + R)."""
    return vin * r1 / (r1 + np.asarray(r, dtype=np.float64))
