"""``evaluate`` from Python: ``strain-comp evaluate`` on one run, and its result
(``Evaluation``: scores, table, JSON, frame, report page; docs/api.md)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from strain_comp.api._inputs import (
    as_calibration,
    as_recordings,
    checked,
    input_paths,
    paths_of,
)
from strain_comp.api.inputs import CalibrationLike, Data, PathLike, read_recordings
from strain_comp.core.calibration import Calibration, strain_unit_words
from strain_comp.core.engine import tracking_off
from strain_comp.errors import InputError
from strain_comp.offline.evaluate import evaluate_bag, evaluate_recordings
from strain_comp.offline.evaluation import format_notes, format_table
from strain_comp.offline.fit import in_run_bound as _in_run_bound
from strain_comp.offline.plots import evaluation_figures
from strain_comp.offline.report_page import BagSection, evaluation_page, scores_table
from strain_comp.offline.series import series_csv

if TYPE_CHECKING:
    from strain_comp.offline.evaluation import EvaluationResult


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
        return {name: {"model": ev.model, "n": ev.stats.n, **ev.stats.to_dict(), "unit": ev.unit}
                for name, ev in self.result.sensors.items()}

    def table(self) -> str:
        """The table ``strain-comp evaluate`` prints.

        Returns:
            The table's text, one row per sensor.

        """

        return format_table(self.result)

    def to_json(self) -> dict[str, Any]:
        """What ``evaluate --json`` writes (docs/design.md).

        Returns:
            The JSON document.

        """
        return self.result.to_json()

    def __repr__(self) -> str:
        """Short: the run and each sensor's model, n and RMSE (``table`` has the rest)."""
        parts = [f"{name} ({row['model']}, n {row['n']}, RMSE {row['rmse']:.4g} "
                 f"{strain_unit_words(row['unit'])})" for name, row in self.scores.items()]
        return f"Evaluation({self.source}: {', '.join(parts)})"

    def _repr_html_(self) -> str:
        """The report page's table of the scores, for a notebook."""
        return scores_table(((name, ev.model, ev.stats, ev.unit, {})
                             for name, ev in self.result.sensors.items()), self.source)

    def to_frame(self, run: str | None = None) -> Any:
        """``scores`` as a pandas DataFrame, one row per sensor, indexed by (model, run,
        sensor): frames of several models and runs stay unique when concatenated
        (``pd.concat([ev.to_frame() for ev in evaluations])``).

        Args:
            run: The index's run label (default: the bag's path, or ``recordings``; name
                runs given as recordings here).

        Returns:
            The DataFrame: columns n, rmse, mae, max_abs, r2, unit.

        Raises:
            InputError: pandas (optional) is not installed, or ``run`` is not text.

        """
        run = checked(run, "text", "run") or self.source
        try:
            import pandas
        except ImportError:
            raise InputError("to_frame needs pandas (optional: pip install pandas); the "
                             "arrays and dicts work without it") from None
        rows = [{"model": row["model"], "run": run, "sensor": name,
                 **{k: v for k, v in row.items() if k != "model"}}
                for name, row in self.scores.items()]
        return pandas.DataFrame(rows).set_index(["model", "run", "sensor"])

    def to_html(self, calibration_path: str = "") -> str:
        """The ``evaluate --report`` page (``strain_comp.offline.report_page``): the table, the
        plots (of the samples kept: ``plot_points``) and the calibration's provenance.

        Args:
            calibration_path: How the page names the calibration (default: ``(in memory)``).

        Returns:
            The page, one self-contained HTML document.

        """

        cal = self.calibration or Calibration({})
        figures = evaluation_figures(self.result, cal, bag=self.source,
                                     calibration_path=calibration_path, tare=self.tare)
        return evaluation_page([BagSection(self.source, self.result,
                                           problems=self.problems, figures=figures)],
                               cal, calibration_path or "(in memory)", tare=self.tare)


def evaluate(calibration: CalibrationLike, data: Data, *, tare: str = "calibration",
             out_of_range: str = "extend", tracking: str = "off",
             in_run_bound: bool = False, plot_points: int = 0,
             references_every: float | None = None,
             csv: PathLike | None = None, inputs: Sequence[PathLike] = ()) -> Evaluation:
    """Score ``calibration`` on one run with a reference strain (``strain-comp evaluate``).

    Args:
        calibration: A ``Calibration`` or the path of a calibration file.
        data: One bag (streamed, as ``strain-comp evaluate`` reads it), a Recording or a
            dict of them.
        tare: As ``--tare``.
        out_of_range: As ``--out-of-range``.
        tracking: As ``--baseline-tracking``: ``off``, the only value left.
        in_run_bound: Also the RMSE of the same model fitted on this run.
        plot_points: Keep that many evenly spaced samples per sensor in ``result`` for
            plots and ``to_html`` (a bag; recordings keep all).
        references_every: The run's own reference every that many seconds fused into each
            sensor's output gain and offset (``evaluate --references-every``;
            docs/results.md); None fuses none.
        csv: Also write every sample there (``evaluate --csv``; a bag only).
        inputs: Files ``csv`` must not overwrite (besides the calibration's path and the
            bag).

    Returns:
        The scores per sensor, with what the reader skipped.

    Raises:
        InputError: No calibrated sensor can be scored, several bags, ``csv`` with
            recordings, a path that cannot be read, or a ``tracking`` but ``off``.
        CalibrationError: The calibration file cannot be read.
        BagError: The bag cannot be read.
        OutputError: ``csv`` would overwrite an input or cannot be written.

    """

    checked(data, "data", "data", optional=False)
    for value, what in ((tare, "tare"), (out_of_range, "out_of_range"), (tracking, "tracking")):
        checked(value, "text", what, optional=False)
    tracking_off(tracking)
    plot_points = checked(plot_points, "count", "plot_points", optional=False)
    references_every = checked(references_every, "seconds", "references_every")
    cal = as_calibration(calibration)
    paths = paths_of(data)
    if paths is not None and len(paths) == 1:
        with series_csv(None if csv is None else os.fspath(csv),
                        inputs=[*paths, *input_paths(calibration, list(inputs))]) as table:
            result, problems = evaluate_bag(paths[0], cal, tare=tare, plot_points=plot_points,
                                            series=table, out_of_range=out_of_range,
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
    recordings = as_recordings(data)
    result = evaluate_recordings(recordings, cal, tare=tare, out_of_range=out_of_range,
                                 references_every=references_every)
    if in_run_bound:
        _in_run_bound(result, recordings, cal)
    return Evaluation(result, [], cal, "recordings", tare)
