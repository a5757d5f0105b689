"""``evaluate --report`` and ``diagnose --report``: one self-contained HTML page whose
figures are the JSON's (parsed back with html.parser), with the plots embedded and nothing
fetched from a network; written atomically, never over an input."""

from __future__ import annotations

import base64
import json
import re
import shutil
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from strain_comp.cli import main
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration
from strain_comp.offline.report_page import provenance_section

ROOT = Path(__file__).resolve().parents[2]
BAG = str(ROOT / "bags" / "demo_rates.mcap")
STEPS = str(ROOT / "bags" / "steps.mcap")
CAL = str(ROOT / "config" / "demo_calibration.yaml")
PNG = b"\x89PNG\r\n\x1a\n"


class Page(HTMLParser):
    """What a test reads of a report: every cell with ``data-key`` (in its table and row
    context), the embedded images, every linked address and the provenance rows."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.cells: list[dict[str, Any]] = []
        self.images: list[bytes] = []
        self.links: list[str] = []
        self.effects: list[list[str]] = []
        self.provenance: dict[str, str] = {}
        self._table: dict[str, str] = {}
        self._row: dict[str, str] = {}
        self._text: list[str] | None = None
        self._prov_key: str | None = None
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        for key in ("src", "href"):
            if key in a:
                self.links.append(a[key])
        if tag == "table":
            self._table = a
        elif tag == "tr":
            self._row = a
            if "data-effect" in a:
                self.effects.append([])
            if self._table.get("class") == "provenance":
                self._prov_key = a.get("data-key")
        elif tag == "td":
            self._text = []
            if "data-key" in a:
                self.cells.append({"table": self._table.get("class"),
                                   "bag": self._table.get("data-bag"),
                                   "sensor": self._row.get("data-sensor")
                                   or self._table.get("data-sensor"),
                                   "when": self._row.get("data-when"),
                                   "effect": self._row.get("data-effect"),
                                   "key": a["data-key"], "value": json.loads(a["data-value"])})
        elif tag == "img":
            src = a.get("src", "")
            assert src.startswith("data:image/png;base64,")
            self.images.append(base64.b64decode(src.split(",", 1)[1]))

    def handle_data(self, data: str) -> None:
        if self._text is not None:
            self._text.append(data)

    def handle_endtag(self, tag: str) -> None:
        if tag == "td" and self._text is not None:
            text = "".join(self._text)
            if "data-effect" in self._row:
                self.effects[-1].append(text)
            if self._prov_key is not None:
                self.provenance[self._prov_key] = text
            self._text = None

    def cell(self, **where: Any) -> Any:
        found = [c["value"] for c in self.cells
                 if all(c.get(k) == v for k, v in where.items())]
        assert len(found) == 1, (where, found)
        return found[0]


def _self_contained(page: Page) -> None:
    assert all(link.startswith("data:") for link in page.links), page.links
    assert page.images and all(png.startswith(PNG) for png in page.images)


def test_evaluate_report_holds_the_json_figures(tmp_path: Path) -> None:
    report, out = tmp_path / "report.html", tmp_path / "errors.json"
    assert main(["evaluate", BAG, "--calibration", CAL, "--report", str(report), "--json",
                 str(out), "-q"]) == 0
    page = Page(report.read_text(encoding="utf-8"))
    record = json.loads(out.read_text())["sensors"]["s1"]
    for key in ("n", "rmse", "mae", "max_abs", "r2", "n_out_of_range", "n_bad"):
        assert page.cell(table="scores", bag=BAG, sensor="s1", key=key) == record[key]
    _self_contained(page)
    assert len(page.images) == 4  # time, loop, raw, histogram
    assert page.provenance["model"] == "apl"
    assert "train" in page.provenance["fitted on"]  # the bags it was fitted on
    assert page.provenance["recalibrations"] == "none"


def test_evaluate_report_over_several_bags(tmp_path: Path) -> None:
    report, out = tmp_path / "many.html", tmp_path / "many.json"
    assert main(["evaluate", BAG, STEPS, "--calibration", CAL, "--report", str(report),
                 "--json", str(out), "-q"]) == 0
    page = Page(report.read_text(encoding="utf-8"))
    data = json.loads(out.read_text())
    for bag in (BAG, STEPS):
        for key in ("n", "rmse", "max_abs"):
            assert page.cell(table="scores", bag=bag, sensor="s1", key=key) == \
                data["bags"][bag]["sensors"]["s1"][key]
    pooled = data["aggregate"]["sensors"]["s1"]
    for key in ("n", "rmse", "mae", "r2", "n_bags"):
        assert page.cell(table="scores", bag="(pooled)", sensor="s1", key=key) == pooled[key]
    assert len(page.images) == 8
    _self_contained(page)


def test_diagnose_report_holds_each_effect_and_the_error_before_and_after(
        tmp_path: Path) -> None:
    report, out = tmp_path / "diagnose.html", tmp_path / "diagnose.json"
    assert main(["diagnose", BAG, "--calibration", CAL, "--out", str(tmp_path / "v2.yaml"),
                 "--report", str(report), "--json", str(out), "-q"]) == 0
    page = Page(report.read_text(encoding="utf-8"))
    data = json.loads(out.read_text())
    for when in ("before", "after"):
        for key in ("rmse", "mae", "n"):
            assert page.cell(table="before-after", when=when, key=key) == data[when][key]
            assert page.cell(table="sensor-before-after", sensor="s1", when=when, key=key) \
                == data["sensors"]["s1"][when][key]
    added = [e for e in data["effects"] if e["added"]]
    assert added
    assert [(row[1], row[3]) for row in page.effects] == \
        [(e["name"], e["reading"]) for e in added]
    for e in added:
        assert page.cell(table="effects", effect=e["name"], key="gain") == e.get("gain")
    _self_contained(page)
    assert page.provenance["model"] == "apl"
    # the run through each calibration: evaluate's figures
    for heading, cal in (("the run through the calibration diagnosed", CAL),
                         ("the run through it with the terms added", tmp_path / "v2.yaml")):
        assert main(["evaluate", BAG, "--calibration", str(cal), "--json",
                     str(tmp_path / "e.json"), "-q"]) == 0
        record = json.loads((tmp_path / "e.json").read_text())["sensors"]["s1"]
        for key in ("n", "rmse", "r2"):
            assert page.cell(table="scores", bag=heading, sensor="s1", key=key) == record[key]
    assert len(page.images) == 1 + 2 * 4  # the residuals, each run's four plots


def test_a_report_over_an_input_is_refused_before_any_work(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cal = tmp_path / "cal.yaml"
    shutil.copy(CAL, cal)
    before = cal.read_bytes()
    capsys.readouterr()
    assert main(["evaluate", BAG, "--calibration", str(cal), "--report", str(cal)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("strain-comp: error: ")
    assert cal.read_bytes() == before


@pytest.mark.parametrize("unit", ["ohm", "R/R0"])
def test_the_report_gives_the_dead_zone_in_the_input_unit(unit: str) -> None:
    """The calibration's dead zone as the file holds it, per second of the input's unit
    (``input.unit``, ohm when absent), and the valid range in that unit."""
    cal = load_calibration(CAL).sensors["s1"]
    cal = replace(cal, input=replace(cal.input, unit=unit))
    page = Page(provenance_section(Calibration({"s1": cal}), CAL))
    deadzone = float(page.provenance["direction"].split()[2])
    assert deadzone == float(f"{cal.direction.deadzone:.4g}")
    assert page.provenance["direction"].startswith(f"dead zone {deadzone:g} {unit}/s, tau ")
    assert f" {unit}, S " in page.provenance["valid range"]


def test_provenance_is_rounded_and_readable_and_the_tare_said_in_words() -> None:
    cal = load_calibration(CAL).sensors["s1"]
    cal = replace(cal, provenance={**cal.provenance, "fit_rmse": 5.31314532867488,
                                   "options": {"sigma": 0.123456789, "pair": "mean"}})
    page_text = provenance_section(Calibration({"s1": cal}), CAL, tare="calibration")
    page = Page(page_text)
    assert page.provenance["training RMSE"] == "5.313"
    assert page.provenance["options"] == "sigma: 0.1235; pair: mean"
    assert "{" not in page.provenance["input"], page.provenance["input"]
    assert "rest level (tare) from the calibration" in page_text
    assert "tare <code>" not in page_text


def test_plots_say_where_they_show_a_subsample_and_legends_sit_beside_the_data() -> None:
    import numpy as np

    import strain_comp as sc
    from strain_comp.offline.plots import _figure, _finish

    ev = sc.evaluate(CAL, BAG, plot_points=1000).result.sensors["s1"]
    from strain_comp.offline.plots import _title
    assert re.search(r"\(shown: a subsample of \d+ of 14451 samples\)$", _title(ev))
    fig = _figure()
    ax = fig.subplots()
    ax.plot(np.arange(10.0), label="x")
    _finish(ax)
    fig.canvas.draw()
    box = ax.get_legend().get_window_extent()
    assert box.x0 >= ax.get_window_extent().x1  # right of the axes: over no data
