"""What the API's functions take (docs/api.md): bag paths, recordings, calibrations or
their paths, each checked into the one form the commands use."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration as _load_calibration
from strain_comp.core.calibration_file import save_calibration as _save_calibration
from strain_comp.errors import InputError
from strain_comp.io.inputs import existing
from strain_comp.io.recording import Recording, load_recordings

PathLike = str | Path
Data = PathLike | Recording | Sequence[Recording] | Mapping[str, Recording]
"""What the functions take as data: a bag's path, a recording, several, or a mapping of
sensor name to recording (``read_recordings``)."""
CalibrationLike = Calibration | PathLike
"""A ``Calibration`` or the path of a calibration file."""


def is_path(data: object) -> bool:
    """Is ``data`` one path (str or ``os.PathLike``)?"""
    return isinstance(data, (str, os.PathLike))


def paths_of(data: object) -> list[str] | None:
    """``data`` as bag paths when it is one path or a non-empty list of them, else None."""
    if isinstance(data, (str, os.PathLike)):
        return [existing(data, "bag", directory=True)]
    if isinstance(data, (list, tuple)) and data and all(is_path(p) for p in data):
        return [existing(p, "bag", directory=True) for p in data]
    return None


def load_calibration(path: PathLike) -> Calibration:
    """Read and check a calibration file (``CalibrationError`` naming the file and field)."""
    return _load_calibration(existing(path, "calibration file"))


def save_calibration(calibration: Calibration, path: PathLike) -> None:
    """Write ``calibration`` to ``path`` atomically, after the checks every reader applies."""
    _save_calibration(calibration, path)


def as_calibration(calibration: CalibrationLike) -> Calibration:
    """``calibration`` itself, or the calibration file at that path, read and checked."""
    if isinstance(calibration, Calibration):
        return calibration
    if isinstance(calibration, (str, os.PathLike)):
        return _load_calibration(existing(calibration, "calibration file"))
    raise InputError(f"expected a Calibration or the path of a calibration file, got "
                     f"{type(calibration).__name__}")


def read_recordings(path: PathLike, *, report: Callable[[str], None] | None = None
                    ) -> dict[str, Recording]:
    """Every sensor of a bag (MCAP file, rosbag2 directory or ``.db3``) as a Recording,
    the reference and temperature put on the resistance's time stamps. What the reader
    skipped (damage, unknown types) goes to ``report``, one line each."""

    recordings, problems = load_recordings(existing(path, "bag", directory=True))
    for line in problems:
        if report is not None:
            report(line)
    return recordings


def as_recordings(data: object) -> dict[str, Recording]:
    """Sensor name -> recording, for one bag's worth of recordings."""
    if isinstance(data, Recording):
        return {data.name: data}
    if isinstance(data, Mapping):
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
                     f"{type(data).__name__}")
