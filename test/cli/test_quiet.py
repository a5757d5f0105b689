"""``--quiet`` is quiet in every command: nothing on stderr when nothing fails."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from strain_comp.cli import main
from strain_comp.models import apl_fit

ROOT = Path(__file__).resolve().parents[2]


class _SlowClock:
    """The time module with a monotonic clock 10 s further at each reading: every fit
    looks long enough for its progress lines."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        self.now += 10.0
        return self.now

    def __getattr__(self, name: str) -> object:
        return getattr(time, name)


def test_evaluate_in_run_bound_quiet_prints_no_fit_progress(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """The in-run bound refits the APL calibration on the run (made to look long: its grid
    lines would show); with ``-q`` stderr stays empty and the table is on stdout."""
    monkeypatch.setattr(apl_fit, "time", _SlowClock())
    assert main(["evaluate", str(ROOT / "bags" / "steps.mcap"), "--calibration",
                 str(ROOT / "config" / "demo_calibration.yaml"), "--in-run-bound", "-q"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and "RMSE" in out
