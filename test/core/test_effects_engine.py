"""Effect terms inside the engine: cross-talk with the same tick's neighbours (replay equals
the node's ``step_array``), effect state reset at gap resets, and the published direction
sign of a sensor whose resistance falls with strain."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import DIRECTION, NORM, R_LO, S_HI, S_LO, cubic_cal, engine_of

from strain_comp.base.direction import DirectionSettings
from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.effects import Batch, regressor_from_dict
from strain_comp.core.range_policy import MARGIN
from strain_comp.errors import CalibrationError, ParameterError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.recording import Recording
from strain_comp.models import Segment, model_class
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.replay import replay_bag

NAMES = ["a", "b", "c"]


def crosstalk(neighbours: list[str], coef: float = 0.2) -> list[dict]:
    return [{"name": f"ct_{n}", "kind": "crosstalk", "params": {"neighbour": n}, "coef": coef}
            for n in neighbours] + [{"name": "offset", "kind": "offset", "params": {},
                                     "coef": 0.1}]


def array_stream(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Three sensors with their own motion, some bad samples and a long outage on one."""
    rng = np.random.default_rng(11)
    t = 100.0 + np.arange(n) * 0.02
    r = np.stack([150 + 30 * np.sin(t * (1 + k) + k) + rng.normal(0, 0.3, n)
                  for k in range(len(NAMES))], axis=1)
    r[rng.random(r.shape) < 0.03] = np.nan
    r[150:220, 1] = np.nan  # 1.4 s without sensor b: a gap reset with gap_reset=1
    return t, r


def apl_cals(effects: dict[str, list[dict]]) -> list[SensorCalibration]:
    t = np.arange(400) * 0.01
    r_true = 150.0 + 40.0 * np.sin(2 * np.pi * 0.5 * t)
    model = model_class("apl").fit([Segment(t, r_true, 0.5 * (r_true - R_LO))], NORM,
                                   direction=DIRECTION, N=3, M=3, sigma_grid=[1.0],
                                   p_grid=[1.0], refine=False, progress=False)
    base = cubic_cal("x")
    return [replace(base, name=n, model="apl", params=model.to_params(),
                    effects=effects.get(n, [])) for n in NAMES]


def creep_cals(effects: dict[str, list[dict]]) -> list[SensorCalibration]:
    t = np.arange(400) * 0.01
    r_true = 150.0 + 40.0 * np.sin(2 * np.pi * 0.5 * t)
    model = model_class("creep_pi").fit([Segment(t, r_true, 0.5 * (r_true - R_LO))], NORM,
                                        direction=DIRECTION, taus=[0.3, 3.0], n_play=3)
    base = cubic_cal("x")
    return [replace(base, name=n, model="creep_pi", params=model.to_params(),
                    effects=effects.get(n, [])) for n in NAMES]


@pytest.mark.parametrize("family", ["cubic", "apl", "creep_pi"])
def test_array_crosstalk_replay_equals_step_array(tmp_path: Path, family: str) -> None:
    effects = {"a": crosstalk(["b"]), "b": crosstalk(["a", "c"], -0.3), "c": crosstalk(["b"])}
    cals = ([cubic_cal(n, effects=effects[n]) for n in NAMES] if family == "cubic"
            else apl_cals(effects) if family == "apl" else creep_cals(effects))
    t, r = array_stream()
    with BagWriter(tmp_path / "in.mcap") as writer:
        writer.write_float64_array("/arr/resistance", t, r, NAMES)
    calibration = Calibration({c.name: c for c in cals})
    replay_bag(tmp_path / "in.mcap", calibration, tmp_path / "out.mcap", gap_reset=1.0)
    replayed = read_bag(tmp_path / "out.mcap").series
    engine = engine_of(*cals, arrays={"arr": NAMES}, gap_reset=1.0)
    outs = [engine.step_array("arr", ti, ri) for ti, ri in zip(t, r, strict=True)]
    stepped = np.array([o.strain for o in outs])
    np.testing.assert_allclose(replayed["/arr/strain"].values, stepped, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(replayed["/arr/direction"].values,
                                  np.array([o.direction for o in outs]))
    # the terms read the same tick's neighbours: a one-tick-stale neighbour differs
    batch = engine_of(*cals, gap_reset=1.0).run_array(NAMES, t, r)
    np.testing.assert_allclose(batch["b"].strain, stepped[:, 1], rtol=1e-12, atol=1e-12)
    b = engine_of(*cals, gap_reset=1.0)._sensors["b"]
    stale = b.run_finish(b.run_model(t, r[:, 1], None, 1.0), lambda n: np.nan,
                         {n: np.roll(batch[n].strain, 1) for n in ("a", "c")})
    assert np.abs(stale.strain - stepped[:, 1]).max() > 1e-3


def test_effect_state_resets_at_a_gap_reset() -> None:
    """A baseline captured at the start of a run is captured again after a gap reset."""
    effects = [{"name": "baseline", "kind": "baseline", "params": {"window": 0.5, "rest": 0.0},
                "coef": 1.0},
               {"name": "drift", "kind": "elapsed", "params": {"scale": 1.0}, "coef": 0.5}]
    cal = cubic_cal("s1", effects=effects)
    t1 = np.arange(100) * 0.02
    t2 = t1[-1] + 10.0 + np.arange(100) * 0.02  # 10 s later: gap reset (gap_reset = 5 s)
    r1 = 150 + 20 * np.sin(3 * t1)
    r2 = 170 + 20 * np.sin(3 * t2)
    t, r = np.concatenate([t1, t2]), np.concatenate([r1, r2])
    engine = engine_of(cal)
    batch = engine.run("s1", t, r)
    assert engine.health()["s1"].n_gaps == 1
    fresh = engine_of(cal).run("s1", t2, r2).strain
    np.testing.assert_allclose(batch.strain[100:], fresh, rtol=0, atol=1e-12)
    stepper = engine_of(cal)
    stepped = [stepper.step("s1", ti, ri).strain for ti, ri in zip(t, r, strict=True)]
    np.testing.assert_allclose(stepped, batch.strain, rtol=0, atol=1e-12)
    # without the reset the terms would carry the first run's state over
    carried = engine_of(cal, gap_reset=100.0).run("s1", t, r).strain
    assert np.abs(carried[100:] - fresh).max() > 0.1


def falling_sensor(n: int = 1500) -> Recording:
    """R falls with strain (negative gauge factor, like the nanocomposite seed)."""
    rng = np.random.default_rng(5)
    t = np.arange(n) * 0.02
    s = 15 * (1 - np.cos(2 * np.pi * t / 10.0))
    return Recording("neg", t, 1000.0 * (1 - 0.01 * s) + rng.normal(0, 0.05, n), s)


def test_falling_resistance_publishes_loading_as_plus_one() -> None:
    rec = falling_sensor()
    cal = fit_sensor([rec], "cubic", name="neg", options={"tau": 0.2})
    assert cal.direction.sign == -1
    assert fit_sensor([replace(rec, r=2000.0 - rec.r)], "cubic", name="neg",
                      options={"tau": 0.2}).direction.sign == 1
    rising = np.gradient(rec.s) > 0.05
    falling = np.gradient(rec.s) < -0.05
    out = engine_of(cal).run("neg", rec.t, rec.r)
    assert np.mean(out.direction[rising] == 1) > 0.9
    assert np.mean(out.direction[falling] == -1) > 0.9
    engine = engine_of(cal)
    stepped = [engine.step("neg", ti, ri).direction for ti, ri in zip(rec.t, rec.r, strict=True)]
    np.testing.assert_array_equal(stepped, out.direction)
    arrays = engine_of(replace(cal, name="x"), replace(cal, name="y"), arrays={"arr": ["x", "y"]})
    ticks = [arrays.step_array("arr", ti, [ri, ri]).direction
             for ti, ri in zip(rec.t, rec.r, strict=True)]
    np.testing.assert_array_equal(np.array(ticks)[:, 0], out.direction)


def test_apl_array_kernel_publishes_the_signed_direction() -> None:
    cals = [replace(c, direction=replace(c.direction, sign=-1)) for c in apl_cals({})]
    t = 100.0 + np.arange(300) * 0.02
    r = np.stack([150 + 30 * np.sin(t)] * len(NAMES), axis=1)
    engine = engine_of(*cals, arrays={"arr": NAMES})
    assert engine._arrays["arr"].fused
    ticks = np.array([engine.step_array("arr", ti, ri).direction for ti, ri in zip(t, r,
                                                                                    strict=True)])
    raw = engine_of(cals[0]).run("a", t, r[:, 0]).direction
    np.testing.assert_array_equal(ticks[:, 0], raw)
    slope = np.gradient(r[:, 0], t)  # R rising beyond the dead zone: unloading here
    for sel, published in ((slope > 25.0, -1), (slope < -25.0, 1)):
        assert np.mean(raw[sel] == published) > 0.8 and not np.any(raw[sel] == -published)


def test_sign_in_calibration_files(tmp_path: Path) -> None:
    cal = cubic_cal("s1", direction=DirectionSettings(deadzone=1.0, sign=-1))
    save_calibration(Calibration({"s1": cal}), tmp_path / "c.yaml")
    assert load_calibration(tmp_path / "c.yaml").sensors["s1"].direction.sign == -1
    text = (tmp_path / "c.yaml").read_text()
    (tmp_path / "old.yaml").write_text(text.replace("sign: -1", ""))
    assert load_calibration(tmp_path / "old.yaml").sensors["s1"].direction.sign == 1
    for bad in ("sign: 0", "sign: '+1'", "sign: true"):
        (tmp_path / "bad.yaml").write_text(text.replace("sign: -1", bad))
        with pytest.raises(CalibrationError) as err:
            load_calibration(tmp_path / "bad.yaml")
        assert err.value.field == "sensors.s1.direction.sign"
    with pytest.raises(ParameterError):
        DirectionSettings(deadzone=1.0, sign=2)


def test_resistance_memory_reads_what_the_model_reads() -> None:
    """A resistance-memory term reads the tared input the model sees: step, run and the
    loop's view (``BatchOutput.resistance`` of the calibration without its terms) agree."""
    rng = np.random.default_rng(4)
    t = np.arange(500) * 0.05
    r = 150.0 + 30.0 * np.sin(t) + rng.normal(0, 0.5, t.size)
    r[rng.random(t.size) < 0.05] = np.nan
    effect = {"name": "spike", "kind": "resistance_memory",
              "params": {"tau": 2.0, "form": "peak"}, "coef": 0.4}
    stepped, ran, stripped = (engine_of(cubic_cal(effects=e)) for e in ([effect], [effect], []))
    for engine in (stepped, ran, stripped):
        engine.set_input_gain("s1", 0.8)
    by_step = np.array([stepped.step("s1", tk, rk).strain for tk, rk in zip(t, r, strict=True)])
    by_run = ran.run("s1", t, r)
    np.testing.assert_allclose(by_run.strain, by_step, atol=1e-12)
    base = stripped.run("s1", t, r)
    used = used_mask(base.status)
    np.testing.assert_allclose(base.resistance[used], 0.8 * r[used])
    g = regressor_from_dict(effect).run(Batch.of(t[used], base.resistance[used],
                                                 base.strain[used], base.direction[used]))
    lo, hi = S_LO - MARGIN * (S_HI - S_LO), S_HI + MARGIN * (S_HI - S_LO)
    expected = np.clip(np.clip(base.strain[used], lo, hi) - 0.4 * g, lo, hi)
    np.testing.assert_allclose(by_run.strain[used], expected, atol=1e-9)


def test_a_tare_during_a_run_is_no_step_for_a_resistance_memory() -> None:
    """A tare mid-run (the node's auto tare or ``~/tare``) rescales what the models read;
    a resistance-memory term carries its memory over to the new gain, so after the tare it
    reads as if that gain had been set from the first sample (``--tare auto`` offline)."""
    rng = np.random.default_rng(6)
    t = np.arange(400) * 0.05
    r = 150.0 + 30.0 * np.sin(t) + rng.normal(0, 0.5, t.size)
    for form in ("relaxation", "peak", "trough"):
        effect = {"name": "m", "kind": "resistance_memory",
                  "params": {"tau": 4.0, "form": form}, "coef": 0.4}
        offline, live = engine_of(cubic_cal(effects=[effect])), engine_of(cubic_cal(
            effects=[effect]))
        offline.set_input_gain("s1", 0.9)
        whole = offline.run("s1", t, r).strain
        live.run("s1", t[:100], r[:100])
        live.set_input_gain("s1", 0.9)
        np.testing.assert_allclose(live.run("s1", t[100:], r[100:]).strain, whole[100:],
                                   atol=1e-9)
