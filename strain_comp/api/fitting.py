"""``fit`` from Python: ``strain-comp fit`` on bags, recordings or arrays (docs/api.md)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from strain_comp.api._inputs import as_recordings, checked, paths_of
from strain_comp.api.inputs import Data, PathLike
from strain_comp.core.calibration import Calibration, SensorCalibration, unit_problem
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import (
    auto_fitter,
    check_auto_options,
    fit_bags,
    fit_runs,
    parse_candidates,
    parse_groups,
)
from strain_comp.offline.options import check_fit_options, model_options
from strain_comp.progress import bar, grid_progress


def fit(data: Data | Sequence[PathLike], model: str = "cubic", *,
        sensors: Sequence[str] | None = None, strain_unit: str = "%",
        report: Callable[[str], None] | None = None, progress_bar: bool = False,
        pool: str = "spanned", input_unit: str = "ohm",
        candidates: Sequence[str] | str | None = None,
        groups: Sequence[Any] | str | None = None, jobs: int = 1,
        **options: Any) -> Calibration:
    """Fit ``model`` to recordings with a reference strain: one calibration, one entry per
    sensor (``strain-comp fit``).

    Args:
        data: Bag paths (one or several runs), a Recording, or a list of Recordings (each
            a run; several runs of one sensor are fitted together).
        model: apl, pl, mpi, cubic, sinh_pl, rational, spike_decay or creep_pi; or
            ``"auto"``: each of ``candidates`` fitted on all runs but one (or one group),
            started on the run left out (``strain-comp start``) and scored over it; the
            lowest median wins, a simpler model within 2 % of it before it
            (``strain_comp.offline.fit``); the table and the error to expect are
            stored in the provenance (``model_choice``, ``expected_error``).
        sensors: Which sensors to fit (default: every one with a reference).
        strain_unit: The reference strain's unit (``%``, ``mm``), stored in the calibration.
        report: Where notes go (skipped bag damage, a sensor left out, a resistance that
            looks like a ratio R/R0); None drops them, but for the last,
            given as a ``UserWarning``.
        progress_bar: A bar on stderr over an APL-family fit's grid (``strain_comp.progress``).
        pool: How several runs of a sensor are pooled: ``"spanned"`` (each run's input zero
            and span put onto the run of median sensitivity, with the session start chosen
            by leaving out each run), ``"joint"`` or ``"stretch"`` (that session start) or
            ``"raw"`` (``strain-comp fit --pool``).
        input_unit: The unit of the recordings' resistance: ohm, or another for an input
            not in ohm (``R/R0``), stored in ``InputSettings.unit`` so the dead zone is read
            in it per second (``strain-comp fit --input-unit``).
        candidates: With ``"auto"``: the models tried (a list or ``"cubic,apl"``; default
            cubic, mpi, apl, creep_pi).
        groups: With ``"auto"``: one label per run (``[1, 1, 1, 2, 2]`` or ``"1,1,1,2,2"``):
            runs of a session or mounting left out together; default each run alone.
        jobs: With ``"auto"``: worker processes for the runs left out.
        **options: The model's fit options, as ``strain-comp fit --option K=V`` takes them
            (``strain-comp fit --help`` lists them); with ``"auto"`` each candidate takes
            its own.

    Returns:
        The calibration, one ``SensorCalibration`` per sensor fitted.

    Raises:
        InputError: ``data`` or an argument of the wrong type (``api._inputs.checked``), an
            unknown model or option, a bad unit, a sensor not in the data or
            without a reference, or a bag path that cannot be read.
        BagError: A bag cannot be read.
        FitError: The model cannot be fitted to a sensor's data (with ``"auto"``: no
            candidate can).

    """

    checked(data, "data", "data", optional=False)
    for value, what in ((model, "model"), (strain_unit, "strain_unit"), (pool, "pool"),
                        (input_unit, "input_unit")):
        checked(value, "text", what, optional=False)
    sensors = checked(sensors, "names", "sensors")
    if model != "auto":
        check_fit_options(model, options)
    for unit, what, example in ((strain_unit, "strain unit", "% or mm"),
                                (input_unit, "input unit", "ohm or R/R0")):
        if (problem := unit_problem(unit, example)) is not None:
            raise InputError(f"{what}: {problem}")
    paths = paths_of(data)
    runs = paths if paths is not None else (
        [data] if isinstance(data, (Recording, Mapping)) else list(data))  # type: ignore[arg-type]
    auto = None
    if model == "auto":
        chosen = parse_candidates(candidates)
        check_auto_options(chosen, options)
        auto = auto_fitter(chosen, parse_groups(groups, len(runs)), jobs)

    grid = auto is None and "progress" in model_options(model) and "progress" not in options
    with bar(None, f"{model} fit", enabled=grid and progress_bar) as shown:
        if grid:  # the grid's own lines give way to the bar (or to silence)
            options = {**options, "progress": grid_progress(shown) if progress_bar else False}
        calibration = (fit_bags(paths, model, sensors, options, report=report, pool=pool,
                                fitter=auto) if paths is not None else
                       fit_runs([(None, as_recordings(run)) for run in runs], model, sensors,
                                options, where="the recordings", report=report, pool=pool,
                                fitter=auto))
    for cal in calibration.sensors.values():
        cal.strain_unit = strain_unit
        if "expected_error" in cal.provenance:
            cal.provenance["expected_error"]["unit"] = strain_unit
        if input_unit != "ohm":
            if cal.input.kind != "resistance":
                raise InputError(f"input unit {input_unit!r}: {cal.name}'s input is a "
                                 f"{cal.input.kind}, whose resistance is in ohm")
            cal.input = replace(cal.input, unit=input_unit)
        if grid or auto is not None:  # how the fit was shown is no fit option
            cal.provenance.get("options", {}).pop("progress", None)
        line = _ratio_note(cal)
        if line is not None and report is not None:
            report(line)
        elif line is not None:
            warnings.warn(line, UserWarning, stacklevel=2)
    return calibration


RATIO_TOP = 5.0
"""A resistance in ohm whose calibrated range lies at or below this [ohm] looks like R/R0."""


def _ratio_note(cal: SensorCalibration) -> str | None:
    """One line when a sensor's resistance, read as ohm, looks like a ratio R/R0."""
    # a soft sensor's rest is tens of ohm to megaohm; a ratio is about 1 at rest
    vr = cal.valid_range
    if cal.input.kind != "resistance" or cal.input.unit != "ohm" or vr.r_hi > RATIO_TOP:
        return None
    return (f"sensor {cal.name!r}: its resistance spans {vr.r_lo:.3g} to {vr.r_hi:.3g}, "
            "read as ohm; if it is a ratio (R/R0), fit with --input-unit R/R0 (Python: "
            "input_unit='R/R0') so that the dead zone and the plots say so")
