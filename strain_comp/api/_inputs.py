"""The checks of what the API's functions are given, each into the one form the commands
use (the user's names are in ``api.inputs``)."""

from __future__ import annotations

import math
import os
import reprlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal, TypeGuard

from strain_comp.api.inputs import CalibrationLike, load_calibration, read_recordings
from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError
from strain_comp.io.inputs import existing
from strain_comp.io.recording import Recording

Kind = Literal["data", "text", "names", "count", "seconds", "window", "points"]
"""What ``checked`` expects (``_WANTED``: in words); ``data``'s items are checked where read."""
_WANTED = {"data": "a bag path, a Recording, a list or a dict of Recordings (arrays: "
                   "sc.Recording.from_arrays(t, r, s))", "text": "text",
           "names": "a name or a list of names",
           "count": "a whole number >= 0", "seconds": "a finite number of seconds > 0",
           "window": "(START, END) seconds after the run's start, 0 <= START < END",
           "points": "(resistance [ohm], strain) pairs of numbers"}


def _items(value: object) -> list[Any] | None:
    """The items of a list, tuple or other iterable that is not text nor a mapping."""
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
        return None
    return list(value)


def _number(value: object) -> float | None:
    """``value`` as a float when it is a real number (not a bool nor a str), else None."""
    if isinstance(value, (bool, str, bytes)) or not hasattr(value, "__float__"):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _pair(value: object) -> tuple[float, float] | None:
    """``value`` as two floats when it holds exactly two real numbers, else None."""
    numbers = [_number(v) for v in _items(value) or []]
    if len(numbers) != 2 or numbers[0] is None or numbers[1] is None:
        return None
    return numbers[0], numbers[1]


def checked(value: Any, kind: Kind, what: str, *, optional: bool = True) -> Any:
    """An argument as the ``kind`` it must be (None passes when ``optional``), else InputError."""
    if value is None and optional:
        return None
    if kind == "data":
        if not (is_path(value) or isinstance(value, (Recording, Mapping, list, tuple))):
            raise InputError(f"{what}: expected {_WANTED[kind]}, got {type(value).__name__}")
        return value
    bad = InputError(f"{what}={reprlib.repr(value)}: expected {_WANTED[kind]}, got "
                     f"{type(value).__name__}")
    if kind == "text":
        if not isinstance(value, str):
            raise bad
        return value
    if kind == "names":
        names = [value] if isinstance(value, str) else value
        if not (isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names)):
            raise bad
        return list(names)
    if kind == "count":
        number = _number(value)
        if number is None or not (number.is_integer() and number >= 0):
            raise bad
        return int(number)
    if kind == "seconds":
        number = _number(value)
        if number is None or not (math.isfinite(number) and number > 0):
            raise bad
        return number
    if kind == "window":
        pair = _pair(value)
        if pair is None or not 0.0 <= pair[0] < pair[1] < math.inf:
            raise bad
        return pair
    rows = _items(value)
    if rows is None:
        raise bad
    points = []
    for row in rows:
        point = _pair(row)
        if point is None:
            raise InputError(f"{what}: point {reprlib.repr(row)}: expected (resistance "
                             "[ohm], strain), two numbers")
        points.append(point)
    return points


def is_path(data: object) -> TypeGuard[str | os.PathLike[str]]:
    return isinstance(data, (str, os.PathLike))


def paths_of(data: object) -> list[str] | None:
    """``data`` as existing bag paths when it is one path or a non-empty list of them (or None)."""
    if is_path(data):
        return [existing(data, "bag", directory=True)]
    if isinstance(data, (list, tuple)) and data and all(is_path(p) for p in data):
        return [existing(p, "bag", directory=True) for p in data]
    return None


def input_paths(*given: object) -> list[str]:
    """The paths among ``given`` (paths or lists of them): files no output may overwrite."""
    out: list[str] = []
    for value in given:
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(item, (str, os.PathLike)):
                out.append(os.fspath(item))
    return out


def as_calibration(calibration: CalibrationLike) -> Calibration:
    """``calibration`` itself, or the calibration file at that path, read and checked."""
    if isinstance(calibration, Calibration):
        return calibration
    if is_path(calibration):
        return load_calibration(os.fspath(calibration))
    raise InputError(f"expected a Calibration or the path of a calibration file, got "
                     f"{type(calibration).__name__}")


def as_recordings(data: object) -> dict[str, Recording]:
    """Sensor name -> recording, for one bag's worth of recordings (one, a list or a dict)."""
    if isinstance(data, Recording):
        return {data.name: data}
    if isinstance(data, Mapping):
        for name, rec in data.items():
            if not isinstance(rec, Recording):
                raise InputError(f"sensor {name!r}: expected a Recording, got "
                                 f"{type(rec).__name__} (make one with "
                                 "sc.Recording.from_arrays(t, r, s))")
        return dict(data)
    if isinstance(data, Sequence) and all(isinstance(r, Recording) for r in data):
        out: dict[str, Recording] = {}
        for rec in data:
            if rec.name in out:
                raise InputError(f"two recordings of sensor {rec.name!r} in one run (pass "
                                 "several runs to fit as a list of lists or of paths)")
            out[rec.name] = rec
        return out
    raise InputError(f"expected a bag path, a Recording, a list or a dict of Recordings, got "
                     f"{type(data).__name__} (arrays: sc.Recording.from_arrays(t, r, s))")


def one_run(data: object) -> tuple[dict[str, Recording], str]:
    """One run's recordings by sensor name, read from a bag path or as given, and their source."""
    paths = paths_of(data)
    if paths is not None and len(paths) > 1:
        raise InputError(f"expected one run (a bag path or its recordings), got {len(paths)} "
                         "bag paths")
    return (as_recordings(data), "the recordings") if paths is None else \
        (read_recordings(paths[0]), paths[0])
