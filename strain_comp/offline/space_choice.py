"""Which session start a pooled fit takes (``fit A B C ...``, ``--pool spanned``), chosen by
leaving out each training run in turn.

For every training run j, the pooled cubic (``POOL_DEGREE``'s model, as the pooling's
``gate``) is fitted on the other runs in one input space (``pool.joint_maps``), started on
run j as a user starts a session (``session_started``: its calibration stretch, the
README's procedure) both ways (``pool.SPACES``) and scored over all of run j. The start with
the lower root mean square of those errors is the fit's. The two err in opposite ways:
``joint`` reads the run's zero and span on its stretch through the calibration's steady
outputs, right where the sensor holds its sensitivity through a run (the conductive
fibre); ``stretch`` places the run where the training runs' stretches lay, so a
sensitivity that moves after the stretch as it did on them (the silver-nylon thread) is
placed as it was there (docs/results.md, "Pooling and the session start").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.errors import StrainCompError
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.pool import SPACES
from strain_comp.offline.session_start import start_or_keep

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

Fit = Callable[[Sequence["Recording"]], SensorCalibration]
"""Fits the choice's model on runs pooled with the stretch line (``fit_sensor`` of the
cubic, ``pool="stretch"``)."""


def session_started(cal: SensorCalibration, rec: Recording) -> Calibration:
    """``cal`` after the session start on ``rec`` (``session_start.start_or_keep``: its
    calibration stretch found, as ``strain-comp start`` finds it); as it is where refused."""
    return start_or_keep(Calibration({cal.name: cal}), {cal.name: rec}).calibration


def choose_space(recordings: Sequence[Recording], fit: Fit) -> tuple[str, dict[str, Any]]:
    """The session start of a pooled fit (module docstring)."""
    errors: dict[str, list[float]] = {space: [] for space in SPACES}
    for j, held in enumerate(recordings):
        rest = [rec for i, rec in enumerate(recordings) if i != j]
        try:
            cal = fit(rest)
        except StrainCompError:
            continue
        if cal.input.stretch_line is None:
            continue
        fold = {}
        for space in SPACES:
            used = cal if space == "stretch" else replace(
                cal, input=replace(cal.input, stretch_line=None))
            try:
                started = session_started(used, held)
                ev = evaluate_recordings({cal.name: held}, started, tare="calibration")
                fold[space] = float(ev.sensors[cal.name].stats.rmse)
            except StrainCompError:
                fold[space] = float("nan")
        if all(np.isfinite(v) for v in fold.values()):
            for space, value in fold.items():
                errors[space].append(value)
    measured = {space: float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")
                for space, v in errors.items()}
    chosen = SPACES[1] if measured[SPACES[1]] < measured[SPACES[0]] else SPACES[0]
    return chosen, {"left_out_rmse": {k: round(v, 6) if np.isfinite(v) else None
                                      for k, v in measured.items()},
                    "runs_left_out": len(errors[SPACES[0]])}
