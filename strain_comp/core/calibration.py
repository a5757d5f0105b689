"""Calibration files in memory, format ``strain_comp/calibration/v1`` (docs/design.md,
"Calibration file"), and the limits a file may hold (checked by ``calibration_file``).
Floats are written with Python's shortest round-trip repr, so load(save(c)) == c exactly."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from html import escape
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import Compensator, Normalisation
from strain_comp.base.conversion import divider_to_resistance
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.registry import model_class
from strain_comp.core.uncertainty import Uncertainty
from strain_comp.errors import ParameterError, StrainCompError
from strain_comp.version import __version__

FORMAT = "strain_comp/calibration/v1"
MAX_SENSORS = 4096
MAX_SENSOR_BYTES = 8 * 2**10
"""Bytes per sensor: an APL sensor with two effect terms and its provenance is ~1.3 kB."""
MAX_FILE_BYTES = 8 * 2**20
"""Bytes of any file before it is parsed: 4096 sensors of 2 KiB."""
MAX_SENSOR_EFFECTS = 16
MAX_ALIASES = 100
MAX_NODES = 256 * MAX_SENSORS
MAX_DEPTH = 64
PARAM_MAX = 1e12
STRAIN_MAX = 1e6
SPAN_GAIN_MAX = 1000.0
"""The most an input's sensitivity (zero_span gain, stretch line) may differ, either way."""


def check_reference(name: str, s: npt.ArrayLike, error: type[StrainCompError]) -> None:
    """No finite reference strain beyond +/- ``STRAIN_MAX`` (for ``fit`` and ``evaluate``)."""
    values = np.asarray(s, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        top = float(np.max(np.abs(values), initial=0.0, where=np.isfinite(values)))
    if top > STRAIN_MAX:
        raise error(f"sensor {name!r}: the reference strain reaches {top:.4g}, beyond the "
                    f"+/- {STRAIN_MAX:g} a calibration holds; import it in a larger unit "
                    "(microstrain to %: import-csv --scales strain=1e-4)")


@dataclass(frozen=True)
class InputSettings:
    """The calibration's ``input`` (docs/design.md, "Calibration file")."""

    kind: str = "resistance"
    r1: float | None = None
    vin: float | None = None
    alternation: bool = False
    pair: str = "mean"
    despike: float | None = None
    baseline_step: float | None = None
    zero_span: tuple[float, float, float] | None = None
    """(rest [ohm], rest_calibrated [ohm], gain k) of ``core.correction``'s input map."""
    stretch_line: tuple[float, float] | None = None
    """(R_0 [ohm], g [ohm per strain unit]) of the pooled stretch R = R_0 + g S, or None."""
    unit: str = "ohm"
    """The unit of the resistance the models read (``ohm``, ``R/R0``, ...)."""

    @property
    def rate_unit(self) -> str:
        """The unit of the dead zone: the input's per second (``ohm/s`` by default)."""
        return f"{self.unit}/s"

    @property
    def filtered(self) -> bool:
        """True when the models see the input through a measurement-chain correction."""
        return self.alternation or self.despike is not None or self.baseline_step is not None

    def to_dict(self) -> dict[str, Any]:
        extra: dict[str, Any] = {"alternation": True} if self.alternation else {}
        if self.alternation and self.pair != "mean":
            extra["pair"] = self.pair
        if self.despike is not None:
            extra["despike"] = self.despike
        if self.baseline_step is not None:
            extra["baseline_step"] = self.baseline_step
        if self.zero_span is not None:
            rest, rest_cal, k = self.zero_span
            extra["zero_span"] = {"rest": rest, "rest_calibrated": rest_cal, "gain": k}
        if self.stretch_line is not None:
            extra["stretch_line"] = {"rest": self.stretch_line[0],
                                     "slope": self.stretch_line[1]}
        if self.unit != "ohm":
            extra["unit"] = self.unit
        if self.kind == "divider":
            return {"kind": "divider", "r1": self.r1, "vin": self.vin, **extra}
        return {"kind": "resistance", **extra}

    def to_ohm(self, raw: npt.ArrayLike) -> np.ndarray:
        """Resistance [ohm] of raw input values (divider readings outside (0, Vin): NaN)."""
        if self.kind == "divider":
            return divider_to_resistance(raw, *self.divider())
        return np.asarray(raw, dtype=np.float64)

    def divider(self) -> tuple[float, float]:
        """(r1 [ohm], vin [V]) of a ``divider`` input; ParameterError for other kinds."""
        if self.kind != "divider" or self.r1 is None or self.vin is None:
            raise ParameterError("input", f"not a voltage divider: {self.to_dict()}")
        return float(self.r1), float(self.vin)


@dataclass(frozen=True)
class ValidRange:
    """Resistance [ohm] and strain [%] range the calibration was fitted over."""

    r_lo: float
    r_hi: float
    s_lo: float
    s_hi: float

    def to_dict(self) -> dict[str, list[float]]:
        return {"resistance": [self.r_lo, self.r_hi], "strain": [self.s_lo, self.s_hi]}


@dataclass
class SensorCalibration:
    """Everything needed to turn one sensor's resistance into strain."""

    name: str
    model: str
    params: dict[str, Any]
    normalisation: Normalisation
    valid_range: ValidRange
    direction: DirectionSettings
    input: InputSettings = field(default_factory=InputSettings)
    effects: list[dict[str, Any]] = field(default_factory=list)
    provenance: dict[str, Any] = field(default_factory=dict)
    rest_resistance: float | None = None
    """Resistance at rest (zero strain) when the calibration was made [ohm]: the tare's zero."""
    strain_unit: str = "%"
    """The unit of the strain the model gives: that of the training reference ("%", "mm")."""
    sample_interval: float | None = None
    """Median sample interval of a slow instrument's training data [s] (``samples.gap_for``)."""
    uncertainty: Uncertainty | None = None
    """The learned standard deviation of every estimate; None: no band."""

    def __repr__(self) -> str:
        """Short: the name, model, ranges and fit error, not the parameters (``to_dict``)."""
        vr, fit = self.valid_range, self.fit_rmse()
        return (f"SensorCalibration({self.name!r}, {self.model}, {vr.r_lo:.4g}-{vr.r_hi:.4g} "
                f"{self.input.unit} -> {vr.s_lo:.4g}-{vr.s_hi:.4g} {self.strain_unit}"
                + ("" if fit is None else f", fit RMSE {fit:.4g}") + ")")

    def fit_rmse(self) -> float | None:
        """The fit's RMSE from the provenance (None when it holds no number)."""
        fit = self.provenance.get("fit_rmse")
        return float(fit) if isinstance(fit, (int, float)) and not isinstance(fit, bool) \
            else None

    @property
    def input_rest(self) -> float | None:
        """The rest [ohm] a tare refers to: ``zero_span``'s rest, else ``rest_resistance``."""
        span = self.input.zero_span
        return span[0] if span is not None else self.rest_resistance

    def build_model(self) -> Compensator:
        """A fresh compensator with these parameters."""
        return model_class(self.model).from_params(self.params, self.normalisation,
                                                  direction=self.direction)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": {"name": self.model, "params": self.params},
            "normalisation": self.normalisation.to_dict(),
            "input": self.input.to_dict(),
            "valid_range": self.valid_range.to_dict(),
            **({} if self.rest_resistance is None else {"rest_resistance": self.rest_resistance}),
            **({} if self.strain_unit == "%" else {"strain_unit": self.strain_unit}),
            **({} if self.sample_interval is None
               else {"sample_interval": self.sample_interval}),
            **({} if self.uncertainty is None else {"uncertainty": self.uncertainty.to_dict()}),
            "direction": self.direction.to_dict(),
            "effects": self.effects,
            "provenance": self.provenance,
        }


@dataclass
class Calibration:
    """A calibration file: sensors by name, in file order (the order of an array)."""

    sensors: dict[str, SensorCalibration]

    def __repr__(self) -> str:
        """Short: each sensor's name, model and fit error (``to_dict`` has everything)."""
        parts = [f"{name} ({cal.model}" + ("" if cal.fit_rmse() is None else
                                            f", fit RMSE {cal.fit_rmse():.4g} "
                                            f"{strain_unit_words(cal.strain_unit)}") + ")"
                 for name, cal in self.sensors.items()]
        return f"Calibration({len(parts)} sensor{'s' if len(parts) != 1 else ''}: " \
               f"{', '.join(parts)})"

    def _repr_html_(self) -> str:
        """A small table for a notebook: sensor, model, ranges, fit RMSE, unit."""
        head = ("sensor", "model", "resistance range", "strain range", "fit RMSE", "unit")
        rows = ["<tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
        for name, cal in self.sensors.items():
            vr, fit = cal.valid_range, cal.fit_rmse()
            cells = (name, cal.model, f"{vr.r_lo:.4g} to {vr.r_hi:.4g} {cal.input.unit}",
                     f"{vr.s_lo:.4g} to {vr.s_hi:.4g}",
                     "" if fit is None else f"{fit:.4g}", strain_unit_words(cal.strain_unit))
            rows.append("<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in cells) + "</tr>")
        return "<table>" + "".join(rows) + "</table>"

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT,
                "sensors": {name: cal.to_dict() for name, cal in self.sensors.items()}}


def unit_problem(unit: object, example: str) -> str | None:
    """Why ``unit`` is no strain or input unit a file may name (None: it is one)."""
    if isinstance(unit, str) and 0 < len(unit) <= 16 and all(c.isalnum() or c in "%/."
                                                               for c in unit):
        return None
    return f"must be a unit such as {example} (1-16 letters, digits, %, / or .), got {unit!r}"


def strain_unit_words(unit: str) -> str:
    """How a number in ``unit`` reads."""
    return "% strain" if unit == "%" else unit


def provenance(bags: list[str], fit_rmse: float, n_samples: int, **extra: Any) -> dict[str, Any]:
    """A provenance record of a fit."""
    from datetime import datetime, timezone

    record: dict[str, Any] = {
        "bags": [str(b) for b in bags],
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "fit_rmse": float(fit_rmse),
        "n_samples": int(n_samples),
        "tool": f"strain_comp {__version__}",
    }
    record.update(extra)
    return record


def expected_error(cal: SensorCalibration) -> dict[str, Any] | None:
    """The provenance's ``expected_error`` (``fit --model auto``), when it holds a valid one."""
    found = cal.provenance.get("expected_error")
    if not isinstance(found, dict):
        return None
    try:
        median, worst = float(found["median"]), float(found["worst"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (math.isfinite(median) and math.isfinite(worst)):
        return None
    return dict(found, median=median, worst=worst, unit=str(found.get("unit", cal.strain_unit)))


def expected_words(cal: SensorCalibration) -> str | None:
    """``expected on a new session: RMSE 4.8 % strain (median), ...``; None without one."""
    found = expected_error(cal)
    if found is None:
        return None
    runs = found.get("runs")
    over = f" over {runs} runs left out" if isinstance(runs, int) else ""
    return (f"expected on a new session: RMSE {found['median']:.3g} "
            f"{strain_unit_words(found['unit'])} (median), {found['worst']:.3g} at worst{over}")
