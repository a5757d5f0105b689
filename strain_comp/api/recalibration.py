"""``recalibrate`` and ``session_start`` from Python: ``strain-comp recalibrate`` through
two points or over a run with a reference (docs/api.md)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import NamedTuple

from strain_comp.api.inputs import (
    CalibrationLike,
    Data,
    as_calibration,
    as_recordings,
    checked,
    paths_of,
    read_recordings,
)
from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError
from strain_comp.offline.recalibrate import forms_of, recalibrate_recordings
from strain_comp.offline.recalibrate import recalibrate as _recalibrate


class Recalibration(NamedTuple):
    """The re-spanned calibration and one line per sensor saying what changed."""

    calibration: Calibration
    readings: list[str]


def recalibrate(calibration: CalibrationLike, data: Data | None = None, *,
                points: Iterable[tuple[float, float]] = (), form: str = "output",
                first: float | None = None, sensors: Sequence[str] | None = None,
                tare: str = "calibration",
                window: tuple[float, float] | None = None) -> Recalibration:
    """``strain-comp recalibrate``: a new calibration re-spanned through two points or over
    a run with a reference; the input calibration is not changed.

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        data: A bag or recordings with a reference strain; None with ``points``.
        points: Two known points (resistance [ohm], strain in the calibration's unit).
        form: ``"output"`` fits a gain and offset on the strain, ``"input"`` a zero and
            span on the resistance.
        first: Use the run's first that many seconds [s].
        sensors: Which sensors to recalibrate (default: every calibrated one in the data).
        tare: As ``--tare``.
        window: Use the (START, END) seconds after the run's start
            (``strain-comp recalibrate --window``).

    Returns:
        The new calibration and one line per sensor saying what changed.

    Raises:
        InputError: Neither or both of ``points`` and ``data``, an unknown ``form``, points
            the calibration cannot pass through, or a run too short or without a reference.
        CalibrationError: The calibration file cannot be read.
        BagError: The bag cannot be read.

    """

    checked(data, "data", "data")
    checked(form, "text", "form", optional=False)
    checked(tare, "text", "tare", optional=False)
    pts = checked(points, "points", "points")
    first = checked(first, "seconds", "first")
    sensors = checked(sensors, "names", "sensors")
    window = checked(window, "window", "window")
    cal = as_calibration(calibration)
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
                  tare: str = "calibration",
                  window: tuple[float, float] | None = None) -> Recalibration:
    """The start of a session (README): on a run with a reference, first the input zero
    and span, then the output gain and offset (not on a sensor with a stretch
    line: ``recalibrate.session_forms``), over the calibration stretch ``window``
    (after a warm-up stretch), or over the run's first ``first`` seconds.

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        data: A bag or recordings with a reference strain.
        first: How much of the run's start to use [s] when ``window`` is None.
        tare: As ``--tare``.
        window: The calibration stretch, (START, END) seconds after the run's start
            (``recalibrate --window``).

    Returns:
        The calibration with both and the lines of each step.

    Raises:
        InputError: The stretch read has no usable load and unload, or no reference.
        CalibrationError: The calibration file cannot be read.
        BagError: The bag cannot be read.

    """
    checked(data, "data", "data", optional=False)
    checked(tare, "text", "tare", optional=False)
    first = checked(first, "seconds", "first", optional=False)
    window = checked(window, "window", "window")
    cal = as_calibration(calibration)
    paths = paths_of(data)
    held = as_recordings(data) if paths is None else read_recordings(paths[0])
    source = "recordings" if paths is None else paths[0]
    head = first if window is None else None
    cal, lines = recalibrate_recordings(cal, held, form="input", first=head, tare=tare,
                                        source=source, span=window)
    takes_output = forms_of(cal, held).get("output")
    if takes_output:
        cal, more = recalibrate_recordings(cal, held, form="output", first=head, tare=tare,
                                           sensors=takes_output, source=source, span=window)
        lines += more
    return Recalibration(cal, lines)
