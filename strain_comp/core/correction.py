"""A sensor's one correction, R' = rest + gain (R - zero) on the input and S' = output_gain
S + output_offset on the output, which every estimator of a session's change writes; its
file form: docs/design.md, "Calibration file"."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from strain_comp.core.calibration import SensorCalibration

RECALIBRATION_TERMS = ("recalibration_gain", "recalibration_offset")
"""The two effect terms holding the output map in a file: a map, not a term of what moves."""
_GAIN_TERM = {"name": RECALIBRATION_TERMS[0], "kind": "strain_level", "params": {"power": 1}}
_OFFSET_TERM = {"name": RECALIBRATION_TERMS[1], "kind": "offset", "params": {}}


@dataclass(frozen=True)
class Correction:
    """One sensor's input map and output map (module docstring)."""

    zero: float = 0.0
    rest: float = 0.0
    gain: float = 1.0
    output_gain: float = 1.0
    output_offset: float = 0.0

    @classmethod
    def of(cls, cal: SensorCalibration) -> Correction:
        """The correction a calibration holds (its file form, module docstring)."""
        zero, rest, gain = cal.input.zero_span or (0.0, 0.0, 1.0)
        gain_coef, offset_coef = (sum(float(e["coef"]) for e in cal.effects
                                      if _is_output_term(e) and e.get("name") == name)
                                  for name in RECALIBRATION_TERMS)
        a, b = 1.0 - gain_coef, -offset_coef
        if not (math.isfinite(a) and a > 0 and math.isfinite(b)):  # the terms act as they stand
            a, b = 1.0, 0.0
        return cls(zero, rest, gain, a, b)

    @property
    def has_input(self) -> bool:
        """True when the input map is not the identity."""
        return (self.zero, self.rest, self.gain) != (0.0, 0.0, 1.0)

    @property
    def has_output(self) -> bool:
        """True when the output map is not the identity."""
        return (self.output_gain, self.output_offset) != (1.0, 0.0)

    def apply_input(self, ohm: Any, tare: float = 1.0) -> Any:
        """``ohm`` x the engine's ``tare`` gain, through the input map."""
        ohm = ohm * tare if tare != 1.0 else ohm
        if not self.has_input:
            return ohm
        return self.gain * ohm + (self.rest - self.gain * self.zero)

    def apply_output(self, strain: Any) -> Any:
        """``strain`` through the output map."""
        if not self.has_output:
            return strain
        return self.output_gain * strain + self.output_offset

    def with_input(self, zero: float, rest: float, gain: float) -> Correction:
        """This correction with a new input map replacing the old (both map measured R)."""
        return replace(self, zero=float(zero), rest=float(rest), gain=float(gain))

    def with_output(self, gain: float, offset: float) -> Correction:
        """This correction followed by the output map S' = gain S + offset (composed)."""
        return replace(self, output_gain=gain * self.output_gain,
                       output_offset=gain * self.output_offset + offset)

    def effects(self, effects: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """The other effect terms of ``effects``, coefficients before the output map."""
        if not self.has_output:
            return [dict(e) for e in effects]
        return [dict(e, coef=float(e["coef"]) / self.output_gain) for e in effects
                if not _is_output_term(e)]

    def written(self, cal: SensorCalibration) -> SensorCalibration:
        """``cal`` holding this correction in the file form (replacing what it held)."""
        a, b = self.output_gain, self.output_offset
        held = Correction.of(cal)
        if (a, b) == (held.output_gain, held.output_offset):  # the terms as they stand
            effects = list(cal.effects)
        else:
            effects = [dict(e, coef=a * float(e["coef"])) for e in held.effects(cal.effects)]
            if self.has_output:
                effects += [dict(_GAIN_TERM, coef=1.0 - a), dict(_OFFSET_TERM, coef=-b)]
        span = (self.zero, self.rest, self.gain) if self.has_input else None
        return replace(cal, input=replace(cal.input, zero_span=span), effects=effects)


def _is_output_term(effect: Mapping[str, Any]) -> bool:
    """True for one of the two effect terms that hold the output map."""
    for term in (_GAIN_TERM, _OFFSET_TERM):
        if effect.get("name") == term["name"] and effect.get("kind") == term["kind"]:
            params = effect.get("params") or {}
            return term["kind"] == "offset" or params.get("power", 1) == 1
    return False
