"""The ``diagnose --report`` page: the parts of ``strain_comp.offline.report_page`` with the
residual loop's results (each effect found with its reading, the held-out error before and
after, the conditions tried, the residual plots)."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from html import escape
from pathlib import Path

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.report import DiagnoseResult, residual_figure
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


def _before_after(before: dict[str, float], after: dict[str, float]) -> list[str]:
    """The rows of a held-out error table: RMSE, MAE and n before and after."""
    return [f'<tr data-when="{which}"><th>{which}</th>'
            + "".join(html_cell(record[k], "d" if k == "n" else ".4g", k)
                      for k in ("rmse", "mae", "n")) + "</tr>"
            for which, record in (("before", before), ("after", after))]


def diagnosis_page(result: DiagnoseResult, calibration: Calibration, calibration_path: str,
                   bag: str, *, validate: Sequence[str] = (), tare: str = "",
                   runs: Sequence[tuple[str, BagSection]] = ()) -> str:
    """The ``diagnose --report`` page: the held-out error before and after, each effect
    found with its reading, the conditions tried, the residual plots, ``runs`` and the
    provenance of the calibration diagnosed."""
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
        body.append(html_notes(f"{c['name']}: {c['reading']}"
                           + (f"; held-out RMSE after the loop {c['after']:.4g}, "
                              + ("chosen" if c.get("chosen") else "not chosen")
                              if isinstance(c.get("after"), float)
                              and math.isfinite(c["after"]) else "")
                           for c in result.conditions))
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
            buffer = io.BytesIO()
            fig.savefig(buffer, dpi=110, format="png")
            body.append(html_image("residual before and after against the winning term's "
                               "regressor, time and strain (held-out samples)",
                               buffer.getvalue()))
    for heading, section in runs:
        body += bag_section(section, heading)
    body.append(provenance_section(calibration, calibration_path, tare=tare))
    return html_page(f"strain_comp diagnose: {Path(bag.rstrip('/')).name}", body)
