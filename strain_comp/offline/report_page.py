"""``evaluate --report`` and ``diagnose --report``: one self-contained HTML page (docs/design.md,
``--report``); every figure of a table carries its full value in ``data-value``."""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any

from strain_comp.core.calibration import (
    Calibration,
    SensorCalibration,
    expected_words,
    strain_unit_words,
)
from strain_comp.offline.evaluation import format_notes, json_safe
from strain_comp.offline.plots import plot_model_choice, png, tare_words
from strain_comp.version import __version__

if TYPE_CHECKING:
    from strain_comp.core.metrics import ErrorStats
    from strain_comp.offline.evaluation import EvaluationResult

STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1100px;
       color: #222; padding: 0 1em; }
h1 { font-size: 1.5em; } h2 { font-size: 1.25em; margin-top: 2em;
       border-bottom: 1px solid #ccc; } h3 { font-size: 1.05em; }
table { border-collapse: collapse; margin: 0.6em 0; }
th, td { padding: 3px 10px; border-bottom: 1px solid #e4e4e4; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
th { background: #f4f4f4; }
img { max-width: 100%; border: 1px solid #eee; margin: 0.4em 0; }
.note { color: #555; } .error { color: #a00; } code { background: #f4f4f4; }
figure { margin: 0.6em 0; } figcaption { color: #555; font-size: 0.9em; }
"""

SCORE_KEYS = (("n", "n", "d"), ("rmse", "RMSE", ".4f"), ("mae", "MAE", ".4f"),
              ("max_abs", "max_abs", ".4f"), ("r2", "r2", ".5f"))
"""Table columns: JSON key, heading, format of the shown text."""


@dataclass
class BagSection:
    """One evaluated bag (None result: ``error``), its problems, figures and plot files."""

    bag: str
    result: EvaluationResult | None
    error: str | None = None
    problems: list[str] = field(default_factory=list)
    figures: dict[str, list[tuple[str, bytes]]] = field(default_factory=dict)
    plots: list[str] = field(default_factory=list)


def html_cell(value: Any, fmt: str, key: str) -> str:
    """A table cell of a number, sortable by its value."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        text = "n/a"
    else:
        text = format(value, fmt)
    as_json = escape(json.dumps(json_safe(value)))  # NaN / inf: null, as the JSON writes it
    return f'<td class="num" data-key="{key}" data-value="{as_json}">{text}</td>'


def scores_table(rows: Iterable[tuple[str, str, ErrorStats, str, dict[str, Any]]],
                  bag: str, extra: Sequence[tuple[str, str]] = ()) -> str:
    """A table of (sensor, model, stats, unit, extra values) rows."""
    head = "".join(f"<th>{h}</th>" for h in ("sensor", "model",
                                            *(h for _, h, _ in SCORE_KEYS), "unit",
                                            *(h for _, h in extra)))
    lines = [f'<table class="scores" data-bag="{escape(bag)}"><tr>{head}</tr>']
    for name, model, stats, unit, more in rows:
        record = stats.to_dict()
        cells = "".join(html_cell(record[k], fmt, k) for k, _, fmt in SCORE_KEYS)
        cells += f"<td>{escape(strain_unit_words(unit))}</td>"
        cells += "".join(html_cell(more.get(k), "d" if isinstance(more.get(k), int) else ".4g", k)
                         for k, _ in extra)
        lines.append(f'<tr data-sensor="{escape(name)}"><td>{escape(name)}</td>'
                     f"<td>{escape(model)}</td>{cells}</tr>")
    lines.append("</table>")
    return "\n".join(lines)


def html_image(caption: str, png: bytes) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img alt="{escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{escape(caption)}</figcaption></figure>")


def html_notes(lines: Iterable[str]) -> str:
    items = "".join(f"<li>{escape(line)}</li>" for line in lines)
    return f'<ul class="note">{items}</ul>' if items else ""


def plain_text(value: Any) -> str:
    """A provenance value in one line, numbers to 4 significant digits."""
    if isinstance(value, Mapping):
        return "; ".join(f"{k}: {plain_text(v)}" for k, v in value.items()) or "none"
    if isinstance(value, (list, tuple)):
        return ", ".join(plain_text(v) for v in value) or "none"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def provenance_section(calibration: Calibration, path: str, *, tare: str = "",
                       notes: Sequence[str] = ()) -> str:
    """What the calibration is and where it came from, per sensor."""
    parts = [f"<h2>Calibration</h2><p><code>{escape(path)}</code>"
             + (f", {escape(tare_words(tare))}" if tare else "") + "</p>"]
    for name, cal in calibration.sensors.items():
        parts.append(f"<h3>{escape(name)}</h3><table class=\"provenance\">")
        for key, value in _provenance_rows(cal):
            parts.append(f'<tr data-key="{escape(key)}"><th>{escape(key)}</th>'
                         f"<td>{escape(value)}</td></tr>")
        tared = [n.split(": ", 1)[1] for n in notes if n.startswith(f"{name}: ")
                 and "tare" in n]
        if tared:
            parts.append(f"<tr><th>rest level (tare) of this run</th><td>{escape('; '.join(tared))}"
                         "</td></tr>")
        parts.append("</table>")
    return "\n".join(parts)


def _provenance_rows(cal: SensorCalibration) -> list[tuple[str, str]]:
    prov = cal.provenance
    vr = cal.valid_range
    rows = [("model", cal.model), ("strain unit", strain_unit_words(cal.strain_unit)),
            ("options", plain_text(prov.get("options") or {})),
            ("fitted on", ", ".join(str(b) for b in prov.get("bags", [])) or "not recorded"),
            ("samples fitted", plain_text(prov.get("n_samples", "not recorded"))),
            ("training RMSE", plain_text(prov.get("fit_rmse", "not recorded"))),
            ("created", f"{prov.get('created', '?')} by {prov.get('tool', '?')}"),
            ("valid range", f"R {vr.r_lo:.6g} to {vr.r_hi:.6g} {cal.input.unit}, S "
                            f"{vr.s_lo:.4g} to {vr.s_hi:.4g} {cal.strain_unit}"),
            ("direction", f"dead zone {cal.direction.deadzone:.4g} {cal.input.rate_unit}, "
                          f"tau {cal.direction.tau:g} s"),
            ("rest resistance", plain_text(cal.rest_resistance)),
            ("input", plain_text(cal.input.to_dict()))]
    if "memory" in prov:
        rows.append(("memory", plain_text(prov["memory"])))
    if expected_words(cal):
        rows.append(("expected error", str(expected_words(cal))))
    rows.append(("effect terms", "; ".join(
        f"{e.get('name')} ({e.get('kind')}, coef {float(e.get('coef', 0.0)):.4g})"
        for e in cal.effects) or "none"))
    rows.append(("recalibrations", "; ".join(plain_text(r) for r in prov.get("recalibrations", []))
                 or "none"))
    return rows


def html_page(title: str, body: Sequence[str]) -> str:
    """A self-contained page: the style, the title, the version and time, then ``body``."""
    stamp = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{escape(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        f'<p class="note">strain_comp {__version__}, {stamp}. Errors S_hat - S in the '
        "calibration's strain unit over the scored samples; RMSE [Electrolycra] eq. (5).</p>",
        *body, "</body></html>", ""])


def bag_section(section: BagSection, heading: str = "") -> list[str]:
    """One bag's heading, table, notes and plots."""
    body = [f"<h2>{escape(heading or section.bag)}</h2>"]
    if section.result is None:
        return [*body, f'<p class="error">not evaluated: {escape(section.error or "")}</p>']
    result = section.result
    bound = any(ev.in_run_rmse is not None for ev in result.sensors.values())
    body.append(scores_table(
        ((name, ev.model, ev.stats, ev.unit,
          {"n_out_of_range": ev.n_out_of_range, "n_bad": ev.n_bad,
           **({"in_run_rmse": ev.in_run_rmse} if ev.in_run_rmse is not None else {})})
         for name, ev in result.sensors.items()), heading or section.bag,
        [("n_out_of_range", "out of range"), ("n_bad", "bad"),
         *([("in_run_rmse", "in-run RMSE")] if bound else [])]))
    body.append(html_notes(section.problems + format_notes(result)))
    for name, figures in section.figures.items():
        body.append(f"<h3>{escape(name)}</h3>")
        body += [html_image(caption, png) for caption, png in figures]
    return body


def evaluation_page(sections: Sequence[BagSection], calibration: Calibration,
                    calibration_path: str, *, tare: str = "",
                    pooled: Mapping[str, tuple[Any, int, str, str]] | None = None) -> str:
    """The ``evaluate --report`` page: the pooled table, a section per bag, provenance."""
    body: list[str] = []
    if pooled is not None:
        done = sum(s.result is not None for s in sections)
        body.append(f"<h2>All bags: errors pooled over {done} of {len(sections)}</h2>")
        body.append(scores_table(((name, model, acc.stats(), unit, {"n_bags": n_bags})
                                   for name, (acc, n_bags, model, unit) in pooled.items()),
                                  "(pooled)", [("n_bags", "bags")]))
    notes: list[str] = []
    for section in sections:
        body += bag_section(section)
        if section.result is not None:
            notes += section.result.notes
    body.append(provenance_section(calibration, calibration_path, tare=tare, notes=notes))
    names = ", ".join(Path(s.bag.rstrip("/")).name for s in sections[:3])
    more = f" and {len(sections) - 3} more" if len(sections) > 3 else ""
    return html_page(f"strain_comp evaluate: {names}{more}", body)


def model_choice_page(calibration: Calibration, calibration_path: str) -> str:
    """The ``fit --model auto --report`` page: each sensor's candidates, then provenance."""
    body: list[str] = []
    for name, cal in calibration.sensors.items():
        choice = cal.provenance.get("model_choice") or {}
        runs = [Path(str(b)).stem for b in cal.provenance.get("bags", [])]
        body.append(f"<h2>{escape(name)}: {escape(str(choice.get('chosen', cal.model)))} "
                    "chosen</h2>")
        body.append(html_notes([str(choice.get("why", "not chosen by leaving runs out"))]))
        table = choice.get("candidates") or {}
        if not table:
            continue
        head = "".join(f"<th>{escape(h)}</th>" for h in ("model", "median", "worst", *runs))
        lines = [f'<table class="scores" data-sensor="{escape(name)}"><tr>{head}</tr>']
        for model, cell in table.items():
            if "median" not in cell:
                lines.append(f"<tr><td>{escape(model)}</td><td colspan=\"{2 + len(runs)}\">"
                             f"failed: {escape(str(cell.get('failed')))}</td></tr>")
                continue
            cells = html_cell(cell["median"], ".4g", "median") + \
                html_cell(cell["worst"], ".4g", "worst") + \
                "".join(html_cell(e, ".4g", f"run{i}") for i, e in enumerate(cell["errors"]))
            lines.append(f'<tr data-model="{escape(model)}"><td>{escape(model)}</td>{cells}'
                         "</tr>")
        lines.append("</table>")
        body.append("\n".join(lines))
        figure = plot_model_choice(choice, runs, cal.strain_unit, context=calibration_path)
        body.append(html_image(f"{name}: RMSE of each candidate on each run left out, after "
                               "strain-comp start", png(figure)))
    body.append(provenance_section(calibration, calibration_path))
    return html_page(f"strain_comp fit --model auto: {calibration_path}", body)
