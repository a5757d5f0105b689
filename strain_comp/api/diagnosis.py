"""``diagnose`` from Python: ``strain-comp diagnose`` on a bag or recordings, and its result
(``Diagnosis``: effects, before and after, JSON, report page; docs/api.md)."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from strain_comp.api._inputs import (
    as_calibration,
    checked,
    input_paths,
    is_path,
    one_run,
    paths_of,
)
from strain_comp.api.evaluation import evaluate
from strain_comp.api.inputs import CalibrationLike, Data, PathLike
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration as _save_calibration
from strain_comp.diagnosis.conditions import diagnose_conditions
from strain_comp.diagnosis.report import DiagnoseResult, diagnosis_page, plot_file, write_plots
from strain_comp.io.atomic import check_distinct
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import PLOT_POINTS
from strain_comp.offline.plots import evaluation_figures
from strain_comp.offline.report_page import BagSection
from strain_comp.progress import bar, counter


@dataclass
class Diagnosis(DiagnoseResult):
    """What ``diagnose`` found: the effects added with their readings, the held-out error
    before and after (``before``, ``after``: RMSE, MAE and n pooled over the sensors), and
    ``calibration``, the calibration with the added terms (save it with save_calibration)."""

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
    def effects(self) -> list[dict[str, Any]]:
        """The effects added, in order: sensor, name, kind, reading, gain (the relative
        drop of the held-out RMSE when it was added)."""
        return [{"sensor": e.sensor, "name": e.name, "kind": e.kind, "reading": e.reading(),
                 "gain": e.gain} for e in self.added]

    def to_html(self, calibration_path: str = "") -> str:
        """The ``diagnose --report`` page (``strain_comp.offline.report_page``): before and
        after, each effect with its reading, the residual plots, the run evaluated through the
        calibration diagnosed and through the one with the terms added, and the provenance.

        Args:
            calibration_path: How the page names the calibration diagnosed (default:
                ``(in memory)``).

        Returns:
            The page, one self-contained HTML document.

        """

        diagnosed = self.diagnosed or self.calibration
        runs = []
        if self.data is not None:
            for heading, cal in (("the run through the calibration diagnosed", diagnosed),
                                 ("the run through it with the terms added",
                                  self.calibration)):
                ev = evaluate(cal, self.data, tare=self.tare, plot_points=PLOT_POINTS)
                figures = evaluation_figures(ev.result, cal, bag=self.source, tare=self.tare)
                runs.append((heading, BagSection(self.source, ev.result,
                                                 problems=ev.problems, figures=figures)))
        return diagnosis_page(self, diagnosed, calibration_path or "(in memory)",
                              self.source, validate=self.validate, tare=self.tare, runs=runs)


def diagnose(calibration: CalibrationLike, data: Data, *,
             validate: Data | Sequence[Data] | None = None, tare: str = "calibration",
             stretch_history: bool = False, session_start: bool = True,
             out: PathLike | None = None, plots: PathLike | None = None,
             inputs: Sequence[PathLike] = (), progress_bar: bool = False) -> Diagnosis:
    """``strain-comp diagnose``: find the effects ``calibration`` lacks on ``data`` and add
    those that lower the held-out error.

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        data: A bag or recordings with a reference strain.
        validate: Held-out run(s); None holds out time blocks of ``data``.
        tare: As ``--tare``.
        stretch_history: Also try the stretch-history terms (``--stretch-history``).
        session_start: Re-span on the run's start before diagnosing, as a session does.
        out: Also write the new calibration there.
        plots: Also write the residual plots into this directory.
        inputs: Files ``out`` and ``plots`` must not overwrite (besides the calibration's
            path and the bags).
        progress_bar: A bar on stderr over the sensors and conditions tried.

    Returns:
        The effects added, the held-out error before and after, and the new calibration.

    Raises:
        InputError: A path cannot be read, or the data has no calibrated sensor with a
            reference.
        CalibrationError: The calibration file cannot be read.
        BagError: A bag cannot be read.
        OutputError: An output would overwrite an input or another output, or cannot be
            written.

    """

    checked(data, "data", "data", optional=False)
    checked(tare, "text", "tare", optional=False)
    cal = as_calibration(calibration)
    runs: list[Any] = [] if validate is None else [validate] if (
        is_path(validate) or isinstance(validate, (Recording, Mapping))) \
        else list(validate)  # type: ignore[arg-type]
    check_distinct((out, plots, *(plot_file(plots, n) for n in cal.sensors if plots)))
    paths = paths_of(data) or []
    validate_paths = [p for v in runs for p in paths_of(v) or []]
    written = [*input_paths(calibration, list(inputs)), *paths, *validate_paths]
    recordings = one_run(data)[0]
    val = [one_run(v)[0] for v in runs] or None
    with bar(None, "diagnose", enabled=progress_bar) as shown:
        result = diagnose_conditions(recordings, cal, validate_recordings=val, tare=tare,
                                     stretch_history=stretch_history,
                                     session_start=session_start,
                                     progress=counter(shown) if progress_bar else None)
    if out is not None:
        _save_calibration(result.calibration, out, inputs=written)
    if plots is not None:
        write_plots(result, os.fspath(plots), inputs=written)
    return Diagnosis(**vars(result), diagnosed=cal,
                     source=paths[0] if paths else "recordings",
                     validate=validate_paths, tare=tare,
                     data=paths[0] if paths else recordings)
