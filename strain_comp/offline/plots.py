"""Evaluation plots (PNG, matplotlib's Agg backend, imported only when plots are asked for).

Per sensor (slashes in NAME become ``_``): ``NAME_time.png`` (estimate and reference
strain over time, resistance below), ``NAME_loop.png`` (estimate against reference with
the identity line; a perfect compensator lies on it, hysteresis left in the estimate
shows as a loop) and
``NAME_error_hist.png`` (histogram of S_hat - S over the scored samples).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.core.calibration import strain_unit_words
from strain_comp.io.atomic import atomic_output

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from strain_comp.offline.evaluate import EvaluationResult, SensorEvaluation


def _figure(rows: int = 1, *, height: float = 4.0) -> Figure:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=(9.0, height * rows), layout="constrained")


def _save(fig: Figure, path: Path, inputs: Sequence[str | Path] = ()) -> Path:
    """PNG written atomically (``strain_comp.io.atomic``); a path that is an input is refused."""
    with atomic_output(path, inputs=inputs) as handle:
        fig.savefig(handle, dpi=110, format="png")
    return path


def _title(ev: SensorEvaluation) -> str:
    st = ev.stats
    return (f"{ev.name} ({ev.model}): RMSE {st.rmse:.3g} {ev.unit}, max {st.max_abs:.3g} "
            f"{ev.unit}, n = {st.n}")


def plot_time(ev: SensorEvaluation, path: Path, *, inputs: Sequence[str | Path] = ()) -> Path:
    """Estimate and reference strain over time, resistance on a second panel."""
    fig = _figure(2, height=3.2)
    top, bottom = fig.subplots(2, 1, sharex=True)
    t = ev.t - ev.t[0] if ev.t.size else ev.t
    top.plot(t, ev.reference, color="0.2", lw=1.0, label="reference S")
    top.plot(t, ev.estimate, color="tab:red", lw=0.8, alpha=0.85, label="estimate S_hat")
    top.set_ylabel(f"strain [{ev.unit}]")
    top.set_title(_title(ev))
    top.legend(loc="upper right")
    top.grid(alpha=0.3)
    bottom.plot(t, ev.r, color="tab:blue", lw=0.8, label="resistance R")
    bottom.set_xlabel("time since start [s]")
    bottom.set_ylabel("resistance [ohm]")
    bottom.legend(loc="upper right")
    bottom.grid(alpha=0.3)
    return _save(fig, path, inputs)


def plot_loop(ev: SensorEvaluation, path: Path, *, inputs: Sequence[str | Path] = ()) -> Path:
    """S_hat against S with the identity line."""
    fig = _figure(height=6.0)
    ax = fig.subplots()
    s, s_hat = ev.reference[ev.scored], ev.estimate[ev.scored]
    ax.plot(s, s_hat, color="tab:red", lw=0.6, alpha=0.8, label="estimate")
    if s.size:
        lo = float(min(s.min(), s_hat.min()))
        hi = float(max(s.max(), s_hat.max()))
        ax.plot([lo, hi], [lo, hi], color="0.3", ls="--", lw=1.0, label="identity S_hat = S")
    ax.set_xlabel(f"reference strain S [{ev.unit}]")
    ax.set_ylabel(f"estimated strain S_hat [{ev.unit}]")
    ax.set_title(_title(ev))
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    return _save(fig, path, inputs)


def plot_error_hist(ev: SensorEvaluation, path: Path, *, inputs: Sequence[str | Path] = ()) -> Path:
    """Histogram of the error S_hat - S over the scored samples."""
    fig = _figure(height=4.0)
    ax = fig.subplots()
    error = ev.estimate[ev.scored] - ev.reference[ev.scored]
    ax.hist(error, bins=min(80, max(10, int(np.sqrt(error.size)))), color="tab:purple",
            alpha=0.8, label=f"S_hat - S ({error.size} samples)")
    ax.axvline(0.0, color="0.3", lw=1.0)
    ax.set_xlabel(f"error S_hat - S [{strain_unit_words(ev.unit)}]")
    ax.set_ylabel("samples")
    ax.set_title(_title(ev))
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3)
    return _save(fig, path, inputs)


def plot_evaluation(result: EvaluationResult, out_dir: str | Path, *,
                    inputs: Sequence[str | Path] = ()) -> list[Path]:
    """The three plots for every evaluated sensor in ``out_dir`` (created); paths written.
    Each is written atomically; a plot path that is one of ``inputs`` is refused."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, ev in result.sensors.items():
        stem = name.strip("/").replace("/", "_")  # sensor names may hold slashes
        written.append(plot_time(ev, out / f"{stem}_time.png", inputs=inputs))
        written.append(plot_loop(ev, out / f"{stem}_loop.png", inputs=inputs))
        written.append(plot_error_hist(ev, out / f"{stem}_error_hist.png", inputs=inputs))
    return written
