"""The engine: batch equals streaming, bad samples held and counted, gaps, ranges, arrays.

Truth here is (a) the engine's own streaming path for the batch path, and (b) a fresh
model and detector fed only the good samples, for "bad samples never reach the model".
A first-order lag model (``conftest.Lag``) gives the engine a compensator with memory
(the cubic has none), so a poisoned or missing reset would show.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import (
    DIRECTION,
    NORM,
    R_HI,
    R_LO,
    S_HI,
    S_LO,
    Lag,
    cubic_cal,
    engine_of,
    lag_cal,
    noisy_stream,
)

from strain_comp.base.compensator import Segment
from strain_comp.base.direction import DirectionDetector
from strain_comp.base.samples import Status
from strain_comp.core.calibration import (
    Calibration,
    InputSettings,
    SensorCalibration,
    ValidRange,
)
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import MARGIN, SETTLE_STEPS
from strain_comp.errors import ParameterError

CONFIG = Path(__file__).resolve().parents[2] / "config"

def stream(engine: Engine, sensor: str, t: np.ndarray, r: np.ndarray) -> dict[str, np.ndarray]:
    outs = [engine.step(sensor, ti, ri) for ti, ri in zip(t, r, strict=True)]
    return {"strain": np.array([o.strain for o in outs]),
            "direction": np.array([o.direction for o in outs]),
            "status": np.array([o.status for o in outs]),
            "out_of_range": np.array([o.out_of_range for o in outs])}


def assert_same(batch: Any, ref: dict[str, np.ndarray]) -> None:
    np.testing.assert_allclose(batch.strain, ref["strain"], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(batch.direction, ref["direction"])
    np.testing.assert_array_equal(batch.status, ref["status"])
    np.testing.assert_array_equal(batch.out_of_range, ref["out_of_range"])


@pytest.mark.parametrize("make_cal", [cubic_cal, lag_cal])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_batch_in_pieces_continues_where_the_last_one_stopped(make_cal: Any,
                                                                seed: int) -> None:
    """What a bag read piece by piece and the node (pieces of one) rely on."""
    t, r = noisy_stream(np.random.default_rng(seed))
    ref_engine = engine_of(make_cal())
    whole = ref_engine.run("s1", t, r)
    ref = {f: getattr(whole, f) for f in ("strain", "direction", "status", "out_of_range")}
    assert set(np.unique(ref["status"])) >= {1, 2, 4, 5, 7}
    chunked = engine_of(make_cal())
    cut = len(t) // 3
    parts = [chunked.run("s1", t[a:b], r[a:b]) for a, b in ((0, cut), (cut, cut + 1),
                                                           (cut + 1, len(t)))]
    assert_same(type(parts[0])(*(np.concatenate([getattr(p, f) for p in parts])
                                 for f in ("strain", "direction", "status", "out_of_range",
                                           "resistance"))),
                ref)
    assert chunked.health() == ref_engine.health()
    assert_same(whole, stream(engine_of(make_cal()), "s1", t, r))  # pieces of one: step



@pytest.mark.parametrize("alternating", [False, True])
def test_batch_reads_but_never_writes_its_input(alternating: bool) -> None:
    """Read-only input (a bag reader's buffers) gives what writable copies give, and the
    caller's arrays are left as they were, whatever segments the gaps cut."""
    t, r = noisy_stream(np.random.default_rng(5))
    cal = lag_cal(input=InputSettings(alternation=alternating))
    t_ro, r_ro = t.copy(), r.copy()
    t_ro.flags.writeable = r_ro.flags.writeable = False
    ref = engine_of(cal).run("s1", t.copy(), r.copy())
    got = engine_of(cal).run("s1", t_ro, r_ro)
    for f in ("strain", "direction", "status", "out_of_range"):
        np.testing.assert_array_equal(getattr(got, f), getattr(ref, f))
    np.testing.assert_array_equal(r_ro, r)
    np.testing.assert_array_equal(t_ro, t)

def test_bad_samples_counted_held_and_never_reach_the_model() -> None:
    t = np.arange(12) * 0.01
    r = np.array([150.0, np.nan, 152.0, np.inf, -3.0, 0.0, 1e6, 0.2, 154.0, 156.0, 158.0, 160.0])
    t[9] = t[8] - 0.001  # time going back a little
    engine = engine_of(lag_cal())
    out = stream(engine, "s1", t, r)
    expected = [Status.GOOD, Status.NOT_FINITE, Status.GOOD, Status.NOT_FINITE,
                Status.NON_POSITIVE, Status.NON_POSITIVE, Status.OPEN_CIRCUIT,
                Status.SHORT_CIRCUIT, Status.GOOD, Status.TIME_NOT_INCREASING, Status.GOOD,
                Status.GOOD]
    assert out["status"].tolist() == expected
    good = np.array([s == Status.GOOD for s in expected])
    model, detector = Lag(), DirectionDetector(DIRECTION)
    truth = model.run(t[good], r[good])
    truth_dir = detector.run(t[good], r[good])
    np.testing.assert_allclose(out["strain"][good], truth, rtol=1e-14)
    np.testing.assert_array_equal(out["direction"][good], truth_dir)
    held = np.maximum.accumulate(np.where(good, np.arange(12), 0))
    np.testing.assert_array_equal(out["strain"], out["strain"][held])
    h = engine.health()["s1"]
    assert (h.n_good, h.n_nan, h.n_non_positive, h.n_open, h.n_short, h.n_time_backwards) == (
        5, 2, 2, 1, 1, 1)
    assert h.last_good_t == t[11] and h.n_gaps == 0 and h.n_out_of_range == 0


def test_nothing_before_the_first_good_sample_is_held_as_nan() -> None:
    engine = engine_of(cubic_cal())
    out = engine.step("s1", 0.0, math.nan)
    assert math.isnan(out.strain) and out.direction == 0 and out.status is Status.NOT_FINITE
    batch = engine_of(cubic_cal()).run("s1", [0.0, 0.1], [np.nan, -1.0])
    assert np.isnan(batch.strain).all() and (batch.direction == 0).all()


@pytest.mark.parametrize("jump", [6.0, -30.0])
def test_long_gap_or_clock_reset_restarts_the_state(jump: float) -> None:
    t = np.concatenate([np.arange(50) * 0.01, 0.5 + jump + np.arange(50) * 0.01])
    r = 150.0 + 30.0 * np.sin(7.0 * np.arange(100) * 0.01)
    slow = lag_cal(params={"tau": 30.0})
    engine = engine_of(slow, gap_reset=5.0)
    out = engine.run("s1", t, r)
    assert out.status[50] == Status.GAP_RESET and engine.health()["s1"].n_gaps == 1
    np.testing.assert_allclose(out.strain[50:], Lag(30.0).run(t[50:], r[50:]), rtol=1e-14)
    np.testing.assert_array_equal(out.direction[50:],
                                  DirectionDetector(DIRECTION).run(t[50:], r[50:]))
    no_reset = engine_of(slow, gap_reset=100.0).run("s1", t, r)
    if jump > 0:  # without the reset, the lag would have carried over
        assert not np.allclose(no_reset.strain[50:], out.strain[50:])
    else:  # a clock going back less than gap_reset: every later sample is rejected
        assert (no_reset.status[50:] == Status.TIME_NOT_INCREASING).all()


def test_out_of_range_is_flagged_fed_and_clamped() -> None:
    margin_r = MARGIN * (R_HI - R_LO)
    s_top = S_HI + MARGIN * (S_HI - S_LO)
    t = np.arange(4) * 0.1
    r = np.array([150.0, R_HI + 0.5 * margin_r, R_HI + 2 * margin_r, 400.0])
    engine = engine_of(lag_cal(), out_of_range="clamp")
    out = stream(engine, "s1", t, r)
    assert out["out_of_range"].tolist() == [False, False, True, True]
    assert out["status"].tolist() == [Status.GOOD, Status.GOOD, Status.OUT_OF_RANGE,
                                      Status.OUT_OF_RANGE]
    truth = Lag().run(t, r)  # the model saw every sample, out of range ones included
    np.testing.assert_allclose(out["strain"], np.minimum(truth, s_top), rtol=1e-14)
    assert out["strain"][3] == s_top
    assert engine.health()["s1"].n_out_of_range == 2


def test_divider_input_converted_and_screened() -> None:
    r1, vin = 150.0, 3.3
    cal = cubic_cal(input=InputSettings("divider", r1=r1, vin=vin))
    r = np.array([120.0, 160.0, 180.0])
    v = vin * r1 / (r1 + r)
    raw = np.array([v[0], 0.0, v[1], vin, -0.1, v[2], np.nan])
    t = np.arange(raw.size) * 0.01
    out = engine_of(cal).run("s1", t, raw)
    assert out.status.tolist() == [Status.GOOD, Status.OPEN_CIRCUIT, Status.GOOD,
                                   Status.SHORT_CIRCUIT, Status.OPEN_CIRCUIT, Status.GOOD,
                                   Status.NOT_FINITE]
    direct = engine_of(cubic_cal()).run("s1", t[[0, 2, 5]], r)
    np.testing.assert_allclose(out.strain[[0, 2, 5]], direct.strain, rtol=1e-12)
    assert_same(engine_of(cal).run("s1", t, raw), stream(engine_of(cal), "s1", t, raw))


def test_array_path_equals_per_sensor_path() -> None:
    rng = np.random.default_rng(5)
    names = ["a", "b", "c"]
    cals = [lag_cal(n) for n in names]
    streams = [noisy_stream(np.random.default_rng(10 + i)) for i in range(3)]
    t = streams[0][0]
    r = np.stack([s[1] for s in streams], axis=1)
    r[rng.random(r.shape) < 0.05] = np.nan
    array_engine = engine_of(*cals, arrays={"arr": names})
    outs = [array_engine.step_array("arr", ti, ri) for ti, ri in zip(t, r, strict=True)]
    for k, name in enumerate(names):
        ref = engine_of(lag_cal(name))
        expected = stream(ref, name, t, r[:, k])
        np.testing.assert_allclose([o.strain[k] for o in outs], expected["strain"], rtol=1e-14)
        assert [o.status[k] for o in outs] == expected["status"].tolist()
        assert [o.direction[k] for o in outs] == expected["direction"].tolist()
        assert array_engine.health()[name] == ref.health()[name]


def test_apl_array_is_one_kernel_and_equals_per_sensor() -> None:
    from strain_comp.models import model_class

    rng = np.random.default_rng(3)
    t = np.arange(400) * 0.01
    r_true = 150.0 + 40.0 * np.sin(2 * np.pi * 0.5 * t)
    s_true = 0.5 * (r_true - R_LO)
    model = model_class("apl").fit([Segment(t, r_true, s_true)], NORM, direction=DIRECTION)
    names = ["a", "b", "c", "d"]
    cals = [SensorCalibration(name=n, model="apl", params=model.to_params(), normalisation=NORM,
                              valid_range=ValidRange(R_LO, R_HI, S_LO, S_HI),
                              direction=DIRECTION) for n in names]
    r = np.stack([r_true + rng.normal(0, 0.5, t.size) for _ in names], axis=1)
    r[rng.random(r.shape) < 0.05] = np.nan
    r[200:230, 1] += 150.0  # out of range on one sensor only
    r[250:320, 2] = np.nan  # a long outage on one sensor: it alone gets reset
    engine = engine_of(*cals, arrays={"arr": names}, gap_reset=0.5)
    assert engine._arrays["arr"].fused
    outs = [engine.step_array("arr", ti, ri) for ti, ri in zip(t, r, strict=True)]
    for k, name in enumerate(names):
        ref_engine = engine_of(cals[k], gap_reset=0.5)
        ref = ref_engine.run(name, t, r[:, k])
        np.testing.assert_allclose([o.strain[k] for o in outs], ref.strain, rtol=1e-9,
                                   atol=1e-9)
        assert [o.status[k] for o in outs] == ref.status.tolist()
        assert [o.direction[k] for o in outs] == ref.direction.tolist()
        assert engine.health()[name] == ref_engine.health()[name]
    assert engine.health()["c"].n_gaps == 1 and engine.health()["b"].n_out_of_range > 0


def test_health_levels_and_stale() -> None:
    engine = engine_of(cubic_cal("a"), cubic_cal("b"), stale_after=1.0)
    assert engine.health(now=0.0)["a"].to_diagnostic()[0] == 3  # never a sample: stale
    engine.step("a", 10.0, 150.0)
    engine.step("b", 10.0, 150.0)
    engine.step("b", 10.1, math.nan)
    health = engine.health(now=10.5)
    level_a, message_a, values_a = health["a"].to_diagnostic()
    level_b, message_b, values_b = health["b"].to_diagnostic()
    assert (level_a, message_a) == (0, "ok") and values_a["n_good"] == "1"
    assert level_b == 2 and "not_finite" in message_b and values_b["n_nan"] == "1"
    assert engine.health(now=11.5)["a"].to_diagnostic()[0] == 3
    engine.step("a", 11.6, 1000.0)
    assert engine.health(now=11.7)["a"].to_diagnostic()[0] == 1  # out of range
    engine.reset()


def test_deadzone_scale_and_errors() -> None:
    t = np.arange(100) * 0.01
    r = 150.0 + 0.15 * np.arange(100)  # 15 ohm/s: inside a dead zone of 20, outside 2*0.5*...
    engine = engine_of(cubic_cal())
    assert (engine.run("s1", t, r).direction == 0).all()
    engine.set_deadzone_scale(0.1)
    assert engine.run("s1", t + 1.0, r).direction[-1] == 1
    from strain_comp.errors import InputError, ParameterError

    with pytest.raises(InputError, match="unknown sensor"):
        engine.step("nope", 0.0, 1.0)
    with pytest.raises(InputError, match="not in the calibration"):
        engine_of(cubic_cal(), arrays={"arr": ["s1", "x"]})
    with pytest.raises(ParameterError, match="gap_reset"):
        engine_of(cubic_cal(), gap_reset=0.0)


def test_warm_up_leaves_the_engine_untouched() -> None:
    engine = engine_of(cubic_cal("a"), lag_cal("b"), arrays={"arr": ["a", "b"]})
    engine.warm_up()
    assert all(h.n_good == 0 for h in engine.health().values())


def test_input_gain_scales_what_the_model_sees_in_every_path() -> None:
    """A tare gain g: step, run and a fresh engine fed g x R agree; reset keeps the gain."""
    cal = Calibration({"s1": cubic_cal()})
    vr = cal.sensors["s1"].valid_range
    t = np.linspace(0.0, 10.0, 200)
    r = np.linspace(vr.r_lo, vr.r_hi, 200) / 1.1
    tared = Engine(cal)
    tared.set_input_gain("s1", 1.1)
    reference = Engine(cal).run("s1", t, r * 1.1).strain
    np.testing.assert_allclose(tared.run("s1", t, r).strain, reference, rtol=0, atol=1e-12)
    tared.reset()
    assert tared.input_gain("s1") == 1.1
    stepped = [tared.step("s1", ti, ri).strain for ti, ri in zip(t, r, strict=True)]
    np.testing.assert_allclose(stepped, reference, rtol=0, atol=1e-12)
    with pytest.raises(ParameterError):
        tared.set_input_gain("s1", 0.0)


def test_input_gain_in_the_array_kernel_path() -> None:
    """The fused array tick scales by each sensor's gain like the single-sensor path."""
    cal = load_calibration(CONFIG / "array_calibration.yaml")
    names = list(cal.sensors)
    gains = np.linspace(0.9, 1.1, len(names))
    tared = Engine(cal, arrays={"arr": names})
    plain = Engine(cal, arrays={"arr": names})
    for name, g in zip(names, gains, strict=True):
        tared.set_input_gain(name, float(g))
    mid = np.array([0.5 * (cal.sensors[n].valid_range.r_lo + cal.sensors[n].valid_range.r_hi)
                    for n in names])
    for k in range(50):
        r = mid * (1.0 + 0.1 * np.sin(0.2 * k))
        a = tared.step_array("arr", 0.01 * k, r / gains)
        b = plain.step_array("arr", 0.01 * k, r)
        np.testing.assert_allclose(a.strain, b.strain, rtol=0, atol=1e-9)


def test_tare_uses_the_calibrations_rest_resistance() -> None:
    """Tare at R_now: gain = rest_resistance / R_now; refused without a stored rest value."""
    engine = Engine(Calibration({"s1": cubic_cal(rest_resistance=200.0)}))
    assert engine.tare("s1", 250.0) == pytest.approx(0.8)
    assert engine.input_gain("s1") == pytest.approx(0.8)
    with pytest.raises(ParameterError, match="finite"):
        engine.tare("s1", math.nan)
    assert engine.input_gain("s1") == pytest.approx(0.8)
    with pytest.raises(ParameterError, match="rest_resistance"):
        Engine(Calibration({"s1": cubic_cal()})).tare("s1", 250.0)


def test_extrapolate_extends_the_end_slope_beyond_the_range() -> None:
    cal = cubic_cal()
    r_hi = R_HI + MARGIN * (R_HI - R_LO)  # the flag's edge
    width = (r_hi - (R_LO - MARGIN * (R_HI - R_LO))) / SETTLE_STEPS  # one step
    inside = engine_of(cal).run("s1", [0.0, 1.0], [r_hi - width, r_hi]).strain
    slope = (inside[1] - inside[0]) / width
    t = np.arange(5) * 0.1
    r = np.array([150.0, r_hi + 10.0, r_hi + 40.0, 150.0, R_LO * 0.5])
    clamped = engine_of(cal, out_of_range="clamp").run("s1", t, r)
    extended = engine_of(cal, out_of_range="extrapolate").run("s1", t, r)
    np.testing.assert_allclose(extended.strain[[0, 3]], clamped.strain[[0, 3]])
    np.testing.assert_allclose(extended.strain[1:3], clamped.strain[1:3] + slope
                               * np.array([10.0, 40.0]), rtol=1e-9)
    assert extended.strain[4] < clamped.strain[4]
    assert list(extended.out_of_range) == list(clamped.out_of_range) == [False, True, True,
                                                                         False, True]
