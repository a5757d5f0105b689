"""Virtual rig: determinism, every effect switch in its documented direction, round trip."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from strain_comp.errors import ParameterError
from strain_comp.io.recording import load_recordings
from strain_comp.offline.rig import (
    SCENARIOS,
    TEMPERATURE_STEP,
    RigEffects,
    SensorSpec,
    _mechanical,
    _Profile,
    simulate,
    write_sim_bag,
)

CLEAN = RigEffects(noise=0.0, adc_bits=0)


def _r(run, name="s1"):
    return run[name].r


def test_every_scenario_runs_and_is_deterministic() -> None:
    for name in SCENARIOS:
        a = simulate(name, seed=3, duration=60.0)
        b = simulate(name, seed=3, duration=60.0)
        for key in a:
            np.testing.assert_array_equal(a[key].r, b[key].r)
            assert np.isfinite(a[key].r).all()
    assert not np.array_equal(_r(simulate("random", seed=1)), _r(simulate("random", seed=2)))


def test_parse_effects() -> None:
    fx = RigEffects.parse(["drift=0.05", "crosstalk=0.1"])
    assert (fx.drift, fx.crosstalk, fx.hysteresis) == (0.05, 0.1, RigEffects().hysteresis)
    with pytest.raises(ParameterError, match="unknown effect"):
        RigEffects.parse(["wobble=1"])
    with pytest.raises(ParameterError, match="relaxation_tau"):
        RigEffects.parse(["relaxation_tau=0"])
    assert "drift" in RigEffects.describe()


def _loop(rate: float, fx: RigEffects = CLEAN) -> tuple[np.ndarray, np.ndarray]:
    t, s = _Profile().triangles(0, 30, rate, 3).sample(50.0, None)
    r = _mechanical(s, SensorSpec(), fx, 50.0)
    last = slice(2 * t.size // 3, t.size)  # the last cycle
    return s[last], r[last]


def test_loop_is_clockwise_and_rotates_with_rate() -> None:
    areas, tops, bottoms = [], [], []
    for rate in (20.0, 60.0, 100.0):
        s, r = _loop(rate)
        areas.append(0.5 * np.sum(s[:-1] * r[1:] - s[1:] * r[:-1]))
        tops.append(r[np.argmax(s)])
        bottoms.append(r[np.argmin(s)])
    assert all(a < 0 for a in areas)  # clockwise in the (S, R) plane
    assert tops[0] < tops[1] < tops[2]  # the loop steepens (rotates ccw) with rate
    assert tops[2] - tops[0] > 3 * abs(bottoms[2] - bottoms[0])  # about the lower-left corner
    s, r = _loop(60.0, dataclasses.replace(CLEAN, hysteresis=0.0, relaxation=0.0))
    assert abs(0.5 * np.sum(s[:-1] * r[1:] - s[1:] * r[:-1])) < 1e-9  # off: no loop


def _hold_changes(fx: RigEffects) -> tuple[list[float], list[float]]:
    run = simulate("steps", effects=fx)
    x = run["s1"]
    d = np.diff(x.s)
    ends = np.flatnonzero((d != 0) & (np.append(d[1:], 0) == 0)) + 1
    up, down = [], []
    for e in ends:
        seg = x.r[e:e + int(25 / (x.t[1] - x.t[0]))]
        (up if x.s[e] > x.s[e - 3] else down).append(seg[0] - seg[-1])
    return up, down


def test_relaxation_strong_on_loading_weak_on_unloading() -> None:
    up, down = _hold_changes(CLEAN)
    assert min(up) > 0.5  # resistance falls during a hold after loading
    assert max(abs(x) for x in down) < 0.3 * min(up)
    no_ve = dataclasses.replace(CLEAN, hysteresis=0.0, relaxation=0.0)
    up0, down0 = _hold_changes(no_ve)
    assert max(abs(x) for x in up0 + down0) < 1e-9
    slow = _hold_changes(dataclasses.replace(CLEAN, hysteresis=0.0))[0]
    expected = CLEAN.relaxation * 11.5 * 0.3 * (1 - np.exp(-25 / CLEAN.relaxation_tau))
    assert slow[0] == pytest.approx(expected, rel=0.15)  # R0 * relaxation * du, 10 % step


def test_drift_on_a_long_hold() -> None:
    off = simulate("long", effects=CLEAN)
    on = simulate("long", effects=dataclasses.replace(CLEAN, drift=0.05))
    ratio = on["s1"].r / off["s1"].r
    t = on["s1"].t
    np.testing.assert_allclose(ratio, 1 + 0.05 * t / 3600, rtol=1e-12)
    default = simulate("long")  # the scenario's own drift
    own = simulate("long", effects=dataclasses.replace(RigEffects(), drift=0.05))
    np.testing.assert_array_equal(default["s1"].r, own["s1"].r)


def test_temperature_effect_and_topic(tmp_path: Path) -> None:
    off = simulate("triangle", effects=CLEAN)
    assert off["s1"].temperature is None
    fx = dataclasses.replace(CLEAN, temperature=0.004)
    on = simulate("triangle", effects=fx)
    temp = on["s1"].temperature
    assert np.ptp(temp) > 2.0
    np.testing.assert_allclose(_r(on) / _r(off), 1 + 0.004 * (temp - 23.0), rtol=1e-12)
    write_sim_bag(on, tmp_path / "t.mcap")
    recs, _ = load_recordings(tmp_path / "t.mcap")
    err = np.abs(recs["s1"].temperature - temp)  # published at 2 Hz, interpolated back
    assert np.nanmedian(err) < 0.01 and np.nanmax(err) <= TEMPERATURE_STEP[0] + 0.01


def test_crosstalk_comes_from_neighbours_only() -> None:
    off = simulate("array", effects=CLEAN)
    on = simulate("array", effects=dataclasses.replace(CLEAN, crosstalk=0.1))
    names = list(off)
    delta = {n: off[n].r - off[n].r[0] for n in names}
    for i, n in enumerate(names):
        leak = sum(delta[names[j]] for j in (i - 1, i + 1) if 0 <= j < len(names))
        np.testing.assert_allclose(on[n].r - off[n].r,
                                   0.1 * leak, atol=1e-9)
    strains = np.array([off[n].s for n in names])
    assert np.corrcoef(strains)[0, 1] < 0.9  # neighbours strained differently


def test_mullins_softening_after_first_peak() -> None:
    fx = dataclasses.replace(CLEAN, hysteresis=0.0, relaxation=0.0, mullins=0.5)
    run = simulate("triangle", effects=fx)
    x = run["s1"]
    ref = simulate("triangle", effects=dataclasses.replace(fx, mullins=0.0))["s1"]
    at_peak = np.argmax(x.s)
    first = np.flatnonzero(x.s > 15)[0]  # first loading, below the later peak
    later = np.flatnonzero((x.s > 14.9) & (x.s < 15.1))[-1]
    assert x.r[first] - 11.5 > x.r[later] - 11.5  # softer afterwards
    loss = 1 - (x.r[at_peak] - 11.5) / (ref.r[at_peak] - 11.5)
    assert loss == pytest.approx(0.5 * 30 / 100, rel=1e-6)


def test_noise_and_adc() -> None:
    clean = simulate("triangle", effects=CLEAN)
    noisy = simulate("triangle", effects=dataclasses.replace(CLEAN, noise=0.05))
    err = _r(noisy) - _r(clean)
    assert np.std(err) == pytest.approx(0.05, rel=0.05)
    adc = simulate("triangle", effects=dataclasses.replace(CLEAN, adc_bits=8))
    r = _r(adc)
    assert np.unique(r).size < 256
    v1 = 3.2 * 10.5 / (10.5 + 23.0)
    step = 10.5 * 3.2 / v1**2 * 3.2 / 256  # dR/dV * LSB near the top of the range
    assert np.max(np.abs(r - _r(clean))) < step


def test_round_trip_through_bag(tmp_path: Path) -> None:
    """Every sensor, an array's too, reads back its resistance, reference and temperature
    (each sensor's own /NAME/temperature, as the node and evaluate read it)."""
    warm = dataclasses.replace(RigEffects(), temperature=0.004)
    for scenario in ("triangle", "array"):
        run = simulate(scenario, duration=30.0, effects=warm)
        write_sim_bag(run, tmp_path / f"{scenario}.mcap")
        recs, problems = load_recordings(tmp_path / f"{scenario}.mcap")
        assert problems == [] and set(recs) == set(run)
        for name, sensor in run.items():
            np.testing.assert_array_equal(recs[name].r, sensor.r)
            np.testing.assert_array_equal(recs[name].s, sensor.s)
            np.testing.assert_allclose(recs[name].t, sensor.t, atol=1e-9)
            assert sensor.temperature is not None and recs[name].temperature is not None
            err = np.abs(recs[name].temperature - sensor.temperature)  # 2 Hz, interpolated
            assert np.nanmedian(err) < 0.01 and np.nanmax(err) <= TEMPERATURE_STEP[0] + 0.01
