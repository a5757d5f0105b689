"""``estimate`` and ``replay`` from Python: strain and direction of arrays, or of a bag into a
new bag (``strain-comp replay``), by the node's engine (docs/api.md)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

from strain_comp.api.inputs import CalibrationLike, PathLike, as_calibration, paths_of
from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tare import tare_engine
from strain_comp.core.tracking import DEFAULT_TRACKING, tracker_for
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording
from strain_comp.offline.replay import replay_bag

if TYPE_CHECKING:
    from strain_comp.offline.replay import ReplaySummary


class Estimate(NamedTuple):
    """Strain per sample (in the calibration's unit; held over bad samples) and direction
    (+1 loading, 0 hold, -1 unloading): the node's ``/NAME/strain`` and ``/NAME/direction``."""

    strain: np.ndarray
    direction: np.ndarray


def estimate(calibration: CalibrationLike, t: npt.ArrayLike, r: npt.ArrayLike, *,
             sensor: str | None = None, temperature: npt.ArrayLike | None = None,
             tare: str = "calibration", out_of_range: str = "extend",
             tracking: str = DEFAULT_TRACKING) -> Estimate:
    """Strain and direction for time ``t`` [s] and resistance ``r`` [ohm] through the
    calibration's sensor ``sensor`` (default: its only one), by the engine the node and
    ``replay`` run: the same numbers. ``tare``, ``out_of_range`` and ``tracking`` are the
    commands' ``--tare``, ``--out-of-range`` and ``--baseline-tracking``."""

    cal = as_calibration(calibration)
    name = _sensor_name(cal, sensor)
    rec = Recording.from_arrays(t, r, name=name, temperature=temperature)
    engine = Engine(cal, out_of_range=out_of_range)
    tare_engine(engine, {name: (rec.t, rec.r)}, tare)
    runner = tracker_for(engine, tracking) or engine
    out = runner.run(name, rec.t, rec.r, rec.temperature)
    return Estimate(np.asarray(out.strain, dtype=np.float64),
                    np.asarray(out.direction, dtype=np.int8))


def _sensor_name(calibration: Calibration, sensor: str | None) -> str:
    if sensor is None:
        if len(calibration.sensors) != 1:
            raise InputError("name the sensor: the calibration has "
                             f"{', '.join(calibration.sensors)}")
        return next(iter(calibration.sensors))
    if sensor not in calibration.sensors:
        raise InputError(f"sensor {sensor!r} is not in the calibration "
                         f"({', '.join(calibration.sensors)})")
    return sensor


def replay(calibration: CalibrationLike, bag: PathLike, out: PathLike, *,
           tare: str = "calibration", tracking: str = DEFAULT_TRACKING,
           references_every: float | None = None,
           csv: PathLike | None = None, inputs: Sequence[PathLike] = ()) -> ReplaySummary:
    """``strain-comp replay``: a new MCAP bag at ``out`` with every message of ``bag`` and
    the node's outputs (strain, direction, status, stamped strain, /diagnostics) at each
    input's time; ``csv``: also the series as a table. ``inputs``: files the outputs must
    not overwrite. ``references_every``: as in ``evaluate``. Returns what was replayed
    (sensors' health, messages, problems)."""

    cal = as_calibration(calibration)
    paths = paths_of(bag)
    assert paths is not None
    return replay_bag(paths[0], cal, out, inputs=list(inputs), tare=tare,
                      csv=None if csv is None else os.fspath(csv), tracking=tracking,
                      references_every=references_every)
