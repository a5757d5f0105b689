"""docs/api.md runs as written: every ``python`` block is a doctest, from the repository's
root, in one namespace (as a notebook runs its cells). Blocks after the marker
``<!-- needs ../shared/data/measured -->`` need the measured recordings: skipped without
them."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "api.md"
MEASURED_MARK = "<!-- needs ../shared/data/measured -->"
BLOCK = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)


def _blocks(text: str) -> tuple[list[str], list[str]]:
    """The python blocks before the measured-data marker, and those after it."""
    head, _, tail = text.partition(MEASURED_MARK)
    return BLOCK.findall(head), BLOCK.findall(tail)


def _run(blocks: list[str], globs: dict[str, object], name: str) -> dict[str, object]:
    """Run ``blocks`` as one doctest in ``globs``; the namespace after them."""
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    test = parser.get_doctest("\n".join(blocks), globs, name, str(DOC), 0)
    report: list[str] = []
    runner.run(test, out=report.append, clear_globs=False)
    assert runner.failures == 0, "".join(report)
    return test.globs


def test_api_walkthrough_runs_as_written(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    general, measured = _blocks(DOC.read_text(encoding="utf-8"))
    assert len(general) >= 6 and measured
    globs = _run(general, {}, "api.md")
    if not (ROOT / "../shared/data/measured").is_dir():
        pytest.skip("the measured recordings (../shared/data/measured) are not here")
    _run(measured, globs, "api.md, measured")
