"""strain_comp from Python: fit, estimate, evaluate, recalibrate and diagnose on arrays,
tables or bags (docs/api.md walks through it).

The functions here are what the ``strain-comp`` commands call, so a notebook gets the
command line's numbers: ``estimate`` runs ``strain_comp.core.engine.Engine`` (the node's and
``replay``'s engine), ``evaluate`` the ``evaluate`` command's streamed scoring, ``fit`` its
fits. Input is numpy arrays (``Recording.from_arrays``), a table (``Recording.from_frame``:
a pandas DataFrame or a mapping of columns), or bags (paths: MCAP, rosbag2 directories,
``.db3``). pandas is optional: ``to_frame`` methods need it, nothing else does.

Errors: every bad input raises a ``StrainCompError`` (``strain_comp.errors``) whose message is
the line ``strain-comp`` prints after ``strain-comp: error:``. Nothing here writes a file
unless a path to write is given (``save_calibration``, ``csv=``, ``out=``, ``plots=``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import numpy.typing as npt

from strain_comp.core.calibration import Calibration, SensorCalibration, unit_ok
from strain_comp.core.calibration_file import load_calibration as _load_calibration
from strain_comp.core.calibration_file import save_calibration as _save_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tare import tare_engine
from strain_comp.core.tracking import DEFAULT_TRACKING, tracker_for
from strain_comp.diagnosis.command import diagnose_bag
from strain_comp.diagnosis.conditions import diagnose_conditions
from strain_comp.diagnosis.report import write_plots
from strain_comp.diagnosis.report_page import diagnosis_page
from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.inputs import existing
from strain_comp.io.recording import Recording, load_recordings
from strain_comp.offline.evaluate import PLOT_POINTS, evaluate_bag, evaluate_recordings
from strain_comp.offline.evaluate import in_run_bound as _in_run_bound
from strain_comp.offline.evaluation import format_notes, format_table
from strain_comp.offline.fit import fit_bags, fit_sensor
from strain_comp.offline.options import check_fit_options, model_options
from strain_comp.offline.recalibrate import recalibrate as _recalibrate
from strain_comp.offline.recalibrate import recalibrate_recordings
from strain_comp.offline.replay import replay_bag
from strain_comp.offline.report_page import BagSection, evaluation_figures, evaluation_page
from strain_comp.offline.series import series_csv
from strain_comp.progress import bar, counter, grid_progress

if TYPE_CHECKING:
    from strain_comp.diagnosis.report import DiagnoseResult
    from strain_comp.offline.evaluation import EvaluationResult
    from strain_comp.offline.replay import ReplaySummary

__all__ = ["Calibration", "Diagnosis", "Estimate", "Evaluation", "Recalibration", "Recording",
           "StrainCompError", "diagnose", "estimate", "evaluate", "fit", "load_calibration",
           "read_recordings", "recalibrate", "replay", "save_calibration", "session_start"]

PathLike = str | Path
Data = PathLike | Recording | Sequence[Recording] | Mapping[str, Recording]
"""What the functions take as data: a bag's path, a recording, several, or a mapping of
sensor name to recording (``read_recordings``)."""
CalibrationLike = Calibration | PathLike
"""A ``Calibration`` or the path of a calibration file."""


def _pandas() -> Any:
    """pandas, or InputError saying it is optional and missing."""
    try:
        import pandas
    except ImportError:
        raise InputError("to_frame needs pandas (optional: pip install pandas); the arrays "
                         "and dicts work without it") from None
    return pandas


def _is_path(data: object) -> bool:
    return isinstance(data, (str, os.PathLike))


def _paths(data: object) -> list[str] | None:
    """``data`` as bag paths when it is one path or a non-empty list of them, else None."""
    if isinstance(data, (str, os.PathLike)):
        return [existing(data, "bag", directory=True)]
    if isinstance(data, (list, tuple)) and data and all(_is_path(p) for p in data):
        return [existing(p, "bag", directory=True) for p in data]
    return None


def _run(data: object) -> dict[str, Recording]:
    """One run's recordings by sensor name: read from a bag path, or as given."""
    paths = _paths(data)
    if paths is not None and len(paths) == 1:
        return read_recordings(paths[0])
    return _recordings(data)


def load_calibration(path: PathLike) -> Calibration:
    """Read and check a calibration file (``CalibrationError`` naming the file and field)."""
    return _load_calibration(existing(path, "calibration file"))


def save_calibration(calibration: Calibration, path: PathLike) -> None:
    """Write ``calibration`` to ``path`` atomically, after the checks every reader applies."""
    _save_calibration(calibration, path)


def _calibration(calibration: CalibrationLike) -> Calibration:
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


def _recordings(data: object) -> dict[str, Recording]:
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


# ----------------------------------------------------------------------------- fit


def fit(data: Data | Sequence[PathLike], model: str = "cubic", *,
        sensors: Sequence[str] | None = None, strain_unit: str = "%",
        report: Callable[[str], None] | None = None, progress_bar: bool = False,
        pool: str = "spanned", **options: Any) -> Calibration:
    """Fit ``model`` (apl, pl, mpi, cubic, sinh_pl, rational, spike_decay) to recordings
    with a reference strain: one calibration, one entry per sensor.

    ``data``: bag paths (one or several runs), a Recording, or a list of Recordings (each
    a run; several runs of one sensor are fitted together). ``sensors``: which to fit
    (default: every one with a reference). ``options``: the model's fit options, as
    ``strain-comp fit --option K=V`` takes them (``strain-comp fit --help`` lists them).
    ``report``: where notes go (skipped bag damage, a sensor left out). ``progress_bar``: a
    bar on stderr over an APL-family fit's grid (``strain_comp.progress``). ``pool``: how
    several runs of a sensor are pooled, ``"spanned"`` (each run's input zero and span put
    onto the run of median sensitivity) or ``"raw"`` (``strain-comp fit --pool``).
    """

    check_fit_options(model, options)
    if not unit_ok(strain_unit):
        raise InputError(f"strain unit {strain_unit!r}: expected a unit such as % or mm "
                         "(1-16 letters, digits, %, / or .)")

    grid = "progress" in model_options(model) and "progress" not in options
    with bar(None, f"{model} fit", enabled=grid and progress_bar) as shown:
        if grid:  # the grid's own lines give way to the bar (or to silence)
            options = {**options, "progress": grid_progress(shown) if progress_bar else False}
        calibration = _fit(data, model, sensors, report, options, pool)
    for cal in calibration.sensors.values():
        cal.strain_unit = strain_unit
        if grid:  # how the fit was shown is no fit option
            cal.provenance.get("options", {}).pop("progress", None)
    return calibration


def _fit(data: Data | Sequence[PathLike], model: str, sensors: Sequence[str] | None,
         report: Callable[[str], None] | None, options: Mapping[str, Any],
         pool: str = "spanned") -> Calibration:

    paths = _paths(data)
    if paths is not None:
        return fit_bags(paths, model, sensors, options, report=report, pool=pool)
    runs = [data] if isinstance(data, (Recording, Mapping)) else list(data)  # type: ignore[arg-type]
    by_sensor: dict[str, list[Recording]] = {}
    for run in runs:
        for name, rec in _recordings(run).items():
            by_sensor.setdefault(name, []).append(rec)
    names = list(sensors) if sensors and "all" not in sensors else \
        [n for n, recs in by_sensor.items() if any(r.s is not None for r in recs)]
    if not names:
        raise InputError("no recording with a reference strain to fit to")
    fitted: dict[str, SensorCalibration] = {}
    for name in names:
        if name not in by_sensor:
            raise InputError(f"sensor {name!r} is not in the recordings "
                             f"(sensors found: {', '.join(by_sensor)})")
        fitted[name] = fit_sensor(by_sensor[name], model, name=name,
                                  bags=[f"(arrays: {name})"], options=options, pool=pool)
    return Calibration(fitted)


# ------------------------------------------------------------------------ estimate


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

    cal = _calibration(calibration)
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


# ------------------------------------------------------------------------ evaluate


@dataclass
class Evaluation:
    """A calibration scored on one run: per sensor n, RMSE, MAE, max |error| and R^2 in
    the calibration's strain unit (``evaluate``'s table and JSON)."""

    result: EvaluationResult
    """The full result: per sensor its statistics and (decimated) arrays for plots."""
    problems: list[str] = field(default_factory=list)
    """What the bag reader skipped."""
    calibration: Calibration | None = None
    """The calibration scored."""
    source: str = "recordings"
    """The bag's path, or ``recordings``."""
    tare: str = "calibration"

    @property
    def notes(self) -> list[str]:
        """What the table does not show: bad and out-of-range samples, tares, unscored."""

        return format_notes(self.result)

    @property
    def scores(self) -> dict[str, dict[str, Any]]:
        """Sensor -> {model, n, rmse, mae, max_abs, r2, unit}."""
        return {name: {"model": ev.model, "n": ev.stats.n, "rmse": ev.stats.rmse,
                       "mae": ev.stats.mae, "max_abs": ev.stats.max_abs, "r2": ev.stats.r2,
                       "unit": ev.unit}
                for name, ev in self.result.sensors.items()}

    def table(self) -> str:
        """The table ``strain-comp evaluate`` prints."""

        return format_table(self.result)

    def to_json(self) -> dict[str, Any]:
        """What ``evaluate --json`` writes (docs/design.md)."""
        return self.result.to_json()

    def to_frame(self) -> Any:
        """``scores`` as a pandas DataFrame, one row per sensor (needs pandas)."""
        return _pandas().DataFrame.from_dict(self.scores, orient="index")

    def to_html(self, calibration_path: str = "") -> str:
        """The ``evaluate --report`` page (``strain_comp.offline.report_page``): the table,
        the plots (of the samples kept: ``plot_points``) and the calibration's provenance;
        ``calibration_path`` names the calibration on the page."""

        cal = self.calibration or Calibration({})
        figures = evaluation_figures(self.result, cal, bag=self.source,
                                     calibration_path=calibration_path, tare=self.tare)
        return evaluation_page([BagSection(self.source, self.result,
                                           problems=self.problems, figures=figures)],
                               cal, calibration_path or "(in memory)", tare=self.tare)


def evaluate(calibration: CalibrationLike, data: Data, *, tare: str = "calibration",
             out_of_range: str = "extend", tracking: str = DEFAULT_TRACKING,
             in_run_bound: bool = False, plot_points: int = 0,
             references_every: float | None = None,
             csv: PathLike | None = None, inputs: Sequence[PathLike] = ()) -> Evaluation:
    """Score ``calibration`` on one run with a reference strain: a bag (streamed, as
    ``strain-comp evaluate`` reads it), a Recording or a dict of them.

    ``in_run_bound``: also the RMSE of the same model fitted on this run. ``plot_points``:
    keep that many evenly spaced samples per sensor in ``result`` for plots and
    ``to_html`` (a bag; recordings keep all). ``csv``: also write every sample there
    (``evaluate --csv``; ``inputs``: files it must not overwrite). ``references_every``:
    the run's own reference every that many seconds fused into each sensor's output gain and
    offset (``evaluate --references-every``; docs/fusion.md). Raises InputError when no
    calibrated sensor can be scored.
    """

    cal = _calibration(calibration)
    paths = _paths(data)
    if paths is not None and len(paths) == 1:
        with series_csv(None if csv is None else os.fspath(csv),
                        inputs=[*paths, *(os.fspath(i) for i in inputs)]) as table:
            result, problems = evaluate_bag(paths[0], cal, tare=tare, plot_points=plot_points,
                                            series=table, out_of_range=out_of_range,
                                            tracking=tracking,
                                            references_every=references_every)
        if in_run_bound:
            _in_run_bound(result, read_recordings(paths[0]), cal)
        return Evaluation(result, problems, cal, paths[0], tare)
    if paths is not None:
        raise InputError("evaluate scores one run: call it once per bag (the pooled "
                         "figures of several: strain-comp evaluate BAG1 BAG2 ...)")
    if csv is not None:
        raise InputError("evaluate: csv= is for a bag; with recordings, estimate gives the "
                         "series as arrays")
    recordings = _recordings(data)
    result = evaluate_recordings(recordings, cal, tare=tare, out_of_range=out_of_range,
                                 tracking=tracking, references_every=references_every)
    if in_run_bound:
        _in_run_bound(result, recordings, cal)
    return Evaluation(result, [], cal, "recordings", tare)


def replay(calibration: CalibrationLike, bag: PathLike, out: PathLike, *,
           tare: str = "calibration", tracking: str = DEFAULT_TRACKING,
           references_every: float | None = None,
           csv: PathLike | None = None, inputs: Sequence[PathLike] = ()) -> ReplaySummary:
    """``strain-comp replay``: a new MCAP bag at ``out`` with every message of ``bag`` and
    the node's outputs (strain, direction, status, stamped strain, /diagnostics) at each
    input's time; ``csv``: also the series as a table. ``inputs``: files the outputs must
    not overwrite. ``references_every``: as in ``evaluate``. Returns what was replayed
    (sensors' health, messages, problems)."""

    cal = _calibration(calibration)
    paths = _paths(bag)
    assert paths is not None
    return replay_bag(paths[0], cal, out, inputs=list(inputs), tare=tare,
                      csv=None if csv is None else os.fspath(csv), tracking=tracking,
                      references_every=references_every)


# --------------------------------------------------------------------- recalibrate


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

    cal = _calibration(calibration)
    pts = [(float(r), float(s)) for r, s in points]
    if (data is None) == (not pts):
        raise InputError("recalibrate needs either two points (R, S) or data with a "
                         "reference strain")
    paths = _paths(data)
    if data is None or paths is not None:
        bag = None if paths is None else paths[0]
        new, lines = _recalibrate(cal, points=pts, bag=bag, sensors=sensors, tare=tare,
                                  form=form, first=first, span=window)
    else:
        new, lines = recalibrate_recordings(cal, _recordings(data), form=form, first=first,
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


# ------------------------------------------------------------------------ diagnose


@dataclass
class Diagnosis:
    """What ``diagnose`` found: the effects added with their readings, the held-out error
    before and after, and the calibration with the added terms."""

    result: DiagnoseResult
    diagnosed: Calibration | None = None
    """The calibration diagnosed (without the added terms)."""
    source: str = "recordings"
    """The run's bag path, or ``recordings``."""
    validate: list[str] = field(default_factory=list)
    """The validation bags' paths (none: held-out time blocks, or recordings)."""
    tare: str = "calibration"
    data: Any = None
    """The run diagnosed (a bag's path or recordings), for ``to_html``'s evaluations."""

    @property
    def calibration(self) -> Calibration:
        """The calibration with the added effect terms (save it with save_calibration)."""
        return self.result.calibration

    @property
    def before(self) -> dict[str, float]:
        """Held-out RMSE, MAE and n before the added terms (pooled over the sensors)."""
        return self.result.before

    @property
    def after(self) -> dict[str, float]:
        """The same after them."""
        return self.result.after

    @property
    def effects(self) -> list[dict[str, Any]]:
        """The effects added, in order: sensor, name, kind, reading, gain (the relative
        drop of the held-out RMSE when it was added)."""
        return [{"sensor": e.sensor, "name": e.name, "kind": e.kind,
                 "reading": record.get("reading", ""), "gain": e.gain}
                for e in self.result.added for record in [e.to_json()]]

    def summary(self) -> str:
        """The lines ``strain-comp diagnose`` prints."""
        return self.result.summary()

    def to_json(self) -> dict[str, Any]:
        """What ``diagnose --json`` writes (docs/design.md)."""
        return self.result.to_json()

    def to_html(self, calibration_path: str = "") -> str:
        """The ``diagnose --report`` page (``strain_comp.offline.report_page``): before and
        after, each effect with its reading, the residual plots, the run evaluated through
        the calibration diagnosed and through the one with the terms added (tables and
        plots), the provenance of the calibration diagnosed (named ``calibration_path``)."""

        diagnosed = self.diagnosed or self.result.calibration
        runs = []
        if self.data is not None:
            for heading, cal in (("the run through the calibration diagnosed", diagnosed),
                                 ("the run through it with the terms added",
                                  self.result.calibration)):
                ev = evaluate(cal, self.data, tare=self.tare, plot_points=PLOT_POINTS)
                figures = evaluation_figures(ev.result, cal, bag=self.source, tare=self.tare)
                runs.append((heading, BagSection(self.source, ev.result,
                                                 problems=ev.problems, figures=figures)))
        return diagnosis_page(self.result, diagnosed, calibration_path or "(in memory)",
                              self.source, validate=self.validate, tare=self.tare, runs=runs)


def diagnose(calibration: CalibrationLike, data: Data, *,
             validate: Data | Sequence[Data] | None = None, tare: str = "calibration",
             stretch_history: bool = False, session_start: bool = True,
             out: PathLike | None = None, plots: PathLike | None = None,
             inputs: Sequence[PathLike] = (), progress_bar: bool = False) -> Diagnosis:
    """``strain-comp diagnose``: find the effects ``calibration`` lacks on ``data`` (a bag or
    recordings with a reference) and add those that lower the held-out error; held out are
    time blocks of ``data``, or the ``validate`` run(s). ``out`` / ``plots``: also write the
    new calibration / the residual plots (``inputs``: files they must not overwrite).
    ``progress_bar``: a bar on stderr over the sensors and conditions tried."""

    with bar(None, "diagnose", enabled=progress_bar) as shown:
        return _diagnose(calibration, data, validate, tare, stretch_history, session_start,
                         out, plots, inputs, counter(shown) if progress_bar else None)


def _diagnose(calibration: CalibrationLike, data: Data, validate: Data | Sequence[Data] | None,
              tare: str, stretch_history: bool, session_start: bool, out: PathLike | None,
              plots: PathLike | None, inputs: Sequence[PathLike],
              progress: Callable[[int, int], None] | None) -> Diagnosis:

    cal = _calibration(calibration)
    runs: list[Any] = [] if validate is None else [validate] if (
        _is_path(validate) or isinstance(validate, (Recording, Mapping))) \
        else list(validate)  # type: ignore[arg-type]
    written = [os.fspath(p) for p in inputs]
    paths = _paths(data)
    if paths is not None and all(_paths(v) is not None for v in runs):  # the command's way
        validated = [os.fspath(v) for v in runs]
        return Diagnosis(diagnose_bag(
            paths[0], cal, validate=validated or None,
            out=out, plots=None if plots is None else os.fspath(plots), inputs=written,
            tare=tare, stretch_history=stretch_history, session_start=session_start,
            progress=progress), cal, paths[0], validated, tare, paths[0])
    val = [_run(v) for v in runs] or None
    result = diagnose_conditions(_run(data), cal, validate_recordings=val, tare=tare,
                                 stretch_history=stretch_history, session_start=session_start,
                                 progress=progress)
    written += [p for v in [data, *runs] for p in _paths(v) or []]
    if out is not None:
        _save_calibration(result.calibration, out, inputs=written)
    if plots is not None:
        write_plots(result, os.fspath(plots), inputs=written)
    return Diagnosis(result, cal, paths[0] if paths else "recordings",
                     [p for v in runs for p in _paths(v) or []], tare,
                     paths[0] if paths else _run(data))
