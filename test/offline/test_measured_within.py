"""The within-run tables of studies/measured.py: the residual loop is chosen on the training
part alone, and what it adds is scored on the rest against the reference strain."""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np

from strain_comp.io.recording import Recording
from strain_comp.offline.rig import simulate

SCRIPT = Path(__file__).resolve().parents[2] / "studies" / "measured.py"


@functools.cache
def measured() -> ModuleType:
    spec = importlib.util.spec_from_file_location("measured_script", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.cache
def steps_recording() -> Recording:
    """300 s of the rig's 0-40 % steps with 30 s holds (relaxation after each step)."""
    return simulate("steps", seed=3, duration=300.0)["s1"]


def _tail_changed(rec: Recording) -> Recording:
    """The same run with resistance and reference changed after the training cut."""
    m = measured()
    cut = rec.t[0] + m.WITHIN_FIT * (rec.t[-1] - rec.t[0])
    tail = rec.t > cut
    assert rec.s is not None
    return dataclasses.replace(rec, r=np.where(tail, 1.05 * rec.r, rec.r),
                               s=np.where(tail, rec.s + 3.0, rec.s))


def test_loop_decides_on_the_training_part_alone() -> None:
    m = measured()
    rec = steps_recording()
    failures: list[str] = []
    plain, looped = m.within_run({"steps.csv": {"s1": rec}}, ["cubic"], failures)
    plain_b, looped_b = m.within_run({"steps.csv": {"s1": _tail_changed(rec)}}, ["cubic"],
                                     failures)
    assert failures == []
    first, second = looped["steps"]["cubic"], looped_b["steps"]["cubic"]
    assert first["added"], "the rig's relaxation after each step should be found"
    assert [(a["name"], a["coef"]) for a in first["added"]] \
        == [(a["name"], a["coef"]) for a in second["added"]]
    assert (first["loop_before"], first["loop_after"]) \
        == (second["loop_before"], second["loop_after"])
    assert first["condition"] == second["condition"]
    # the scored part did change, so the equal decisions are not an accident of scoring
    assert plain["steps"]["cubic"] != plain_b["steps"]["cubic"]
    assert first["rmse"] != second["rmse"]


def test_loop_terms_lower_the_error_on_the_scored_part() -> None:
    m = measured()
    plain, looped = m.within_run({"steps.csv": {"s1": steps_recording()}}, ["cubic"], [])
    added = looped["steps"]["cubic"]["added"]
    assert any(a["kind"] == "relaxation" for a in added)
    assert looped["steps"]["cubic"]["rmse"] < 0.8 * plain["steps"]["cubic"]


def test_target_table_compares_the_best_memory_model_to_the_cubic() -> None:
    m = measured()
    within = {"v10": {"cubic": 10.0, "mpi": 9.0, "apl": 8.5},
              "v9": {"cubic": 5.0, "spike_decay": 3.0, "rational": 1.0}}
    looped = {"v10": {name: {"rmse": value, "added": [], "condition": "as calibrated",
                             "top_score": {"name": "offset", "score": 0.0},
                             "offset_score": 0.0, "loop_before": 1.0, "loop_after": 1.0,
                             "message": ""}
                      for name, value in {"cubic": 6.0, "mpi": 7.9, "apl": 9.0}.items()},
              "v9": {name: {"rmse": value, "added": [{"name": "offset", "reading": "x"}],
                            "condition": "as calibrated", "loop_before": 1.0,
                            "loop_after": 0.5, "message": ""}
                     for name, value in {"cubic": 5.0, "spike_decay": 3.0}.items()}}
    text = m.loop_markdown(within, looped)
    # v9: 3 / 5 = 0.60 in every column; rational is not a memory model
    assert "| v9 | spike_decay 3.000 / cubic 5.000 = 0.60 met |" in text
    # v10: apl 8.5 / 10 = 0.85 without; mpi 7.9 / 10 = 0.79 with; 7.9 / 6.0 = 1.32 with both
    assert "| v10 | apl 8.500 / cubic 10.000 = 0.85 not met | mpi 7.900 / cubic 10.000 " \
        "= 0.79 met | mpi 7.900 / cubic 6.000 = 1.32 not met |" in text
    assert "met on 1 of 2 / 2 of 2 / 1 of 2 files" in text
