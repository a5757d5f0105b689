"""Dead-zone direction detector (egain_rational... section V.E): loading / hold / unloading."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class DirectionSettings:
    """Settings of the dead-zone direction detector.

    ``deadzone`` [ohm/s] on the causal derivative of R, low-pass filtered with time
    constant ``tau`` [s]; ``k_sigma`` records how the dead zone was set (k times the
    derivative noise on a hold segment), or None when it was given in ohm/s.
    """

    deadzone: float
    tau: float = 0.0
    k_sigma: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"deadzone": self.deadzone, "tau": self.tau, "k_sigma": self.k_sigma}
