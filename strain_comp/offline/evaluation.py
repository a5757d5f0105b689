"""An evaluation's result (``offline.evaluate``): each sensor's run and error statistics, its
table and its notes."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from strain_comp.core.calibration import strain_unit_words
from strain_comp.core.fusion import fusion_note
from strain_comp.core.metrics import ErrorAccumulator, ErrorStats


@dataclass
class SensorEvaluation:
    """One sensor's run: the arrays (for plots) and its error statistics."""

    name: str
    model: str
    stats: ErrorStats
    t: np.ndarray
    r: np.ndarray
    reference: np.ndarray
    estimate: np.ndarray
    direction: np.ndarray
    scored: np.ndarray
    """Boolean mask of the samples the statistics were taken over."""
    n_samples: int
    n_bad: int
    n_out_of_range: int
    errors: ErrorAccumulator = field(repr=False, compare=False)
    """The running sums behind ``stats``, to pool several bags."""
    bad_by_status: dict[str, int] = field(default_factory=dict)
    in_run_rmse: float | None = None
    """RMSE of the same model fitted on this run itself (``in_run_bound``), if asked."""
    unit: str = "%"
    """The unit of the strain and of the errors: the calibration's ``strain_unit``."""
    out_of_range: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    """Boolean mask (same samples as ``t``): outside the calibration's valid range."""
    input_unit: str = "ohm"
    input_gain: float = 1.0
    """The tare's gain: the model saw ``r`` (in ohm) times this."""
    references: dict[str, Any] | None = None
    """What the fused references did (``OutputFusion.state`` and ``every``), when fused."""
    std: np.ndarray = field(default_factory=lambda: np.empty(0))
    """The estimate's standard deviation per sample of ``t`` (empty: no uncertainty)."""
    coverage_95: float | None = None
    """The share of the scored samples inside the 95 % band; None without a band."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON record: the docs/design.md keys first, then extra keys."""
        record: dict[str, Any] = self.stats.to_dict()
        record.update(model=self.model, n_samples=self.n_samples, n_bad=self.n_bad,
                      n_out_of_range=self.n_out_of_range, bad_by_status=self.bad_by_status,
                      unit=self.unit)
        if self.coverage_95 is not None:
            record["coverage_95"] = self.coverage_95
        if self.in_run_rmse is not None:
            record["in_run_rmse"] = self.in_run_rmse
        # docs/design.md's key, kept: baseline tracking was removed, so it never acts
        record["baseline_tracking"] = {"seconds": 0.0, "correction": 0.0}
        if self.references is not None:
            record["references"] = self.references
        return json_safe(record)  # type: ignore[no-any-return]


@dataclass
class EvaluationResult:
    """Per-sensor evaluations plus notes (calibrated sensors the data could not score)."""

    sensors: dict[str, SensorEvaluation]
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """``{"sensors": {NAME: {"rmse", "mae", "max_abs", "r2", "n", ...}}}`` (docs/design.md)."""
        return {"sensors": {name: ev.to_dict() for name, ev in self.sensors.items()}}


def json_safe(value: Any) -> Any:
    """NaN and inf (not JSON) as null, recursively (dicts, lists, tuples as lists)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def score_lines(rows: Sequence[tuple[str, str, int | None, ErrorStats, float | None]],
                bags: bool = False) -> Iterator[str]:
    """Header, rule and a line per (sensor, model, bags, stats, 95 % coverage) row."""
    banded = any(coverage is not None for *_, coverage in rows)
    header = (f"{'sensor':<16} {'model':<11}" + (f" {'bags':>4}" if bags else "")
              + f" {'n':>8} {'RMSE':>9} {'MAE':>9} {'max_abs':>9} {'r2':>8}"
              + (f" {'in 95%':>7}" if banded else ""))
    yield from (header, "-" * len(header))
    for name, model, n_bags, st, coverage in rows:
        line = (f"{name:<16} {model:<11}" + (f" {n_bags:>4d}" if bags else "")
                + f" {st.n:>8d} {st.rmse:>9.4f} {st.mae:>9.4f} {st.max_abs:>9.4f} {st.r2:>8.5f}")
        if banded:  # the share of the scored samples inside the band, "-" without one
            line += f" {'-':>7}" if coverage is None else f" {100.0 * coverage:>6.1f}%"
        yield line


def format_table(result: EvaluationResult) -> str:
    """Fixed-width error table, errors in each calibration's strain unit (% strain)."""
    banded = any(ev.coverage_95 is not None for ev in result.sensors.values())
    rows = score_lines([(name, ev.model, None, ev.stats, ev.coverage_95)
                        for name, ev in result.sensors.items()])
    lines = [next(rows), next(rows)]
    for ev in result.sensors.values():
        lines.append(next(rows))
        if ev.in_run_rmse is not None:
            lines.append(f"{'':<16} in-run bound (same model fitted on this run): RMSE "
                         f"{ev.in_run_rmse:.4f}")
    units = sorted({ev.unit for ev in result.sensors.values()} or {"%"})
    words = strain_unit_words(units[0])
    if len(units) > 1:
        words = ", ".join(strain_unit_words(u) + " (" + ", ".join(
            n for n, ev in result.sensors.items() if ev.unit == u) + ")" for u in units)
    lines.append(f"errors in {words}; RMSE [Electrolycra] eq. (5)"
                 + ("; in 95%: the scored samples inside the 95 % band (+-1.96 sigma)"
                    if banded else ""))
    return "\n".join(lines)


def format_notes(result: EvaluationResult) -> list[str]:
    """Lines for what the table does not show: bad, unreferenced, out of range, unscored."""
    lines = []
    for name, ev in result.sensors.items():
        if ev.n_bad:
            kinds = ", ".join(f"{k} {v}" for k, v in ev.bad_by_status.items())
            lines.append(f"{name}: {ev.n_bad} of {ev.n_samples} samples bad ({kinds}); "
                         "estimate held, not scored")
        unreferenced = ev.n_samples - ev.n_bad - ev.stats.n
        if unreferenced > 0:
            lines.append(f"{name}: {unreferenced} of {ev.n_samples} samples without a finite "
                         "reference or estimate (NaN, or outside the reference's time span); "
                         "not scored")
        if ev.n_out_of_range:
            lines.append(f"{name}: {ev.n_out_of_range} of the {ev.n_samples} samples ("
                         f"{ev.stats.n} scored) outside the "
                         "calibration's valid range (flagged, scored); if the sensor's "
                         "rest level or sensitivity moved, start the session on a stretch "
                         "and back (strain-comp start)")
        if ev.references is not None:
            lines.append(fusion_note(name, ev.references, ev.references["every"], ev.unit))
    return lines + list(result.notes)
