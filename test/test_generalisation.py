"""scripts/generalisation.py on two short rig runs: its pieces against independent truth.

The in-run bound of a pair must be ``evaluate --in-run-bound``'s number (a fit through
``fit_sensor`` on the recording, not the script's cached bag fit), a pair's ratio the RMSE
of ``evaluate`` over that bound, and the first cycle of a triangle the time of its first
return to rest.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from strain_comp.offline.evaluate import evaluate_recordings, in_run_bound

ROOT = Path(__file__).resolve().parents[1]


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("strain_comp_generalisation",
                                                  ROOT / "scripts" / "generalisation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_first_cycle_of_a_triangle() -> None:
    gen = _script()
    t = np.arange(0.0, 100.0, 0.1)
    s = np.interp(t % 20.0, [0.0, 5.0, 15.0, 20.0], [0.0, 0.0, 30.0, 0.0])
    # above half the span at t = 10 s, back below 10 % of it (3 %) at 20 - 0.5 s
    assert gen.first_cycle(t, s) == pytest.approx(19.5, abs=0.15)
    assert gen.first_cycle(t, np.linspace(0, 1, t.size)) == pytest.approx(0.4 * t[-1])


def test_weighted_median_counts_each_sensor_once() -> None:
    gen = _script()
    values = np.array([1.0, 1.0, 1.0, 5.0, 6.0])  # sensor A's three pairs, B's, C's
    assert gen.weighted_median(values, np.array([1 / 3, 1 / 3, 1 / 3, 1.0, 1.0])) == 5.0
    assert gen.weighted_median(values, np.ones(5)) == 1.0


def test_pairs_of_two_rig_runs(tmp_path: Path) -> None:
    gen = _script()
    runs = (gen.Run("triangle", "rig:triangle"), gen.Run("steps", "rig:steps"))
    sensor = gen.Sensor("rig", runs)
    bench = gen.Bench(tmp_path, tmp_path / "out", log=lambda line: None)
    pairs = gen.run_benchmark(bench, [sensor], ["cubic"])
    assert [(p.train, p.test) for p in pairs] == [("triangle", "steps"), ("steps", "triangle")]
    for pair in pairs:
        label = {r.label: r for r in runs}
        test = bench.recording(sensor, label[pair.test])
        cal = bench.fit(sensor, label[pair.train], "cubic")
        result = evaluate_recordings({"s1": test}, cal)
        in_run_bound(result, {"s1": test}, cal)
        ev = result.sensors["s1"]
        assert pair.in_run == pytest.approx(ev.in_run_rmse, rel=1e-9)
        assert pair.ratio("plain") == pytest.approx(ev.stats.rmse / ev.in_run_rmse, rel=1e-9)
        assert set(pair.rmse) == set(gen.WORKFLOWS)
    table = gen.summary(pairs, "plain")["cubic"]
    assert table["overall"]["worst"] == max(p.ratio("plain") for p in pairs)
