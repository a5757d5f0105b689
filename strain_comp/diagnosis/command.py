"""``strain-comp diagnose``: the bags read, the residual loop and its conditions run
(``strain_comp.diagnosis.conditions``), the new calibration and the plots written
(docs/design.md, "The residual loop")."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration
from strain_comp.diagnosis.conditions import diagnose_conditions
from strain_comp.diagnosis.report import DiagnoseResult, write_plots
from strain_comp.io.recording import load_recordings


def diagnose_bag(bag: str | Path, calibration: Calibration, *,
                 validate: str | Path | Sequence[str | Path] | None = None,
                 out: str | Path | None = None, plots: str | Path | None = None,
                 inputs: Sequence[str | Path] = (), **options: Any) -> DiagnoseResult:
    """``strain-comp diagnose``: load the bag(s), diagnose, write CAL2 and the plots
    (atomically; an output that is a bag or one of ``inputs`` is refused). ``validate``:
    one validation bag or several (each a run of its own)."""
    paths = [] if validate is None else [validate] if isinstance(validate, str | Path) \
        else list(validate)
    inputs = [bag, *paths, *inputs]
    recordings, _ = load_recordings(bag)
    val = [load_recordings(p)[0] for p in paths] or None
    result = diagnose_conditions(recordings, calibration, validate_recordings=val,
                                 **options)
    if out is not None:
        save_calibration(result.calibration, out, inputs=inputs)
    if plots is not None:
        write_plots(result, plots, inputs=inputs)
    return result
