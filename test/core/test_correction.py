"""The one correction (``strain_comp.core.correction``): calibration files written before it
load with the same meaning, and the estimators write the same numbers.

The truth is ``data/old_calibrations.json``, recorded on main at 674a52b (before the
correction) by running, for the bundled calibrations (config/demo_calibration.yaml on
bags/demo_rates.mcap, config/array_calibration.yaml on bags/array.mcap): main's
``recalibrate`` through two points (input form, output form, both; on a calibration with
effect terms too, twice) and ``start`` on the demo bag, then the engine over each bag's
first 3000 samples, untared and tared to 0.97 x the rest. Each case holds the fields main
wrote (``input``, ``effects``) and 12 estimates plus the mean.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, parse_calibration
from strain_comp.core.correction import Correction
from strain_comp.core.engine import Engine
from strain_comp.io.recording import load_recordings
from strain_comp.offline.session_start import recalibrate, steady_output

ROOT = Path(__file__).resolve().parents[2]
CASES: dict[str, Any] = json.loads((Path(__file__).parent / "data" /
                                    "old_calibrations.json").read_text(encoding="utf-8"))
BAGS = {"config/demo_calibration.yaml": "bags/demo_rates.mcap",
        "config/array_calibration.yaml": "bags/array.mcap"}
N, K = 3000, 12
TOL = 1e-9


def _old_file(cfg: str, fields: dict[str, Any]) -> Calibration:
    """The bundled calibration ``cfg`` with the ``input`` and ``effects`` main wrote, read by
    today's loader (JSON is YAML)."""
    node = json.loads(json.dumps(load_calibration(ROOT / cfg).to_dict()))
    for name, written in fields.items():
        node["sensors"][name]["input"] = written["input"]
        node["sensors"][name]["effects"] = written["effects"]
    return parse_calibration(json.dumps(node), cfg)


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_old_file_gives_mains_estimates(case: str) -> None:
    """Every recorded file, untared and tared, within 1e-9 of main's estimates."""
    cfg = case.split("|")[0]
    calibration = _old_file(cfg, CASES[case]["fields"])
    recs = load_recordings(ROOT / BAGS[cfg])[0]
    runs = CASES[case]["runs"]
    for tared in (False, True):
        engine = Engine(calibration)
        for name in CASES[case]["fields"]:
            rest = calibration.sensors[name].input_rest
            if tared and rest is not None:
                engine.tare(name, 0.97 * rest)
            s = engine.run(name, recs[name].t[:N], recs[name].r[:N]).strain
            expected = runs[f"{name}/{'tare' if tared else 'none'}"]
            idx = np.linspace(0, N - 1, K).astype(int)
            np.testing.assert_allclose(s[idx], expected["at"], rtol=TOL, atol=TOL)
            assert abs(float(np.nanmean(s)) - expected["mean"]) <= TOL * max(
                1.0, abs(expected["mean"]))


def test_the_estimators_write_mains_numbers() -> None:
    """``recalibrate`` through two points (input, output, on effect terms, twice) writes
    main's zero_span and coefficients within 1e-9, and the correction reads them as the
    composed maps."""
    cfg = "config/demo_calibration.yaml"
    base = load_calibration(ROOT / cfg)
    cal = base.sensors["s1"]
    vr = cal.valid_range
    r1, r2 = vr.r_lo + 0.2 * (vr.r_hi - vr.r_lo), vr.r_lo + 0.7 * (vr.r_hi - vr.r_lo)
    o1, o2 = steady_output(cal, r1), steady_output(cal, r2)
    terms = [{"name": "rate", "kind": "rate", "params": {"tau": 2.0, "mode": "signed"},
              "coef": 0.4},
             {"name": "memory", "kind": "resistance_memory",
              "params": {"tau": 20.0, "form": "relaxation"}, "coef": -0.03}]
    fx = Calibration({"s1": replace(cal, effects=terms)})
    inputs, outputs = [(r1 * 1.04, o1), (r2 * 1.01, o2)], [(r1, o1 + 0.3), (r2, 1.1 * o2)]
    second = [(r1 * 1.04, o1 - 0.2), (r2 * 1.01, 0.95 * o2)]
    made = {"input_points": recalibrate(base, points=inputs, sensors=["s1"], form="input")[0],
            "output_points": recalibrate(base, points=outputs, sensors=["s1"])[0],
            "effects_output": recalibrate(fx, points=outputs, sensors=["s1"])[0]}
    made["both"] = recalibrate(made["input_points"], points=second, sensors=["s1"])[0]
    made["effects_both_twice"] = recalibrate(
        recalibrate(made["effects_output"], points=inputs, sensors=["s1"], form="input")[0],
        points=second, sensors=["s1"])[0]
    for variant, calibration in made.items():
        old = CASES[f"{cfg}|{variant}"]["fields"]["s1"]
        new = calibration.sensors["s1"]
        span = old["input"].get("zero_span")
        if span is None:
            assert new.input.zero_span is None
        else:
            np.testing.assert_allclose(new.input.zero_span, [span["rest"],
                                       span["rest_calibrated"], span["gain"]], rtol=TOL)
        coefs = {e["name"]: e["coef"] for e in old["effects"]}
        assert {e["name"] for e in new.effects} == set(coefs)
        for e in new.effects:
            assert e["coef"] == pytest.approx(coefs[e["name"]], rel=TOL, abs=TOL)
    # the composed output map of effects_both_twice: main's two steps' gains and offsets
    steps = made["effects_both_twice"].sensors["s1"].provenance["recalibrations"]
    (a1, b1), (a2, b2) = [(r["gain"], r["offset"]) for r in steps if "gain" in r]
    read = Correction.of(made["effects_both_twice"].sensors["s1"])
    assert read.output_gain == pytest.approx(a1 * a2, rel=TOL)
    assert read.output_offset == pytest.approx(a2 * b1 + b2, rel=TOL, abs=TOL)


def test_the_correction_round_trips_its_file_form() -> None:
    """``written`` then ``of`` gives the correction back, and the identity writes nothing."""
    cal = load_calibration(ROOT / "config/demo_calibration.yaml").sensors["s1"]
    assert Correction().written(cal).to_dict() == cal.to_dict()
    made = Correction(10.0, 11.0, 1.2, 0.9, 0.3)
    back = Correction.of(made.written(cal))
    assert back == made
    assert back.apply_input(np.array([10.0, 20.0])).tolist() == pytest.approx([11.0, 23.0])
    assert back.apply_output(2.0) == pytest.approx(2.1)
