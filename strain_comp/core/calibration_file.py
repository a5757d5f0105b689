"""Calibration files read, checked and written: every problem is one ``CalibrationError``
naming the file and the field, so a hostile file is refused, never half-read; saving is
atomic and checks the text first, so nothing written fails to load."""

from __future__ import annotations

import gc
import math
import os
import stat
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import yaml

from strain_comp.base.compensator import Normalisation, require_float
from strain_comp.base.direction import DirectionSettings
from strain_comp.core.calibration import (
    FORMAT,
    MAX_ALIASES,
    MAX_DEPTH,
    MAX_FILE_BYTES,
    MAX_NODES,
    MAX_SENSOR_BYTES,
    MAX_SENSOR_EFFECTS,
    MAX_SENSORS,
    PARAM_MAX,
    SPAN_GAIN_MAX,
    STRAIN_MAX,
    Calibration,
    InputSettings,
    SensorCalibration,
    ValidRange,
    strain_unit_words,
    unit_problem,
)
from strain_comp.core.chain import DESPIKE_K, PAIR_BRANCHES, STEP_K
from strain_comp.core.effects import validate_effect_dict
from strain_comp.core.engine import Engine
from strain_comp.core.uncertainty import FEATURES, WEIGHT_MAX, Uncertainty
from strain_comp.errors import CalibrationError, InputError, ParameterError
from strain_comp.io.atomic import write_text
from strain_comp.io.safe_yaml import LimitError, load_limited


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

    def bounded(self, node: Any, where: str, limit: float = PARAM_MAX) -> None:
        """Every number inside ``node`` finite and at most ``limit`` in magnitude."""
        # the place is named only for a number refused: a large array has many
        if isinstance(node, Mapping):
            for key, value in node.items():
                self.bounded(value, f"{where}.{key}", limit)
        elif isinstance(node, list):
            if all(type(value) is float and abs(value) <= limit for value in node):
                return
            for i, value in enumerate(node):
                self.bounded(value, f"{where}.{i}", limit)
        elif type(node) in (int, float) or (isinstance(node, (int, float))
                                            and not isinstance(node, bool)):
            if not abs(node) <= limit:
                raise self.fail(where, f"must be finite and at most {limit:g} in magnitude, "
                                f"got {node!r}")

    def sensor(self, name: str, node: Any) -> SensorCalibration:
        """One sensor's entry: every field checked, its model built once."""
        where = f"sensors.{name}"
        node = self.mapping(node, where)
        model_node = self.mapping(self.child(node, "model", where), f"{where}.model")
        model_name = self.child(model_node, "name", f"{where}.model")
        if not isinstance(model_name, str):
            raise self.fail(f"{where}.model.name", f"must be a string, got {model_name!r}")
        params = self.mapping(self.child(model_node, "params", f"{where}.model"),
                              f"{where}.model.params")
        self.bounded(params, f"{where}.model.params")
        rest = (None if node.get("rest_resistance") is None
                else self.number(node, "rest_resistance", where, lo=0.0, strict=True))
        unit = node.get("strain_unit", "%")
        if (problem := unit_problem(unit, "'%' or 'mm'")) is not None:
            raise self.fail(f"{where}.strain_unit", problem)
        interval = (None if node.get("sample_interval") is None
                    else self.number(node, "sample_interval", where, lo=0.0, hi=1e6, strict=True))
        prov = node.get("provenance", {}) or {}
        self.mapping(prov, f"{where}.provenance")
        if prov.get("options") is not None:  # a refit (the in-run bound) reads them
            self.mapping(prov["options"], f"{where}.provenance.options")
        calibration = SensorCalibration(
            name=name, model=model_name, params=dict(params),
            normalisation=self.normalisation(node, where),
            valid_range=self.valid_range(node, where), direction=self.direction(node, where),
            input=self.input(node.get("input", {"kind": "resistance"}), f"{where}.input"),
            effects=self.effects(name, node, where), provenance=dict(prov),
            rest_resistance=rest, strain_unit=unit, sample_interval=interval,
            uncertainty=self.uncertainty(node.get("uncertainty"), f"{where}.uncertainty"))
        try:
            model = calibration.build_model()
        except ParameterError as err:
            prefix = f"{where}.model" if err.field == "name" else f"{where}.model.params"
            raise self.fail(f"{prefix}.{err.field}", err.problem) from None
        line, vr = calibration.input.stretch_line, calibration.valid_range
        slope = (vr.r_hi - vr.r_lo) / (vr.s_hi - vr.s_lo)  # of the calibrated range
        ratio = 1.0 if line is None else abs(line[1]) / slope
        if line is not None and not 1.0 / SPAN_GAIN_MAX <= ratio <= SPAN_GAIN_MAX:
            raise self.fail(f"{where}.input.stretch_line.slope",
                            f"{line[1]:.4g} ohm per strain unit is {ratio:.3g} times the "
                            f"slope of the calibrated range; it must lie within "
                            f"{SPAN_GAIN_MAX:g} times of it either way")
        pole = model.singular_in(calibration.valid_range.r_lo, calibration.valid_range.r_hi)
        if pole is not None:
            raise self.fail(f"{where}.model", f"has no finite strain at R = {pole:.6g} ohm, "
                            "inside its valid range (a pole)")
        return calibration

    def normalisation(self, node: Mapping[str, Any], where: str) -> Normalisation:
        """``normalisation``: r0 and s0 > 0, every number bounded."""
        nw = f"{where}.normalisation"
        norm_node = self.mapping(self.child(node, "normalisation", where), nw)
        self.bounded(norm_node, nw)
        return Normalisation(
            r0=self.number(norm_node, "r0", nw, lo=0.0, strict=True),
            alpha=self.number(norm_node, "alpha", nw),
            s0=self.number(norm_node, "s0", nw, lo=0.0, strict=True),
            beta=self.number(norm_node, "beta", nw),
        )

    def valid_range(self, node: Mapping[str, Any], where: str) -> ValidRange:
        """``valid_range``: resistance in (0, PARAM_MAX], strain within +/- STRAIN_MAX."""
        rw = f"{where}.valid_range"
        range_node = self.mapping(self.child(node, "valid_range", where), rw)
        r_lo, r_hi = self.pair(range_node, "resistance", rw)
        if r_lo <= 0:
            raise self.fail(f"{rw}.resistance", f"must be > 0 ohm, got {r_lo}")
        if r_hi > PARAM_MAX:
            raise self.fail(f"{rw}.resistance", f"must be <= {PARAM_MAX:g} ohm, got {r_hi}")
        s_lo, s_hi = self.pair(range_node, "strain", rw)
        if not (-STRAIN_MAX <= s_lo and s_hi <= STRAIN_MAX):
            raise self.fail(f"{rw}.strain",
                            f"must lie within +/- {STRAIN_MAX:g} %, got [{s_lo}, {s_hi}]")
        return ValidRange(r_lo, r_hi, s_lo, s_hi)

    def direction(self, node: Mapping[str, Any], where: str) -> DirectionSettings:
        """``direction``: the dead zone > 0, tau >= 0, k_sigma null or > 0, the sign."""
        dw = f"{where}.direction"
        dir_node = self.mapping(self.child(node, "direction", where), dw)
        k_sigma, sign = dir_node.get("k_sigma"), dir_node.get("sign", 1)
        if isinstance(sign, bool) or sign not in (1, -1):
            raise self.fail(f"{dw}.sign", f"must be +1 or -1, got {sign!r}")
        return DirectionSettings(
            deadzone=self.number(dir_node, "deadzone", dw, lo=0.0, strict=True),
            tau=self.number(dir_node, "tau", dw, lo=0.0) if "tau" in dir_node else 0.0,
            k_sigma=None if k_sigma is None else self.number(dir_node, "k_sigma", dw, lo=0.0,
                                                             strict=True),
            sign=int(sign),
        )

    def effects(self, name: str, node: Mapping[str, Any], where: str) -> list[dict[str, Any]]:
        """``effects``: valid terms, no cross-talk term reading the sensor ``name`` itself."""
        effects = node.get("effects", []) or []
        if not isinstance(effects, list):
            raise self.fail(f"{where}.effects", "must be a list")
        for i, effect in enumerate(effects):
            effect = self.mapping(effect, f"{where}.effects.{i}")
            try:
                validate_effect_dict(effect)
            except ParameterError as err:
                raise self.fail(f"{where}.effects.{i}.{err.field}", err.problem) from None
            self.bounded({k: effect.get(k) for k in ("params", "coef")}, f"{where}.effects.{i}")
            if (effect.get("kind") == "crosstalk" and isinstance(effect.get("params"), Mapping)
                    and str(effect["params"].get("neighbour")) == name):
                raise self.fail(f"{where}.effects.{i}.params.neighbour",
                                f"a cross-talk term must read another sensor, not {name!r}")
        return [dict(e) for e in effects]

    def sigmas(self, node: Mapping[str, Any], key: str, where: str, default: float
               ) -> float | None:
        """An optional threshold in robust sigmas: off, true (the default) or in (0, 1000)."""
        value = node.get(key)
        if value is None or value is False:
            return None
        if value is True:
            return default
        return self.number(node, key, where, lo=0.0, hi=1000.0, strict=True)

    def zero_span(self, node: Any, where: str) -> tuple[float, float, float] | None:
        """``input.zero_span``: absent or null, else its rest, rest_calibrated and gain."""
        if node is None:
            return None
        node = self.mapping(node, where)
        rest = self.number(node, "rest", where, lo=0.0, hi=PARAM_MAX, strict=True)
        rest_cal = self.number(node, "rest_calibrated", where, lo=0.0, hi=PARAM_MAX,
                               strict=True)
        return rest, rest_cal, self.number(node, "gain", where, lo=0.0, hi=SPAN_GAIN_MAX,
                                           strict=True)

    def stretch_line(self, node: Any, where: str) -> tuple[float, float] | None:
        """``input.stretch_line``: absent or null, else its rest and a non-zero slope."""
        if node is None:
            return None
        node = self.mapping(node, where)
        rest = self.number(node, "rest", where, lo=0.0, hi=PARAM_MAX, strict=True)
        slope = self.number(node, "slope", where, lo=-PARAM_MAX, hi=PARAM_MAX)
        if slope == 0.0:
            raise self.fail(f"{where}.slope", "must not be 0 (a resistance that moves with "
                                              "strain)")
        return rest, slope

    def uncertainty(self, node: Any, where: str) -> Uncertainty | None:
        """``uncertainty``: absent or null, else ``weights`` and counts ``runs``, ``samples``."""
        if node is None:
            return None
        node = self.mapping(node, where)
        unknown = sorted(set(node) - {"weights", "runs", "samples"})
        if unknown:
            raise self.fail(f"{where}.{unknown[0]}", "unknown key (known: weights, runs, "
                            "samples)")
        weights = self.mapping(self.child(node, "weights", where), f"{where}.weights")
        unknown = sorted(str(k) for k in set(weights) - set(FEATURES))
        if unknown:
            raise self.fail(f"{where}.weights.{unknown[0]}",
                            f"unknown feature (known: {', '.join(FEATURES)})")
        values = {name: self.number(weights, name, f"{where}.weights", lo=-WEIGHT_MAX,
                                    hi=WEIGHT_MAX) for name in weights}
        counts = [0 if node.get(key) is None else
                  int(self.number(node, key, where, lo=0.0, hi=1e15)) for key in ("runs",
                                                                                "samples")]
        return Uncertainty.from_weights(values, *counts)

    def input(self, node: Any, where: str) -> InputSettings:
        node = self.mapping(node, where)
        kind = node.get("kind", "resistance")
        alternation = node.get("alternation", False)
        if not isinstance(alternation, bool):
            raise self.fail(f"{where}.alternation", f"must be true or false, got {alternation!r}")
        pair = node.get("pair", "mean")
        if pair not in PAIR_BRANCHES:
            raise self.fail(f"{where}.pair", f"must be one of {', '.join(PAIR_BRANCHES)}, "
                                             f"got {pair!r}")
        if pair != "mean" and not alternation:
            raise self.fail(f"{where}.pair", f"{pair!r} needs alternation: true (without it "
                                             "the models see the samples themselves)")
        despike = self.sigmas(node, "despike", where, DESPIKE_K)
        step = self.sigmas(node, "baseline_step", where, STEP_K)
        span = self.zero_span(node.get("zero_span"), f"{where}.zero_span")
        line = self.stretch_line(node.get("stretch_line"), f"{where}.stretch_line")
        unit = node.get("unit", "ohm")
        if (problem := unit_problem(unit, "'ohm' or 'R/R0'")) is not None:
            raise self.fail(f"{where}.unit", problem)
        if kind not in ("resistance", "divider"):
            raise self.fail(f"{where}.kind", f"must be 'resistance' or 'divider', got {kind!r}")
        if kind == "divider" and unit != "ohm":
            raise self.fail(f"{where}.unit", "a divider's resistance is in ohm (as r1), got "
                            f"{unit!r}")
        divider = {key: self.number(node, key, where, lo=0.0, strict=True)
                   for key in ("r1", "vin")} if kind == "divider" else {}
        return InputSettings(kind, alternation=alternation, pair=pair, despike=despike,
                             baseline_step=step, zero_span=span, stretch_line=line, unit=unit,
                             **divider)


def read_text(path: str | os.PathLike[str]) -> str:
    """The text of the calibration file ``path``: regular (never a FIFO), UTF-8, not too large."""
    reader = _Reader(str(path))
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise reader.fail("file", "cannot read: not a regular file")
        with open(path, "rb") as handle:
            data = handle.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise reader.fail("file", f"refused: larger than {MAX_FILE_BYTES} bytes")
        return data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise reader.fail("file", f"cannot read: {err}") from None


def _parse_fields(text: str, reader: _Reader) -> Calibration:
    try:
        root = load_limited(text, max_aliases=MAX_ALIASES, max_nodes=MAX_NODES,
                            max_depth=MAX_DEPTH)
    except LimitError as err:
        raise reader.fail("yaml", f"refused: {err}") from None
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
    if len(sensors) > MAX_SENSORS:
        raise reader.fail("sensors", f"refused: {len(sensors)} sensors, at most {MAX_SENSORS}")
    size = len(text.encode("utf-8"))
    if size > MAX_SENSOR_BYTES * (len(sensors) + 1):
        raise reader.fail("file", f"refused: {size} bytes for {len(sensors)} sensors, at most "
                          f"{MAX_SENSOR_BYTES} per sensor")
    for name, node in sensors.items():
        effects = node.get("effects") if isinstance(node, dict) else None
        if isinstance(effects, list) and len(effects) > MAX_SENSOR_EFFECTS:
            raise reader.fail(f"sensors.{name}.effects", f"refused: {len(effects)} effect "
                              f"terms, at most {MAX_SENSOR_EFFECTS} per sensor")
    return Calibration({str(name): reader.sensor(str(name), node)
                        for name, node in sensors.items()})


def _plain(value: Any) -> Any:
    """Numpy scalars/arrays and tuples to plain Python, recursively, for safe YAML."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):
        return _plain(value.tolist())
    return value


def calibration_text(calibration: Calibration) -> str:
    """The YAML text ``save_calibration`` writes."""
    return yaml.safe_dump(_plain(calibration.to_dict()), sort_keys=False,
                          default_flow_style=None, width=100)


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and validate a calibration file."""
    return parse_calibration(read_text(path), str(path))


def parse_calibration(text: str, path: str) -> Calibration:
    """Validate the text of a calibration file: the limits, the fields, the probe."""
    # the cyclic garbage collector is paused: a large array's many small objects, no cycles
    collecting = gc.isenabled()
    gc.disable()
    try:
        calibration = _parse_fields(text, _Reader(path))
    finally:
        if collecting:
            gc.enable()
    probed: dict[str, str | None] = {}
    for name, cal in calibration.sensors.items():
        key = repr({**cal.to_dict(), "provenance": None})  # alike sensors: one probe
        if key not in probed:
            probed[key] = probe_calibration(cal)
        where = probed[key]
        if where is not None:
            raise CalibrationError(path, f"sensors.{name}", f"gives a non-finite strain "
                                   f"({where}); its parameters are out of any usable range")
    return calibration


def check_calibration(calibration: Calibration, path: str | os.PathLike[str] = "calibration"
                      ) -> str:
    """The text ``save_calibration`` writes, after the load-time checks on it."""
    text = calibration_text(calibration)
    if len(text.encode("utf-8")) > MAX_FILE_BYTES:
        raise CalibrationError(str(path), "file", f"refused: larger than {MAX_FILE_BYTES} bytes")
    parse_calibration(text, str(path))
    return text


def save_calibration(calibration: Calibration, path: str | os.PathLike[str], *,
                     inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
    """Write atomically (a crash leaves the old or the new file), checked first."""
    try:
        text = check_calibration(calibration, path)
    except CalibrationError as err:
        raise CalibrationError(err.path, err.field,
                               f"not written, it would not load: {err.problem}") from None
    write_text(path, text, inputs=inputs)


def probe_calibration(cal: SensorCalibration) -> str | None:
    """Where the engine gives a non-finite strain on this sensor's probe (25 deg C), or None."""
    # no input zero and span: a probe value it maps below the short level would be screened out
    probe = SensorCalibration(**{**vars(cal), "input": replace(cal.input, zero_span=None),
                                 "effects": [e for e in cal.effects
                                             if e.get("kind") != "crosstalk"]})
    engine = Engine(Calibration({cal.name: probe}))
    # log-spaced from short to open (0.01 x the bottom to 100 x the top of the valid range)
    # and back, slowly, fast, and with a long hold
    lo, hi = math.log(cal.valid_range.r_lo * 0.011), math.log(cal.valid_range.r_hi * 99.0)
    up = np.exp(np.linspace(lo, hi, 200))
    r = np.concatenate([up, up[::-1], up[::4], up[::-4], np.full(50, up[100])])
    t = np.concatenate([np.arange(400) * 0.05, 20.0 + np.arange(100) * 0.01,
                        21.0 + np.arange(50) * 2.0])
    with np.errstate(all="ignore"):
        out = engine.run(cal.name, t, r, np.full(t.size, 25.0))
    bad = np.flatnonzero(~np.isfinite(out.strain))
    return None if bad.size == 0 else f"R = {r[bad[0]]:.6g} ohm at t = {t[bad[0]]:g} s"


def loadable(cal: SensorCalibration, change: str) -> SensorCalibration:
    """``cal`` after the load-time checks (the API refuses what the command line's write does)."""
    try:
        check_calibration(Calibration({cal.name: cal}))
    except CalibrationError as err:
        raise InputError(f"recalibration of {cal.name!r}: {change} gives a calibration that "
                         f"would not load ({err.problem}); check the known strains (in "
                         f"{strain_unit_words(cal.strain_unit)}) and resistances") from None
    return cal
