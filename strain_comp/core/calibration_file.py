"""Calibration files loaded and saved with every load-time check: the fields
(``calibration_reader``) and a probe through the engine (a sensor giving a non-finite
strain there is refused). Saving is atomic and checks the text first: nothing written
fails to load.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import yaml

from strain_comp.core.calibration import (
    MAX_FILE_BYTES,
    Calibration,
    SensorCalibration,
    strain_unit_words,
)
from strain_comp.core.calibration_reader import parse_fields, read_text
from strain_comp.core.engine import Engine
from strain_comp.errors import CalibrationError, InputError
from strain_comp.io.atomic import write_text


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
    calibration = parse_fields(text, path)
    probed: dict[str, str | None] = {}
    for name, cal in calibration.sensors.items():
        key = probe_key(cal)
        if key not in probed:
            probed[key] = probe_calibration(cal)
        where = probed[key]
        if where is not None:
            raise CalibrationError(path, f"sensors.{name}", f"gives a non-finite strain "
                                   f"({where}); its parameters are out of any usable range")
    return calibration


def probe_key(cal: SensorCalibration) -> str:
    """What the load-time probe of ``cal`` depends on: everything but its name and provenance
    (sensors of an array written from one fit are probed once)."""
    return repr({**cal.to_dict(), "provenance": None})


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


def probe_resistance(cal: SensorCalibration) -> tuple[np.ndarray, np.ndarray]:
    """A probe of one sensor: log-spaced from short to open (0.01 x the bottom to 100 x the
    top of the valid range) and back, slowly, fast, and with a long hold."""
    lo, hi = math.log(cal.valid_range.r_lo * 0.011), math.log(cal.valid_range.r_hi * 99.0)
    up = np.exp(np.linspace(lo, hi, 200))
    sweep = np.concatenate([up, up[::-1], up[::4], up[::-4], np.full(50, up[100])])
    t = np.concatenate([np.arange(400) * 0.05, 20.0 + np.arange(100) * 0.01,
                        21.0 + np.arange(50) * 2.0])
    return t, sweep


def probe_calibration(cal: SensorCalibration) -> str | None:
    """Where the engine gives a non-finite strain on this sensor's probe (25 deg C), or None.
    The input zero and span is left out: a probe value it maps below the short level would
    be screened out."""
    probe = SensorCalibration(**{**vars(cal), "input": replace(cal.input, zero_span=None),
                                 "effects": [e for e in cal.effects
                                             if e.get("kind") != "crosstalk"]})
    engine = Engine(Calibration({cal.name: probe}))
    t, r = probe_resistance(cal)
    with np.errstate(all="ignore"):
        out = engine.run(cal.name, t, r, np.full(t.size, 25.0))
    bad = np.flatnonzero(~np.isfinite(out.strain))
    return None if bad.size == 0 else f"R = {r[bad[0]]:.6g} ohm at t = {t[bad[0]]:g} s"


def loadable(cal: SensorCalibration, change: str) -> SensorCalibration:
    """``cal`` after the load-time checks, so a recalibration refuses in the API what the
    command line's write refuses."""
    try:
        check_calibration(Calibration({cal.name: cal}))
    except CalibrationError as err:
        raise InputError(f"recalibration of {cal.name!r}: {change} gives a calibration that "
                         f"would not load ({err.problem}); check the known strains (in "
                         f"{strain_unit_words(cal.strain_unit)}) and resistances") from None
    return cal
