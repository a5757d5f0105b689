"""Calibration files: YAML, one per sensor or one for an array.

Format ``strain_comp/calibration/v1``:

```yaml
format: strain_comp/calibration/v1
sensors:
  s1:
    model: {name: apl, params: {...}}        # every model parameter (see strain_comp.models)
    normalisation: {r0: .., alpha: .., s0: .., beta: ..}   # xi = R/r0 + alpha, psi = S/s0 + beta
    input: {kind: resistance}                # or {kind: divider, r1: ohm, vin: volt}
    valid_range: {resistance: [lo, hi], strain: [lo, hi]}  # ohm, %
    rest_resistance: ohm                     # optional: R at rest when fitted (the tare's zero)
    direction: {deadzone: ohm/s, tau: s, k_sigma: null|number, sign: 1|-1}  # sign optional
    effects: []                              # added effect terms (strain_comp.core.effects)
    provenance: {bags: [..], created: .., fit_rmse: .., n_samples: .., tool: ..}
```

Loading validates everything and raises one ``CalibrationError`` naming the file and the
dotted field. Saving is atomic: a temporary file in the same directory, fsync, rename.
Floats are written with Python's shortest round-trip repr, so load(save(c)) == c exactly.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from strain_comp import __version__
from strain_comp.core.direction import DirectionSettings
from strain_comp.core.effects import validate_effect_dict
from strain_comp.errors import CalibrationError, ParameterError
from strain_comp.io.atomic import write_text
from strain_comp.models import Compensator, Normalisation, model_class
from strain_comp.models.base import require_float

FORMAT = "strain_comp/calibration/v1"


@dataclass(frozen=True)
class InputSettings:
    """What the input topic carries: ``resistance`` in ohm, or ``divider`` volts across R1;
    ``alternation``: the excitation alternates every sample, so the models and the
    direction detector see pair means (``strain_comp.core.chain``)."""

    kind: str = "resistance"
    r1: float | None = None
    vin: float | None = None
    alternation: bool = False

    def to_dict(self) -> dict[str, Any]:
        extra = {"alternation": True} if self.alternation else {}
        if self.kind == "divider":
            return {"kind": "divider", "r1": self.r1, "vin": self.vin, **extra}
        return {"kind": "resistance", **extra}


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
    """Resistance at rest (zero strain) when the calibration was made [ohm]; a tare scales
    the measured resistance by rest_resistance / (the rest resistance measured now)."""

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
            "direction": self.direction.to_dict(),
            "effects": self.effects,
            "provenance": self.provenance,
        }


@dataclass
class Calibration:
    """A calibration file: sensors by name, in file order (the order of an array)."""

    sensors: dict[str, SensorCalibration]

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT,
                "sensors": {name: cal.to_dict() for name, cal in self.sensors.items()}}


def provenance(bags: list[str], fit_rmse: float, n_samples: int, **extra: Any) -> dict[str, Any]:
    """A provenance record: source bags, time of the fit (UTC, ISO 8601), fit error."""
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


def _plain(value: Any) -> Any:
    """Numpy scalars/arrays and tuples to plain Python, recursively, for safe YAML."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):
        return _plain(value.tolist())
    return value


def save_calibration(calibration: Calibration, path: str | os.PathLike[str], *,
                     inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
    """Write atomically (``strain_comp.io.atomic``): a crash at any moment leaves the old or
    the new file, never a mix; a target that is one of ``inputs`` or not a regular file is
    refused."""
    text = yaml.safe_dump(_plain(calibration.to_dict()), sort_keys=False,
                          default_flow_style=None, width=100)
    write_text(path, text, inputs=inputs)


class _Reader:
    """Validating reader that turns every problem into one CalibrationError."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> CalibrationError:
        return CalibrationError(self.path, where, problem)

    def mapping(self, node: Any, where: str) -> Mapping[str, Any]:
        if not isinstance(node, Mapping):
            raise self.fail(where, f"must be a mapping, got {type(node).__name__}")
        return node

    def child(self, node: Mapping[str, Any], key: str, where: str) -> Any:
        if key not in node:
            raise self.fail(f"{where}.{key}" if where else key, "missing")
        return node[key]

    def number(self, node: Mapping[str, Any], key: str, where: str, **bounds: Any) -> float:
        try:
            return require_float(node, key, **bounds)
        except ParameterError as err:
            raise self.fail(f"{where}.{err.field}", err.problem) from None

    def pair(self, node: Mapping[str, Any], key: str, where: str) -> tuple[float, float]:
        value = self.child(node, key, where)
        if not (isinstance(value, list) and len(value) == 2):
            raise self.fail(f"{where}.{key}", f"must be a list [lo, hi], got {value!r}")
        lo = self.number({"lo": value[0]}, "lo", f"{where}.{key}")
        hi = self.number({"hi": value[1]}, "hi", f"{where}.{key}")
        if not hi > lo:
            raise self.fail(f"{where}.{key}", f"hi must be > lo, got [{lo}, {hi}]")
        return lo, hi

    def sensor(self, name: str, node: Any) -> SensorCalibration:
        where = f"sensors.{name}"
        node = self.mapping(node, where)
        model_node = self.mapping(self.child(node, "model", where), f"{where}.model")
        model_name = self.child(model_node, "name", f"{where}.model")
        if not isinstance(model_name, str):
            raise self.fail(f"{where}.model.name", f"must be a string, got {model_name!r}")
        params = self.mapping(self.child(model_node, "params", f"{where}.model"),
                              f"{where}.model.params")
        norm_node = self.mapping(self.child(node, "normalisation", where), f"{where}.normalisation")
        nw = f"{where}.normalisation"
        norm = Normalisation(
            r0=self.number(norm_node, "r0", nw, lo=0.0, strict=True),
            alpha=self.number(norm_node, "alpha", nw),
            s0=self.number(norm_node, "s0", nw, lo=0.0, strict=True),
            beta=self.number(norm_node, "beta", nw),
        )
        range_node = self.mapping(self.child(node, "valid_range", where), f"{where}.valid_range")
        r_lo, r_hi = self.pair(range_node, "resistance", f"{where}.valid_range")
        if r_lo <= 0:
            raise self.fail(f"{where}.valid_range.resistance", f"must be > 0 ohm, got {r_lo}")
        s_lo, s_hi = self.pair(range_node, "strain", f"{where}.valid_range")
        rest = (None if node.get("rest_resistance") is None
                else self.number(node, "rest_resistance", where, lo=0.0, strict=True))
        dir_node = self.mapping(self.child(node, "direction", where), f"{where}.direction")
        dw = f"{where}.direction"
        k_sigma = dir_node.get("k_sigma")
        direction = DirectionSettings(
            deadzone=self.number(dir_node, "deadzone", dw, lo=0.0, strict=True),
            tau=self.number(dir_node, "tau", dw, lo=0.0) if "tau" in dir_node else 0.0,
            k_sigma=None if k_sigma is None else self.number(dir_node, "k_sigma", dw, lo=0.0,
                                                             strict=True),
            sign=self.sign(dir_node, dw),
        )
        input_settings = self.input(node.get("input", {"kind": "resistance"}), f"{where}.input")
        effects = node.get("effects", []) or []
        if not isinstance(effects, list):
            raise self.fail(f"{where}.effects", "must be a list")
        for i, effect in enumerate(effects):
            effect = self.mapping(effect, f"{where}.effects.{i}")
            if not isinstance(effect.get("name"), str):
                raise self.fail(f"{where}.effects.{i}.name", "missing or not a string")
            try:
                validate_effect_dict(effect)
            except ParameterError as err:
                raise self.fail(f"{where}.effects.{i}.{err.field}", err.problem) from None
        prov = node.get("provenance", {}) or {}
        self.mapping(prov, f"{where}.provenance")
        calibration = SensorCalibration(
            name=name, model=model_name, params=dict(params), normalisation=norm,
            valid_range=ValidRange(r_lo, r_hi, s_lo, s_hi), direction=direction,
            input=input_settings, effects=[dict(e) for e in effects], provenance=dict(prov),
            rest_resistance=rest)
        try:
            calibration.build_model()
        except ParameterError as err:
            prefix = f"{where}.model" if err.field == "name" else f"{where}.model.params"
            raise self.fail(f"{prefix}.{err.field}", err.problem) from None
        return calibration

    def sign(self, node: Mapping[str, Any], where: str) -> int:
        """Optional ``sign``: +1 (R rises with strain, the default) or -1 (R falls)."""
        value = node.get("sign", 1)
        if isinstance(value, bool) or value not in (1, -1):
            raise self.fail(f"{where}.sign", f"must be +1 or -1, got {value!r}")
        return int(value)

    def input(self, node: Any, where: str) -> InputSettings:
        node = self.mapping(node, where)
        kind = node.get("kind", "resistance")
        alternation = node.get("alternation", False)
        if not isinstance(alternation, bool):
            raise self.fail(f"{where}.alternation", f"must be true or false, got {alternation!r}")
        if kind == "resistance":
            return InputSettings(alternation=alternation)
        if kind == "divider":
            return InputSettings("divider", r1=self.number(node, "r1", where, lo=0.0, strict=True),
                                 vin=self.number(node, "vin", where, lo=0.0, strict=True),
                                 alternation=alternation)
        raise self.fail(f"{where}.kind", f"must be 'resistance' or 'divider', got {kind!r}")


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and validate a calibration file; CalibrationError names the file and field."""
    path_str = str(path)
    reader = _Reader(path_str)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise reader.fail("file", f"cannot read: {err}") from None
    try:
        root = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "yaml"
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise reader.fail(where, f"not valid YAML: {problem}") from None
    root = reader.mapping(root, "(top level)")
    fmt = reader.child(root, "format", "")
    if fmt != FORMAT:
        raise reader.fail("format", f"must be {FORMAT!r}, got {fmt!r}")
    sensors = reader.mapping(reader.child(root, "sensors", ""), "sensors")
    if not sensors:
        raise reader.fail("sensors", "must name at least one sensor")
    return Calibration({str(name): reader.sensor(str(name), node)
                        for name, node in sensors.items()})
