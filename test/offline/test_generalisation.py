"""scripts/generalisation.py on two short rig runs: its pieces against independent truth.

The in-run bound of a case must be a fit through ``fit_sensor`` on the recording (not the
script's cached bag fit), its ratio the RMSE of ``evaluate`` over the lowest bound of any
model, leaving one of two runs out the pair's case, two worker processes (``--jobs``) the
serial run's cases, and the first and second cycles of a triangle the times of its first
and second returns to rest.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from strain_comp.core.calibration import Calibration
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor

ROOT = Path(__file__).resolve().parents[2]


def _script() -> ModuleType:
    """The script as the module ``generalisation`` (as its worker processes import it)."""
    if str(ROOT / "scripts") not in sys.path:
        sys.path.insert(0, str(ROOT / "scripts"))
    return importlib.import_module("generalisation")


def test_weighted_median_counts_each_sensor_once() -> None:
    gen = _script()
    values = np.array([1.0, 1.0, 1.0, 5.0, 6.0])  # sensor A's three pairs, B's, C's
    assert gen.weighted_median(values, np.array([1 / 3, 1 / 3, 1 / 3, 1.0, 1.0])) == 5.0
    assert gen.weighted_median(values, np.ones(5)) == 1.0


def test_the_stretches_of_a_triangle() -> None:
    """The benchmark's ``first`` and ``warmup`` read the stretches ``strain-comp start``
    finds: the first stretch and return, then the next one."""
    from strain_comp.offline.session_start import stretch_of

    t = np.arange(0.0, 100.0, 0.1)
    s = np.interp(t % 20.0, [0.0, 5.0, 15.0, 20.0], [0.0, 0.0, 30.0, 0.0])
    # above half the span at t = 10 s, back below 10 % of it (3 %) at 20 - 0.5 s
    first, second = stretch_of(t, s, 30.0, "run")
    assert first == pytest.approx((0.0, 19.5), abs=0.15)
    assert second == pytest.approx((19.5, 39.5), abs=0.15)


def test_cases_of_two_rig_runs(tmp_path: Path) -> None:
    gen = _script()
    runs = (gen.Run("triangle", "rig:triangle"), gen.Run("steps", "rig:steps"))
    sensor = gen.Sensor("rig", runs)
    bench = gen.Bench(tmp_path, tmp_path / "out", log=lambda line: None)
    cases = gen.run_benchmark(bench, [sensor], ["cubic", "rational"])
    pairs = [c for c in cases if c.scheme == "pair" and c.model == "cubic"]
    assert [(c.train, c.test) for c in pairs] == [("steps", "triangle"), ("triangle", "steps")]
    label = {r.label: r for r in runs}
    for case in pairs:
        test = bench.recording(sensor, label[case.test])
        bounds = []
        for model in ("cubic", "rational"):  # every model's own fit on the test run
            own = fit_sensor([test], model, name="s1")
            bounds.append(evaluate_recordings({"s1": test}, Calibration({"s1": own}))
                          .sensors["s1"].stats.rmse)
        assert case.in_run == pytest.approx(bounds[0], rel=1e-6)
        assert case.best_in_run == pytest.approx(min(bounds), rel=1e-6)
        cal = bench.fit(sensor, label[case.train], "cubic")
        tared = evaluate_recordings({"s1": test}, cal, tare="auto").sensors["s1"].stats.rmse
        assert case.rmse["as_is"] == pytest.approx(tared, rel=1e-9)
        assert case.ratio("as_is") == pytest.approx(tared / min(bounds), rel=1e-6)
        assert set(case.rmse) == set(gen.WORKFLOWS)
        # with two runs, leaving one out trains on the other: the pair's fit and errors
        loro = next(c for c in cases if c.scheme == "loro" and c.model == "cubic"
                    and c.test == case.test)
        assert loro.rmse == case.rmse
    # two worker processes, one model each, give the same cases
    parallel = gen.run_parallel(bench, [sensor], ["cubic", "rational"], 2)
    assert [(c.model, c.scheme, c.train, c.test, c.in_run, c.best_in_run, c.rmse)
            for c in parallel] == [(c.model, c.scheme, c.train, c.test, c.in_run,
                                    c.best_in_run, c.rmse) for c in cases]
    table = gen.summary(cases, "pair", "as_is")["cubic"]
    assert table["overall"]["ratio_worst"] == max(c.ratio("as_is") for c in pairs)
    assert table["rig"]["worst"] == max(c.rmse["as_is"] for c in pairs)
