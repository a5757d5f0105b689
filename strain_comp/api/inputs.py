"""What the API's functions take (docs/api.md): bag paths, recordings, calibrations or their
paths (checked in ``api._inputs``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration as _load_calibration
from strain_comp.core.calibration_file import save_calibration as _save_calibration
from strain_comp.io.inputs import existing
from strain_comp.io.recording import Recording, load_recordings

PathLike = str | Path
Data = PathLike | Recording | Sequence[Recording] | Mapping[str, Recording]
"""What the functions take as data: a bag's path, a recording, several, or a mapping of
sensor name to recording (``read_recordings``)."""
CalibrationLike = Calibration | PathLike
"""A ``Calibration`` or the path of a calibration file."""


def load_calibration(path: PathLike) -> Calibration:
    """Read and check a calibration file.

    Args:
        path: The calibration file (YAML).

    Returns:
        The calibration, every sensor's parameters checked.

    Raises:
        InputError: The path is missing, unreadable or not a regular file.
        CalibrationError: The file is malformed or a field out of range, naming the file
            and the field.

    """
    return _load_calibration(existing(path, "calibration file"))


def save_calibration(calibration: Calibration, path: PathLike) -> None:
    """Write ``calibration`` to ``path`` atomically, after the checks every reader applies.

    Args:
        calibration: The calibration to write.
        path: The output file; nothing is left half written.

    Raises:
        CalibrationError: A sensor fails the reader's checks (nothing is written).
        OutputError: The path cannot be written or is not a regular file.

    """
    _save_calibration(calibration, path)


def read_recordings(path: PathLike, *, report: Callable[[str], None] | None = None
                    ) -> dict[str, Recording]:
    """Every sensor of a bag as a Recording, the reference and temperature put on the
    resistance's time stamps.

    Args:
        path: An MCAP file, a rosbag2 directory or a ``.db3`` file.
        report: Where what the reader skipped (damage, unknown types) goes, one line each;
            None drops it.

    Returns:
        Sensor name -> recording.

    Raises:
        InputError: The path is missing or unreadable.
        BagError: The bag cannot be read.

    """
    recordings, problems = load_recordings(existing(path, "bag", directory=True))
    if report is not None:
        for line in problems:
            report(line)
    return recordings
