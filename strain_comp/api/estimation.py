"""``estimate`` and ``replay`` from Python: strain and direction of arrays, or of a bag into a
new bag (``strain-comp replay``), by the node's engine (docs/api.md)."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from strain_comp.api._inputs import as_calibration, checked, input_paths, paths_of
from strain_comp.api.inputs import CalibrationLike, PathLike
from strain_comp.base.samples import used_mask
from strain_comp.core.engine import Engine, tracking_off
from strain_comp.core.tare import tare_engine
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording
from strain_comp.offline.replay import replay_bag
from strain_comp.offline.session_start import one_sensor

if TYPE_CHECKING:
    from strain_comp.offline.replay import ReplaySummary


@dataclass(frozen=True)
class Estimate:
    """Strain per sample (in the calibration's unit) and direction (+1 loading, 0 hold, -1
    unloading): the node's ``/NAME/strain`` and ``/NAME/direction``; ``valid``, True
    where the sample was read (False where the node screens it: a NaN or non-positive
    resistance, a short or open circuit); ``std``, the estimate's standard deviation, the
    node's ``/NAME/strain_std`` (NaN where the calibration holds no uncertainty). The strain
    is NaN where not ``valid`` (the node holds its last value there). Unpacks as
    ``strain, direction = sc.estimate(...)``."""

    strain: np.ndarray
    direction: np.ndarray
    valid: np.ndarray
    std: np.ndarray

    def __iter__(self) -> Iterator[np.ndarray]:
        """``strain`` and ``direction``, so the result unpacks as the pair.

        Returns:
            An iterator over the two arrays.

        """
        return iter((self.strain, self.direction))


def estimate(calibration: CalibrationLike, t: npt.ArrayLike, r: npt.ArrayLike, *,
             sensor: str | None = None, temperature: npt.ArrayLike | None = None,
             tare: str = "calibration", out_of_range: str = "extend",
             tracking: str = "off") -> Estimate:
    """Strain and direction of one sensor's samples, by the engine the node and ``replay``
    run: the same numbers.

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        t: Time stamps [s], increasing (NaN: a bad sample).
        r: Resistance [ohm] (or the calibration's input unit), one per time stamp.
        sensor: The calibration's sensor to use (default: its only one).
        temperature: Temperature [degC] per sample, for a calibration with a temperature
            term.
        tare: As the commands' ``--tare``: ``calibration`` or ``auto`` (the run's start).
        out_of_range: As ``--out-of-range``: ``extend``, ``clamp`` or ``extrapolate``.
        tracking: As ``--baseline-tracking``: ``off``, the only value left.

    Returns:
        Strain in the calibration's unit (NaN where the sample is not valid), direction
        (+1, 0, -1), validity and standard deviation per sample (``Estimate``).

    Raises:
        InputError: The sensor is not in the calibration (or not named when it has
            several), the arrays are not 1-D numbers of one length, time stamps that do
            not increase, an argument of the wrong type, an unknown ``tare``
            or a ``tracking`` but ``off``, or the run cannot be tared.
        CalibrationError: The calibration file cannot be read.
        ParameterError: ``out_of_range`` is not a known policy.

    """

    checked(sensor, "text", "sensor")
    for value, what in ((tare, "tare"), (out_of_range, "out_of_range"), (tracking, "tracking")):
        checked(value, "text", what, optional=False)
    tracking_off(tracking)
    cal = as_calibration(calibration)
    name = one_sensor(cal, None if sensor is None else [sensor], "estimate")
    rec = Recording.from_arrays(t, r, name=name, temperature=temperature)
    stamps = rec.t[np.isfinite(rec.t)]
    back = np.flatnonzero(np.diff(stamps) <= 0)
    if back.size:
        raise InputError(f"t: time stamps must increase; {back.size} of {rec.t.size} do "
                         f"not (first: {stamps[back[0] + 1]:.6g} s after {stamps[back[0]]:.6g}"
                         " s); sort the samples by time")
    engine = Engine(cal, out_of_range=out_of_range)
    tare_engine(engine, {name: (rec.t, rec.r)}, tare)
    out = engine.run(name, rec.t, rec.r, rec.temperature)
    valid = used_mask(out.status)
    std = (np.full(valid.size, np.nan) if out.std is None
           else np.asarray(out.std, dtype=np.float64))
    return Estimate(np.where(valid, np.asarray(out.strain, dtype=np.float64), np.nan),
                    np.asarray(out.direction, dtype=np.int8), valid, std)


def replay(calibration: CalibrationLike, bag: PathLike, out: PathLike, *,
           tare: str = "calibration", tracking: str = "off",
           references_every: float | None = None,
           csv: PathLike | None = None, inputs: Sequence[PathLike] = ()) -> ReplaySummary:
    """``strain-comp replay``: a new MCAP bag with every message of ``bag`` and the node's
    outputs (strain, direction, status, stamped strain, /diagnostics) at each input's time.

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        bag: The input bag (MCAP file, rosbag2 directory or ``.db3``).
        out: The output MCAP file, written atomically.
        tare: As ``--tare``.
        tracking: As ``--baseline-tracking``: ``off``, the only value left.
        references_every: As in ``evaluate`` [s]; None fuses no reference.
        csv: Also write the series there as a table.
        inputs: Files the outputs must not overwrite (besides the calibration's path and
            the bag).

    Returns:
        What was replayed: sensors' health, message counts, problems.

    Raises:
        InputError: A path cannot be read, or an option is bad.
        CalibrationError: The calibration file cannot be read.
        BagError: The bag cannot be read or has no resistance topic of a calibrated sensor.
        OutputError: An output would overwrite an input or cannot be written.

    """

    for value, what in ((tare, "tare"), (tracking, "tracking")):
        checked(value, "text", what, optional=False)
    tracking_off(tracking)
    checked(references_every, "seconds", "references_every")
    cal = as_calibration(calibration)
    paths = paths_of(bag)
    if paths is None or len(paths) > 1:
        raise InputError("bag: expected the path of one bag, got "
                         + (f"{len(paths)} paths" if paths else type(bag).__name__))
    return replay_bag(paths[0], cal, out, inputs=input_paths(calibration, list(inputs)),
                      tare=tare,
                      csv=None if csv is None else os.fspath(csv),
                      references_every=references_every)
