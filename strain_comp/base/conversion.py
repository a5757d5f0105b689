"""Input conversion: voltage-divider readings to resistance.

[Electrolycra] section II.A: the sensor in series with a known resistor R1 under a
supply Vin; the voltage across R1 is measured and R = R1 (Vin - V_R1) / V_R1.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def divider_to_resistance(v_r1: npt.ArrayLike, r1: float, vin: float) -> np.ndarray:
    """Sensor resistance from the voltage across the series resistor, R = R1 (Vin - V) / V."""
    v = np.asarray(v_r1, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = r1 * (vin - v) / v
    return np.where((v > 0.0) & (v < vin), r, np.nan)


def resistance_to_divider(r: npt.ArrayLike, r1: float, vin: float) -> np.ndarray:
    """Voltage across the series resistor for a sensor resistance, V_R1 = Vin R1 / (R1 + R)."""
    return vin * r1 / (r1 + np.asarray(r, dtype=np.float64))
