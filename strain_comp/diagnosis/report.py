"""Reports of the residual loop: per-candidate evidence, physical readings, per-sensor and
pooled results (terminal summary, JSON), the residual plots and the ``diagnose --report`` page."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import Calibration, strain_unit_words
from strain_comp.io.atomic import atomic_output
from strain_comp.offline.plots import plain, png
from strain_comp.offline.report_page import (
    BagSection,
    bag_section,
    html_cell,
    html_image,
    html_notes,
    html_page,
    plain_text,
    provenance_section,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure

SESSION_RECORDS = ("session start", "gain change between runs")
"""Names of the ``conditions`` records of the validation runs' session start (never chosen)."""


@dataclass
class EffectScore:
    """One candidate's evidence."""

    sensor: str
    name: str
    kind: str
    params: dict[str, Any]
    score: float
    """Held-out share of residual variance explained (first round)."""
    added: bool = False
    gain: float | None = None
    """Relative drop of the cross-validated RMSE in the round it was added."""
    coef: float | None = None
    magnitude: float | None = None
    """coef * std(g) over the fit data: the typical size of the correction."""
    rank: int | None = None
    """Order of addition (0 first); None when not added."""
    unit: str = "%"
    """The calibration's strain unit, the unit of coef and magnitude."""
    span: float | None = None
    """The calibration's valid strain span: creep sizes are read in % of it."""
    lag: bool | None = None
    """A creep term: True when the estimate lags the reference, False when it overshoots."""

    def reading(self) -> str:
        """``effect_reading`` of this term (an added one: with its coefficient)."""
        return effect_reading(self.kind, self.params, self.coef or 0.0, self.magnitude,
                              unit=self.unit, span=self.span, lag=self.lag)

    def to_json(self) -> dict[str, Any]:
        record: dict[str, Any] = {"name": self.name, "score": _num(self.score),
                                  "added": self.added, "sensor": self.sensor, "kind": self.kind,
                                  "params": self.params}
        if self.params.get("tau") is not None:
            record["time_constant"] = self.params["tau"]
        if creep_tau(self.kind, self.params) is not None:
            record["family"] = "creep"
        for key in ("gain", "coef", "magnitude"):
            value = getattr(self, key)
            if value is not None:
                record[key] = _num(value)
        if self.added and self.coef is not None:
            record["reading"] = self.reading()
        return record


def creep_tau(kind: str, params: Mapping[str, Any]) -> float | None:
    """The time constant [s] of a creep term (one Prony-series state), None for any other."""
    if (kind == "relaxation" and params.get("branch", "both") == "both") or (
            kind == "resistance_memory" and params.get("form", "relaxation") == "relaxation"):
        return float(params.get("tau", 10.0))
    return None


def creep_reading(tau: float, of: str, magnitude: float | None, unit: str,
                  span: float | None, lag: bool | None) -> str:
    """A creep term in words: which way the estimate errs after a change, how much, how long."""
    u = strain_unit_words(unit)
    how = {True: "the estimate lags the reference after each change",
           False: "the estimate overshoots the reference after each change",
           None: "the estimate errs after each change"}[lag]
    size = ""
    if magnitude is not None:
        size = f" by typically {abs(magnitude):.2g} {u}"
        if span is not None and span > 0:
            size = (f" by typically {100.0 * abs(magnitude) / span:.2g} % of the span "
                    f"({abs(magnitude):.2g} {u})")
    then = {True: ", catching up", False: ", relaxing back", None: ", decaying"}[lag]
    return (f"creep (Prony series, tau = {tau:g} s, a state of the {of}): {how}{size}"
            f"{then} with a time constant of {tau:g} s")


def effect_reading(kind: str, params: Mapping[str, Any], coef: float,
                   magnitude: float | None = None, *, unit: str = "%",
                   span: float | None = None, lag: bool | None = None) -> str:
    """An added term in physical words (the output carries + coef g), sizes in ``unit``."""
    u = strain_unit_words(unit)
    size = "" if magnitude is None else f", typically {abs(magnitude):.2g} {u}"
    tau = creep_tau(kind, params)
    if tau is not None:
        if kind == "relaxation":
            return creep_reading(tau, "estimate", magnitude, unit, span,
                                 None if coef == 0 else coef < 0)
        return creep_reading(tau, "resistance", magnitude, unit, span, lag)
    if kind == "offset":
        return f"output offset {coef:+.3g} {u}"
    if kind == "strain_level":
        if params.get("power", 1) == 1 and coef < 0.99:
            return f"sensitivity {100.0 * (1.0 / (1.0 - coef) - 1.0):+.1f} % against calibration"
        if params.get("power", 1) == 1:  # the output scaled by 0.01 or less, or reversed
            return (f"output gain {1.0 - coef:+.3g} against calibration: the reference does not "
                    "follow the sensor")
        return f"curvature error (strain^{params.get('power')}){size}"
    if kind == "rate":
        return f"rate-dependent lag {coef:+.3g} s (filter tau {params.get('tau')} s){size}"
    if kind == "direction" and params.get("mode") == "strain":
        return f"hysteresis +-{100.0 * abs(coef):.3g} % of the strain, loading vs unloading"
    if kind == "direction":
        return f"hysteresis +-{abs(coef):.3g} {u} between loading and unloading"
    if kind == "relaxation":
        return (f"relaxation tau {params.get('tau')} s after {params.get('branch')} "
                f"steps{size}")
    if kind == "resistance_memory":
        what = {"relaxation": "resistance still relaxing (above its recent average)",
                "peak": "resistance falling back from a recent spike",
                "trough": "resistance rising back from a recent dip"}.get(
                    str(params.get("form")), str(params.get("form")))
        return f"{what}, tau {params.get('tau')} s{size}"
    if kind == "elapsed":
        scale = float(params.get("scale", 100.0))
        if params.get("form", "linear") == "linear":
            return f"drift {coef * 3600.0 / scale:+.3g} {u}/h"
        if params.get("form") == "linear_strain":
            return f"gain drift {100.0 * coef * 3600.0 / scale:+.3g} %/h"
        return f"drift ({params.get('form')} in time){size}"
    if kind == "temperature":
        if params.get("form") == "strain":
            return f"temperature sensitivity {100.0 * coef:+.3g} %/K"
        return f"temperature offset {coef:+.3g} {u}/K"
    if kind == "mullins":
        return _mullins_reading(str(params.get("form")), float(params.get("n0", 1.0)), coef,
                                u, size)
    if kind == "stretch":
        scale = params.get("scale")
        if str(params.get("form", "rest")).startswith("gain"):
            return (f"sensitivity {100.0 * coef:+.3g} % that comes with the stretch done "
                    f"({params.get('form')}, over {scale} % of travel)")
        return (f"rest level that moves with the stretch done, {coef:+.3g} {u} "
                f"({params.get('form')}, over {scale} % of travel)")
    if kind == "crosstalk":
        return f"cross-talk {100.0 * coef:+.3g} % of {params.get('neighbour')}'s strain"
    if kind == "baseline":
        return f"per-run baseline: each run re-zeroed at its start{size}"
    return f"{kind}{size}"


def _mullins_reading(form: str, n0: float, coef: float, u: str, size: str) -> str:
    """A ``mullins`` term in words: the sensitivity against calibration it stands for."""
    pct = 100.0 * coef
    if form == "cycles_log":
        return (f"sensitivity that moves with the load cycles done: {pct:+.3g} % x ln(1 + "
                f"cycles) against calibration ({pct * math.log(11.0):+.3g} % after 10 "
                f"cycles){size}")
    if form == "cycles_exp":
        return (f"sensitivity {pct:+.3g} % against calibration at the first cycle, dying out "
                f"over about {n0:g} load cycles{size}")
    if form == "peak_strain":
        return (f"sensitivity {10.0 * pct:+.3g} % per 10 {u} of the largest strain reached "
                f"so far (Mullins-type damage){size}")
    if form == "gap":
        return (f"below the largest strain reached so far, {pct:+.3g} % of the distance to it "
                f"(Mullins-type softening){size}")
    return f"Mullins-type softening ({form}){size}"


@dataclass
class SensorDiagnosis:
    """One sensor's diagnosis, with the held-out arrays the plots show."""

    name: str
    before: dict[str, float]
    after: dict[str, float]
    scores: list[EffectScore]
    added: list[dict[str, Any]]
    """Effect entries added to the calibration (with the intercept, if any)."""
    message: str
    plot: dict[str, np.ndarray] = field(default_factory=dict)
    """Held-out t, s, e_before, e_after and the winning regressor ``g`` (empty: none)."""
    winner: str | None = None
    as_calibrated: dict[str, dict[str, float]] = field(default_factory=dict)
    """Before and after without the session start, when ``before`` and ``after`` have one."""
    session: dict[str, Any] = field(default_factory=dict)
    """The session start on the validation runs (``findings.session_record``; empty: none)."""
    runs_after: list[float] = field(default_factory=list)
    """Each validation run's RMSE after its session start, with the added terms."""

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"before": self.before, "after": self.after,
                               "message": self.message, "winner": self.winner,
                               "added": self.added}
        if self.session:
            out["after_session_start"] = True
            out["as_calibrated"] = self.as_calibrated
            out["session_start"] = {k: self.session[k] for k in
                                    ("reading", "sensitivity_change", "windows", "steps")}
        return out


@dataclass
class DiagnoseResult:
    """The outcome: per-sensor detail, pooled before/after and the output calibration."""

    sensors: dict[str, SensorDiagnosis]
    before: dict[str, float]
    after: dict[str, float]
    validated_on: str
    validation: dict[str, Any]
    calibration: Calibration
    conditions: list[dict[str, Any]] = field(default_factory=list)
    """Measurement-chain and tare hypotheses tried (``strain_comp.diagnosis.conditions``)."""

    @property
    def scored(self) -> list[EffectScore]:
        """All candidates: the added ones in order (the intercept last), then by score."""
        rows = [s for d in self.sensors.values() for s in d.scores]
        added = sorted((s for s in rows if s.added),
                       key=lambda s: (s.kind == "offset", s.sensor, s.rank))
        rest = sorted((s for s in rows if not s.added),
                      key=lambda s: -s.score if math.isfinite(s.score) else math.inf)
        return added + rest

    @property
    def added(self) -> list[EffectScore]:
        return [s for s in self.scored if s.added]

    def to_json(self) -> dict[str, Any]:
        """What ``diagnose --json`` writes (docs/design.md).

        Returns:
            The JSON document.

        """
        return {"before": self.before, "after": self.after,
                "effects": [s.to_json() for s in self.scored],
                "validated_on": self.validated_on, "validation": self.validation,
                "sensors": {n: d.to_json() for n, d in self.sensors.items()},
                "conditions": self.conditions,
                "units": {n: self.calibration.sensors[n].strain_unit for n in self.sensors}}

    def summary(self) -> str:
        """The lines ``strain-comp diagnose`` prints (one when nothing was kept).

        Returns:
            The text.

        """
        u = _unit(self)
        if not self.added and not any(c.get("chosen") for c in self.conditions):
            return (f"held-out RMSE ({self.validated_on}) {self.before['rmse']:.4g} {u}: "
                    "nothing kept, no effect term or condition lowered it (each one tried, "
                    "with its reading: --json, --report)")
        lines = [f"held-out RMSE ({self.validated_on}): before {self.before['rmse']:.4g} {u}, "
                 f"after {self.after['rmse']:.4g} {u}"]
        lines += [f"  {line}" for line in condition_lines(self)]
        for name, d in self.sensors.items():
            lines.append(f"  {name}: {d.message}")
            for e in d.scores:
                if e.added and e.coef is not None:
                    lines.append(f"    + {e.name}: {e.reading()}")
        return "\n".join(lines)


def _unit(result: DiagnoseResult) -> str:
    units = {cal.strain_unit for cal in result.calibration.sensors.values()}
    return units.pop() if len(units) == 1 else "(each sensor's unit)"


def condition_lines(result: DiagnoseResult) -> list[str]:
    """Each condition: its reading and, for one the whole loop ran under, the loop's result."""
    lines = []
    for c in result.conditions:
        line = f"{c['name']}: {c['reading']}"
        if c["name"] not in ("measurement chain", *SESSION_RECORDS):
            line += (f"; held-out RMSE after the loop {c['after']:.4g} {_unit(result)} "
                     f"({'chosen' if c['chosen'] else 'not chosen'})")
        lines.append(line)
    return lines


def _num(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def plot_file(out_dir: str | Path, name: str) -> Path:
    """The residual plot ``write_plots`` writes for sensor ``name`` into ``out_dir``."""
    return Path(out_dir) / f"diagnose_{name}.png"


def write_plots(result: DiagnoseResult, out_dir: str | Path, *,
                inputs: Sequence[str | Path] = ()) -> list[Path]:
    """One PNG per sensor of ``residual_figure``, each written atomically, none over ``inputs``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name in result.sensors:
        fig = residual_figure(result, name)
        if fig is None:
            continue
        path = plot_file(out_dir, name)
        with atomic_output(path, inputs=inputs) as handle:
            fig.savefig(handle, dpi=110, format="png")
        written.append(path)
    return written


def residual_figure(result: DiagnoseResult, name: str) -> Figure | None:
    """The held-out residual before and after against the winning regressor, time and strain."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    d = result.sensors[name]
    if not d.plot:
        return None
    fig = Figure(figsize=(16, 4.2))
    p = d.plot
    u = result.calibration.sensors[name].strain_unit
    panels = ((p["g"], plain(f"regressor {d.winner}"), f"residual S_hat - S [{u}]", 0.4),
              (p["t"], "time [s] (held-out samples)", f"residual [{u}]", None),
              (p["s"], f"reference strain [{u}] (held-out samples)", f"residual [{u}]", 0.4))
    for ax, (x, xlabel, ylabel, alpha) in zip(fig.subplots(1, 3), panels, strict=True):
        ax.plot(x, p["e_before"], ".", ms=2, alpha=alpha, label="before")
        ax.plot(x, p["e_after"], ".", ms=2, alpha=alpha, label="after")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.legend(markerscale=4)
    fig.suptitle(plain(f"{name}: {d.message}"), fontsize=8)
    fig.tight_layout()
    return fig


def _before_after(before: dict[str, float], after: dict[str, float]) -> list[str]:
    """The rows of a held-out error table: RMSE, MAE and n before and after."""
    return [f'<tr data-when="{which}"><th>{which}</th>'
            + "".join(html_cell(record[k], "d" if k == "n" else ".4g", k)
                      for k in ("rmse", "mae", "n")) + "</tr>"
            for which, record in (("before", before), ("after", after))]


def diagnosis_page(result: DiagnoseResult, calibration: Calibration, calibration_path: str,
                   bag: str, *, validate: Sequence[str] = (), tare: str = "",
                   runs: Sequence[tuple[str, BagSection]] = ()) -> str:
    """The ``diagnose --report`` page (``Diagnosis.to_html`` says what it shows)."""
    body = [f"<p>Run <code>{escape(bag)}</code>; held out: "
            + (escape(", ".join(validate)) if validate else
               f"time blocks of the run ({escape(plain_text(result.validation))})") + "</p>",
            "<h2>Held-out error, all sensors</h2>",
            '<table class="before-after"><tr><th></th><th>RMSE</th><th>MAE</th><th>n</th>'
            "</tr>", *_before_after(result.before, result.after), "</table>"]
    body.append("<h2>Effects found</h2>")
    added = result.added
    if added:
        body.append('<table class="effects"><tr><th>sensor</th><th>term</th><th>kind</th>'
                    "<th>reading</th><th>held-out RMSE drop</th></tr>")
        for effect in added:
            body.append(f'<tr data-effect="{escape(effect.name)}"><td>{escape(effect.sensor)}'
                        f"</td><td>{escape(effect.name)}</td><td>{escape(effect.kind)}</td>"
                        f"<td>{escape(effect.reading())}</td>"
                        + html_cell(effect.gain, ".1%", "gain") + "</tr>")
        body.append("</table>")
    else:
        body.append("<p>None: no candidate lowered the held-out error enough.</p>")
    if result.conditions:
        body.append("<h2>Conditions tried</h2>")
        body.append(html_notes(condition_lines(result)))
    for name, d in result.sensors.items():
        unit = result.calibration.sensors[name].strain_unit
        body.append(f"<h2>{escape(name)}</h2><p>{escape(d.message)}</p>")
        body.append(f'<table class="sensor-before-after" data-sensor="{escape(name)}">'
                    f"<tr><th></th><th>RMSE [{escape(unit)}]</th><th>MAE</th><th>n</th></tr>")
        body += [*_before_after(d.before, d.after), "</table>"]
        scored = sorted(d.scores, key=lambda e: -e.score if math.isfinite(e.score) else 0.0)
        body.append("<details><summary>every candidate scored</summary>"
                    + html_notes(f"{e.name} ({e.kind}): held-out share of the residual "
                             f"{e.score:.3g}" + (", added" if e.added else "")
                             for e in scored) + "</details>")
        fig = residual_figure(result, name)
        if fig is not None:
            body.append(html_image("residual before and after against the winning term's "
                               "regressor, time and strain (held-out samples)", png(fig)))
    for heading, section in runs:
        body += bag_section(section, heading)
    body.append(provenance_section(calibration, calibration_path, tare=tare))
    return html_page(f"strain_comp diagnose: {Path(bag.rstrip('/')).name}", body)
