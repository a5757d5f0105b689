"""``recalibrate`` and ``session_start`` from Python: ``strain-comp recalibrate`` through
two points or over a run with a reference (docs/api.md)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import NamedTuple

from strain_comp.api.inputs import CalibrationLike, Data, as_calibration, as_recordings, paths_of
from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError
from strain_comp.offline.recalibrate import recalibrate as _recalibrate
from strain_comp.offline.recalibrate import recalibrate_recordings


class Recalibration(NamedTuple):
    """The re-spanned calibration and one line per sensor saying what changed."""

    calibration: Calibration
    readings: list[str]


def recalibrate(calibration: CalibrationLike, data: Data | None = None, *,
                points: Iterable[tuple[float, float]] = (), form: str = "output",
                first: float | None = None, sensors: Sequence[str] | None = None,
                tare: str = "calibration",
                window: tuple[float, float] | None = None) -> Recalibration:
    """``strain-comp recalibrate``: ``form="output"`` fits a gain and offset on the strain,
    ``form="input"`` a zero and span on the resistance; through two known
    ``points`` (resistance [ohm], strain) or over ``data`` with a reference strain (a bag
    or recordings; its first ``first`` seconds, or the ``window`` (START, END) seconds after
    its start: ``strain-comp recalibrate --window``). The input calibration is not
    changed."""

    cal = as_calibration(calibration)
    pts = [(float(r), float(s)) for r, s in points]
    if (data is None) == (not pts):
        raise InputError("recalibrate needs either two points (R, S) or data with a "
                         "reference strain")
    paths = paths_of(data)
    if data is None or paths is not None:
        bag = None if paths is None else paths[0]
        new, lines = _recalibrate(cal, points=pts, bag=bag, sensors=sensors, tare=tare,
                                  form=form, first=first, span=window)
    else:
        new, lines = recalibrate_recordings(cal, as_recordings(data), form=form, first=first,
                                            sensors=sensors, tare=tare, source="recordings",
                                            span=window)
    return Recalibration(new, lines)


def session_start(calibration: CalibrationLike, data: Data, *, first: float = 30.0,
                  tare: str = "calibration") -> Recalibration:
    """The start of a session (README): on the first ``first`` seconds of a run with a
    reference (a known stretch and back), first the input zero and span, then the output
    gain and offset."""
    spanned = recalibrate(calibration, data, form="input", first=first, tare=tare)
    mapped = recalibrate(spanned.calibration, data, form="output", first=first, tare=tare)
    return Recalibration(mapped.calibration, spanned.readings + mapped.readings)
