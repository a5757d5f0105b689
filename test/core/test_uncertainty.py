"""The standard deviation of every estimate: one number from every path (step, batch,
fused and looped array ticks), equal to the variance model written out by hand, and the
calibration file's ``uncertainty`` field."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import (
    DIRECTION,
    NORM,
    R_HI,
    R_LO,
    S_HI,
    S_LO,
    cubic_cal,
    engine_of,
    make_calibration,
)

from strain_comp.core.calibration import SensorCalibration, ValidRange
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.uncertainty import FEATURES, Uncertainty
from strain_comp.errors import CalibrationError
from strain_comp.models import model_class
from strain_comp.offline.fit import Segment

BAND = Uncertainty.from_weights({"bias": -3.0, "loading": 0.4, "unloading": 0.7, "hold": -0.2,
                                 "outside": 2.0, "elapsed": 0.3, "level": 1.1})


def by_hand(cal: SensorCalibration, engine_row: np.ndarray, t: np.ndarray,
            direction: np.ndarray, ohm: np.ndarray, strain: np.ndarray) -> np.ndarray:
    """The docstring's model over used samples, in plain Python."""
    r_lo, r_hi, s_lo, s_hi = engine_row[:4]
    w = dict(zip(FEATURES, BAND.weights, strict=True))
    out, last, changed = [], None, 0.0
    for ti, d, r, s in zip(t, direction, ohm, strain, strict=True):
        if last is None or d != last:
            last, changed = d, ti
        x = {"bias": 1.0, "loading": float(d > 0), "unloading": float(d < 0),
             "hold": math.log1p(ti - changed),
             "outside": max(r - r_hi, r_lo - r, 0.0) / (r_hi - r_lo),
             "elapsed": math.log1p((ti - t[0]) / 60.0),
             "level": (min(max(s, s_lo), s_hi) - s_lo) / (s_hi - s_lo)}
        out.append(math.exp(0.5 * sum(w[k] * x[k] for k in FEATURES)))
    return np.array(out)


def test_step_and_run_give_the_hand_model() -> None:
    cal = cubic_cal(uncertainty=BAND)
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.005, 0.015, 3000))
    r = 150.0 + 60.0 * np.sin(2 * np.pi * 0.3 * t) + rng.normal(0, 0.3, t.size)
    batch = engine_of(cal).run("s1", t, r)
    stepper = engine_of(cal)
    steps = [stepper.step("s1", ti, ri) for ti, ri in zip(t, r, strict=True)]
    assert batch.std is not None
    np.testing.assert_array_equal([o.std for o in steps], batch.std)
    row = stepper._sensor("s1").limits.row
    expected = by_hand(cal, row, t, batch.direction, batch.resistance, batch.strain)
    outside = (r < row[0]) | (r > row[1])
    assert outside.sum() > 100
    np.testing.assert_allclose(batch.std, expected, rtol=1e-12)


def test_a_bad_sample_holds_the_band_and_none_without_uncertainty() -> None:
    engine = engine_of(cubic_cal(uncertainty=BAND), cubic_cal("plain"))
    good = engine.step("s1", 0.0, 150.0)
    held = engine.step("s1", 0.1, math.nan)
    assert held.std == good.std and math.isfinite(good.std)
    assert math.isnan(engine.step("plain", 0.0, 150.0).std)
    assert engine_of(cubic_cal()).run("s1", np.array([0.0, 0.1]),
                                      np.array([150.0, 151.0])).std is None


@pytest.mark.parametrize("model", ["apl", "lag"])
def test_array_ticks_equal_the_batch(model: str) -> None:
    rng = np.random.default_rng(3)
    t = np.arange(400) * 0.01
    r_true = 150.0 + 40.0 * np.sin(2 * np.pi * 0.5 * t)
    names = ["a", "b", "c"]
    if model == "apl":
        fitted = model_class("apl").fit([Segment(t, r_true, 0.5 * (r_true - R_LO))], NORM,
                                        direction=DIRECTION)
        cals = [SensorCalibration(name=n, model="apl", params=fitted.to_params(),
                                  normalisation=NORM,
                                  valid_range=ValidRange(R_LO, R_HI, S_LO, S_HI),
                                  direction=DIRECTION) for n in names]
    else:
        cals = [cubic_cal(n) for n in names]
    cals = [replace(c, uncertainty=BAND) if i != 1 else c for i, c in enumerate(cals)]
    if model != "apl":  # an effect term: the batch path (the fused tick takes none)
        cals[2] = replace(cals[2], effects=[{"name": "drift", "kind": "elapsed",
                                             "params": {}, "coef": 0.05}])
    r = np.stack([r_true + rng.normal(0, 0.5, t.size) for _ in names], axis=1)
    r[rng.random(r.shape) < 0.05] = np.nan
    r[200:230, 2] += 150.0
    engine = engine_of(*cals, arrays={"arr": names}, gap_reset=0.5)
    assert engine._arrays["arr"].fused == (model == "apl")
    outs = [engine.step_array("arr", ti, ri) for ti, ri in zip(t, r, strict=True)]
    for k, cal in enumerate(cals):
        ref = engine_of(cal, gap_reset=0.5).run(cal.name, t, r[:, k])
        got = np.array([o.std[k] for o in outs])
        if ref.std is None:
            assert np.isnan(got).all()
        else:
            np.testing.assert_allclose(got, ref.std, rtol=1e-12)


def test_the_file_keeps_it_and_old_files_load(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cal = make_calibration()
    old = tmp_path / "old.yaml"
    save_calibration(cal, old)
    assert "uncertainty" not in old.read_text()
    assert load_calibration(old).sensors["left"].uncertainty is None
    banded = replace(cal, sensors={**cal.sensors, "left": replace(cal.sensors["left"],
                                                                  uncertainty=BAND)})
    path = tmp_path / "new.yaml"
    save_calibration(banded, path)
    assert load_calibration(path).sensors["left"].uncertainty == BAND


@pytest.mark.parametrize(("text", "says"), [
    ("uncertainty: {weights: {bias: .nan}}", "finite"),
    ("uncertainty: {weights: {wobble: 1.0}}", "unknown feature"),
    ("uncertainty: {weights: {bias: 1000.0}}", "<= 100"),
    ("uncertainty: {spread: 1}", "unknown key"),
    ("uncertainty: [1, 2]", "mapping"),
])
def test_a_bad_uncertainty_is_one_line(tmp_path, text: str, says: str) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    lines = path.read_text().splitlines()
    at = lines.index("  left:") + 1
    path.write_text("\n".join([*lines[:at], "    " + text, *lines[at:]]) + "\n")
    with pytest.raises(CalibrationError) as err:
        load_calibration(path)
    message = str(err.value)
    assert "\n" not in message and says in message and "uncertainty" in message
