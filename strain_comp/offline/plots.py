"""Evaluation plots (PNG, matplotlib's Agg backend, imported only when plots are asked for):
the four of ``PLOTS`` per sensor, samples outside the calibrated range in orange.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.core.calibration import strain_unit_words
from strain_comp.core.metrics import Z_95
from strain_comp.io.atomic import atomic_output

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from strain_comp.core.calibration import Calibration
    from strain_comp.offline.evaluation import EvaluationResult, SensorEvaluation

def _figure(rows: int = 1, *, height: float = 4.0) -> Figure:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=(9.0, height * rows), layout="constrained")


def png(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=110, format="png")
    return buffer.getvalue()


def plain(text: str) -> str:
    """``text`` drawn literally: ``$`` escaped, a surrogate (undecodable file name) escaped."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8").replace("$", r"\$")


def _finish(ax: Axes, title: str | None = None) -> None:
    """The title (if any), the legend beside the axes (never over the data), the grid."""
    if title is not None:
        ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    ax.grid(alpha=0.3)


def tare_words(tare: str) -> str:
    """What a ``--tare`` mode is, in words: ``rest level (tare) from the calibration``."""
    return {"calibration": "rest level (tare) from the calibration",
            "auto": "rest level (tare) from the run's start (--tare auto)"}.get(
                tare, f"tare {tare}")


def _title(ev: SensorEvaluation, context: str = "") -> str:
    st = ev.stats
    head = (f"{plain(ev.name)} ({ev.model}): RMSE {st.rmse:.3g} {ev.unit}, max_abs "
            f"{st.max_abs:.3g} {ev.unit}, n = {st.n}")
    if 0 < ev.t.size < ev.n_samples:
        head += f" (shown: a subsample of {ev.t.size} of {ev.n_samples} samples)"
    return f"{head}\n{plain(context)}" if context else head


def _limits(*arrays: np.ndarray, set_lim: Callable[[float, float], object] | None = None
            ) -> tuple[float, float] | None:
    """The finite data's range widened by 5 % of its span, set by ``set_lim`` (None: no data)."""
    finite = [a[np.isfinite(a)] for a in arrays]
    finite = [a for a in finite if a.size]
    if not finite:
        return None
    lo = float(min(a.min() for a in finite))
    hi = float(max(a.max() for a in finite))
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    lim = lo - 0.05 * span, hi + 0.05 * span
    if set_lim is not None:
        set_lim(*lim)
    return lim


def _resistance_axis(ev: SensorEvaluation) -> tuple[np.ndarray, str, float]:
    """The input in a readable prefix (ohm, kohm, Mohm), its label and its divisor."""
    r = np.asarray(ev.r, dtype=np.float64)
    if ev.input_unit != "ohm":
        return r, f"input [{ev.input_unit}]", 1.0
    top = float(np.nanmax(np.abs(r))) if np.isfinite(r).any() else 0.0
    scale, prefix = next(((f, p) for f, p in ((1e6, "M"), (1e3, "k")) if top >= f), (1.0, ""))
    return r / scale, f"resistance [{prefix}ohm]", scale


def plot_time(ev: SensorEvaluation, context: str = "") -> Figure:
    """Estimate and reference strain over time, resistance on a second panel."""
    fig = _figure(2, height=3.2)
    top, bottom = fig.subplots(2, 1, sharex=True)
    t = ev.t - ev.t[0] if ev.t.size else ev.t
    outside = ev.out_of_range
    if ev.std.size == t.size and t.size:
        half = Z_95 * ev.std
        share = "" if ev.coverage_95 is None else f", holds {100 * ev.coverage_95:.1f} %"
        top.fill_between(t, ev.estimate - half, ev.estimate + half, color="tab:red",
                         alpha=0.15, lw=0, label=f"95 % band of S_hat{share}")
    top.plot(t, ev.reference, color="0.2", lw=1.0, label="reference S")
    top.plot(t, ev.estimate, color="tab:red", lw=0.8, alpha=0.85, label="estimate S_hat")
    r, r_label, _ = _resistance_axis(ev)
    if outside.any():
        top.plot(t[outside], ev.estimate[outside], ".", color="tab:orange", ms=2.5,
                 label=f"outside the calibrated range ({int(ev.n_out_of_range)})")
        bottom.plot(t[outside], r[outside], ".", color="tab:orange", ms=2.5)
    top.set_ylabel(f"strain [{ev.unit}]")
    _limits(ev.reference, ev.estimate, set_lim=top.set_ylim)
    _finish(top, _title(ev, context))
    bottom.plot(t, r, color="tab:blue", lw=0.8, label="R" if ev.input_unit == "ohm"
                else "input")
    _limits(r, set_lim=bottom.set_ylim)
    if t.size:
        bottom.set_xlim(float(t[0]), float(t[-1]) if t[-1] > t[0] else float(t[0]) + 1.0)
    bottom.set_xlabel("time since start [s]")
    bottom.set_ylabel(r_label)
    _finish(bottom)
    return fig


def plot_loop(ax: Axes, ev: SensorEvaluation) -> None:
    """S_hat against S with the identity line; out-of-range samples marked."""
    s, s_hat = ev.reference[ev.scored], ev.estimate[ev.scored]
    ax.plot(s, s_hat, color="tab:red", lw=0.6, alpha=0.8, label="estimate")
    outside = ev.out_of_range[ev.scored]
    if outside.any():
        ax.plot(s[outside], s_hat[outside], ".", color="tab:orange", ms=2.5,
                label="outside the calibrated range")
    lim = _limits(s, s_hat)
    if lim is not None:
        ax.plot(lim, lim, color="0.3", ls="--", lw=1.0, label="identity S_hat = S")
        ax.set_xlim(*lim)
        ax.set_ylim(*lim)
        ax.set_aspect("equal")
    ax.set_xlabel(f"reference strain S [{ev.unit}]")
    ax.set_ylabel(f"estimated strain S_hat [{ev.unit}]")


def plot_raw(ax: Axes, ev: SensorEvaluation, r_range: tuple[float, float] | None) -> None:
    """Resistance against reference strain, with the calibrated range through the tare."""
    r, r_label, scale = _resistance_axis(ev)
    ax.plot(ev.reference, r, color="tab:blue", lw=0.6, alpha=0.8, label="recorded")
    outside = ev.out_of_range
    if outside.any():
        ax.plot(ev.reference[outside], r[outside], ".", color="tab:orange", ms=2.5,
                label="outside the calibrated range")
    bounds = np.empty(0)
    if r_range is not None and ev.input_unit == "ohm":
        scale *= ev.input_gain
        for k, bound in enumerate(r_range):
            ax.axhline(bound / scale, color="0.4", ls=":", lw=1.0,
                       label=("calibrated range" + (" (through the tare)"
                                                    if ev.input_gain != 1.0 else ""))
                       if k == 0 else None)
        bounds = np.asarray(r_range) / scale
    _limits(r, bounds, set_lim=ax.set_ylim)
    _limits(ev.reference, set_lim=ax.set_xlim)
    ax.set_xlabel(f"reference strain S [{ev.unit}]")
    ax.set_ylabel(r_label)


def plot_error_hist(ax: Axes, ev: SensorEvaluation) -> None:
    """Histogram of the error S_hat - S over the scored samples."""
    error = ev.estimate[ev.scored] - ev.reference[ev.scored]
    shown = (f"a subsample of {error.size} of the {ev.stats.n} scored samples"
             if error.size < ev.stats.n else f"{error.size} samples")
    ax.hist(error, bins=min(80, max(10, int(np.sqrt(error.size)))), color="tab:purple",
            alpha=0.8, label=f"S_hat - S ({shown})")
    ax.axvline(0.0, color="0.3", lw=1.0)
    ax.set_xlabel(f"error S_hat - S [{strain_unit_words(ev.unit)}]")
    ax.set_ylabel("samples")


PLOTS = {"time": "estimate and reference over time, resistance below",
         "loop": "estimate against reference (a loop left is hysteresis the model missed)",
         "raw": "recorded resistance against reference, with the calibrated range (dotted); "
                "samples outside it in orange",
         "error_hist": "error histogram"}
"""The plots per sensor, in the order drawn: ``NAME_KIND.png`` and its caption."""


def plot_files(out_dir: str | Path, names: Sequence[str]) -> list[Path]:
    """The files ``write_plots`` writes for ``names``, to check before anything is written."""
    return [Path(out_dir) / f"{name.strip('/').replace('/', '_')}_{kind}.png"
            for name in names for kind in PLOTS]


def evaluation_figures(result: EvaluationResult, calibration: Calibration, *, bag: str = "",
                       calibration_path: str = "", tare: str = ""
                       ) -> dict[str, list[tuple[str, bytes]]]:
    """The four evaluation plots of every sensor with kept samples, as PNG bytes."""
    out: dict[str, list[tuple[str, bytes]]] = {}
    for name, ev in result.sensors.items():
        if ev.t.size:
            context = context_line(result, name, bag, calibration_path, tare)
            cal = calibration.sensors.get(name)
            r_range = None if cal is None else (cal.valid_range.r_lo, cal.valid_range.r_hi)
            figures = [plot_time(ev, context)]
            for height, draw in ((6.0, plot_loop),
                                 (5.0, partial(plot_raw, r_range=r_range)),
                                 (4.0, plot_error_hist)):  # one axes each
                fig = _figure(height=height)
                ax = fig.subplots()
                draw(ax, ev)
                _finish(ax, _title(ev, context))
                figures.append(fig)
            out[name] = [(caption, png(figure))
                         for caption, figure in zip(PLOTS.values(), figures, strict=True)]
    return out


def write_plots(figures: Mapping[str, Sequence[tuple[str, bytes]]], out_dir: str | Path, *,
                inputs: Sequence[str | Path] = ()) -> list[Path]:
    """Each sensor's plots (``evaluation_figures``) into ``out_dir``, written atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, drawn in figures.items():
        for path, (_, png) in zip(plot_files(out, [name]), drawn, strict=True):
            with atomic_output(path, inputs=inputs) as handle:
                handle.write(png)
            written.append(path)
    return written


def context_line(result: EvaluationResult, name: str, bag: str, calibration_path: str,
             tare: str) -> str:
    """``bag demo.mcap, calibration cal.yaml, tare auto: rest resistance 2.1 % below ...``"""
    parts = []
    if bag:
        parts.append(f"bag {Path(bag.rstrip('/')).name}")
    if calibration_path:
        parts.append(f"calibration {Path(calibration_path).name}")
    if tare:
        done = next((note.split(": ", 1)[1] for note in result.notes
                     if note.startswith(f"{name}: ") and "tare" in note), "")
        parts.append(tare_words(tare) + (f" ({done})" if done else ""))
    return ", ".join(parts)


def plot_model_choice(choice: dict[str, object], runs: Sequence[str], unit: str, *,
                      context: str = "") -> Figure:
    """``fit --model auto``'s candidates: RMSE per run left out, the median as a bar."""
    table = choice.get("candidates") or {}
    assert isinstance(table, dict)
    models = list(table)
    fig = _figure(height=3.6)
    ax = fig.subplots()
    for i, model in enumerate(models):
        cell = table[model]
        if "median" not in cell:
            ax.text(i, 0.0, "failed", ha="center", va="bottom", fontsize=8)
            continue
        chosen = model == choice.get("chosen")
        ax.bar(i, cell["median"], 0.6, color="C0" if chosen else "none", edgecolor="C0",
               label="median" if i == 0 else None)
        errors = np.asarray(cell["errors"], dtype=float)
        ax.plot(np.full(errors.size, float(i)) + np.linspace(-0.2, 0.2, errors.size), errors,
                "o", color="C1", ms=4, label="each run left out" if i == 0 else None)
    ax.set_xticks(np.arange(len(models)), models)
    ax.set_ylabel(f"RMSE after start [{strain_unit_words(unit)}]")
    ax.set_title(f"--model auto over {len(runs)} runs: {choice.get('chosen')} chosen"
                 + (f"\n{context}" if context else ""), fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    return fig
