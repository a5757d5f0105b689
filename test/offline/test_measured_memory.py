"""studies/measured_memory.py --effect: the term fitted is the one the engine runs online."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np

from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration
from strain_comp.core.effects import Batch, regressor_from_dict
from strain_comp.core.engine import Engine
from strain_comp.diagnosis.candidates import default_candidates
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.rig import simulate

SCRIPT = Path(__file__).resolve().parents[2] / "studies" / "measured_memory.py"


def test_effect_fit_is_least_squares_on_the_online_term_across_reference_gaps() -> None:
    """A run whose reference is missing for 40 s while the resistance moves: the fitted
    intercept and term leave an online residual orthogonal to both over the referenced
    samples (the term's state runs through the gap, as in the engine)."""
    spec = importlib.util.spec_from_file_location("measured_memory_script", SCRIPT)
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    sensor = next(iter(simulate("steps", seed=3, duration=300.0).values()))
    s = np.where((sensor.t > 100.0) & (sensor.t < 140.0), np.nan, sensor.s)
    rec = Recording("s1", sensor.t, sensor.r, s)
    name = "resistance_relaxation_tau16"
    cal = script.with_effects(fit_sensor([rec], "cubic", name="s1"), [rec], [name])
    plain = Engine(Calibration({"s1": dataclasses.replace(cal, effects=[])}))
    base = plain.run("s1", rec.t, rec.r)
    used = used_mask(base.status)
    term = {c["name"]: c for c in default_candidates()}[name]
    g = regressor_from_dict(term).run(Batch.of(rec.t[used], base.resistance[used],
                                               base.strain[used], base.direction[used]))
    corrected = Engine(Calibration({"s1": cal})).run("s1", rec.t, rec.r).strain[used]
    ok = np.isfinite(s[used])
    residual = (corrected - s[used])[ok]
    assert np.std(g[ok]) > 0.1
    assert abs(np.mean(residual)) < 1e-9 * np.std(residual) + 1e-12
    assert abs(np.dot(residual, g[ok] - g[ok].mean())) < 1e-9 * len(residual) * np.std(g[ok])
