"""``recalibrate`` and ``session_start`` from Python: ``strain-comp recalibrate`` through
two points or over a run with a reference, and ``strain-comp start`` (docs/api.md)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import NamedTuple

from strain_comp.api._inputs import as_calibration, checked, one_run
from strain_comp.api.inputs import CalibrationLike, Data
from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError
from strain_comp.offline.session_start import FORMS, recalibrate_recordings, start
from strain_comp.offline.session_start import recalibrate as recalibrate_points


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
    if form not in FORMS:
        raise InputError(f"recalibrate: form {form!r} is not one of {', '.join(FORMS)}")
    cal = as_calibration(calibration)
    if (data is None) == (not pts):
        raise InputError("recalibrate needs either two points (--point R:S) or data with a "
                         "reference strain (--from BAG.mcap)")
    if data is None:
        return Recalibration(*recalibrate_points(cal, points=pts, sensors=sensors, form=form))
    held, source = one_run(data)
    return Recalibration(*recalibrate_recordings(cal, held, form=form, first=first,
                                                 sensors=sensors, tare=tare, span=window,
                                                 source=source))


def session_start(calibration: CalibrationLike, data: Data, *, first: float | None = None,
                  tare: str = "calibration", window: tuple[float, float] | None = None,
                  sensors: Sequence[str] | None = None) -> Recalibration:
    """``strain-comp start``: the start of a session (README) on a recording with a
    reference, a warm-up stretch and back, then the calibration stretch and back. The
    stretch is found from the reference (the second stretch and return, else the first)
    and the correction the calibration's fit chose is made on it: the input zero and span,
    then the output gain and offset on the sensors that take one
    (``strain_comp.offline.session_start.start``).

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        data: A bag or recordings with a reference strain.
        first: Read the recording's first ``first`` seconds as the stretch, as they are
            (``recalibrate --first``); None: found, or ``window``.
        tare: Kept for older callers; the start reads the stretch as recorded (only
            ``"calibration"`` and ``"auto"`` are accepted, both alike).
        window: The stretch, (START, END) seconds after the recording's start
            (``start --window``); None: found.
        sensors: The sensors started (default: every calibrated one with a reference).

    Returns:
        The started calibration and one line per sensor: the stretch used (seconds), the
        correction and the RMSE on the stretch, with the error the calibration expects on
        a new session where it holds one (``fit --model auto``).

    Raises:
        InputError: A recording a start cannot read (no stretch and return, no return to
            rest after its largest strain, shorter than the warm-up), both ``first`` and
            ``window``, or a stretch on which no correction can be made; each says what
            to record instead.
        CalibrationError: The calibration file cannot be read.
        BagError: The bag cannot be read.

    """
    checked(data, "data", "data", optional=False)
    checked(tare, "text", "tare", optional=False)
    first = checked(first, "seconds", "first")
    window = checked(window, "window", "window")
    if tare not in ("calibration", "auto"):
        raise InputError(f"--tare {tare!r}: expected one of calibration, auto")
    if first is not None and window is not None:
        raise InputError("session_start: give first or window, not both")
    cal = as_calibration(calibration)
    held, source = one_run(data)
    started = start(cal, held, window=window, sensors=sensors, source=source, first=first)
    return Recalibration(started.calibration, started.lines())
