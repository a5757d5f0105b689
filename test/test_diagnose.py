"""The residual loop on data that carry an effect their calibration does not declare.

Each bag is made by a small forward model here (R = R0 (1 + a S + b S^2) plus one physical
effect, plus noise); the calibration is a cubic fitted on a clean recording of the same
sensor. ``diagnose`` knows nothing of how the data were made: it must name the effect
(the kind of the first added effect) and cut the held-out RMSE by at least ``MIN_DROP``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from strain_comp.calibration import (
    Calibration,
    SensorCalibration,
    ValidRange,
    load_calibration,
    save_calibration,
)
from strain_comp.diagnose import diagnose, write_plots
from strain_comp.direction import DirectionSettings
from strain_comp.engine import Engine
from strain_comp.models import Normalisation
from strain_comp.models.base import Segment
from strain_comp.models.cubic import Cubic
from strain_comp.recording import Recording

MIN_DROP = 0.30
"""Least relative fall of the held-out RMSE when the missing effect is added."""
FS = 20.0
DURATION = 600.0


def strain(t: np.ndarray, period: float = 40.0, amp: float = 20.0) -> np.ndarray:
    """Trapezoids: ramp up, hold, ramp down, hold; amplitude slowly modulated."""
    ph = t % (2 * period)
    up = period - 10.0
    s = np.where(ph < up, amp * ph / up, np.where(
        ph < period, amp, np.where(ph < period + up, amp * (1 - (ph - period) / up), 0.0)))
    return s * (1 + 0.2 * np.sin(2 * np.pi * t / 170))


def resistance(s: np.ndarray, gain: np.ndarray | float = 1.0) -> np.ndarray:
    return 100.0 * (1 + 0.02 * gain * s + 1e-4 * s**2)


def make(effect: str | None, seed: int, name: str = "s1", mag: float = 1.0) -> Recording:
    """One sensor's recording with ``effect`` (or none) in its resistance."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION, 1.0 / FS)
    s = strain(t)
    r = resistance(s)
    temperature = None
    if effect == "relaxation":  # overshoot after loading that decays with tau = 8 s
        h = np.zeros_like(s)
        decay = np.exp(-1.0 / FS / 8.0)
        ds = np.maximum(np.diff(s, prepend=s[0]), 0.0)
        for k in range(1, s.size):
            h[k] = h[k - 1] * decay + ds[k]
        r = r + mag * 0.6 * h
    elif effect == "drift":  # baseline creeping up linearly
        r = r + mag * 6.0 * t / DURATION
    elif effect == "temperature":  # TCR 0.4 %/K with a slow temperature swing
        temperature = 25 + 8 * np.sin(2 * np.pi * t / 300)
        r = r * (1 + mag * 0.004 * (temperature - 25))
    elif effect == "mullins":  # gauge factor 30 % high at first, softening over ~1.5 cycles
        r = resistance(s, 1 + mag * 0.3 * np.exp(-np.floor(t / 80.0) / 1.5))
    r = r + rng.normal(0, 0.02, t.size)
    return Recording(name, t, r, s, temperature)


def make_array(crosstalk: float, seed: int) -> dict[str, Recording]:
    """Three sensors of one array with their own strains; sensor b feels its neighbours."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION, 1.0 / FS)
    strains = {"a": strain(t, 40.0), "b": strain(t + 13.0, 55.0, 15.0),
               "c": strain(t + 7.0, 31.0, 25.0)}
    out = {}
    for i, (name, s) in enumerate(strains.items()):
        r = resistance(s)
        if name == "b":
            r = r + crosstalk * (strains["a"] + strains["c"])
        out[name] = Recording(name, t, r + rng.normal(0, 0.02, t.size), s, None, "arr", i)
    return out


def calibrate(rec: Recording) -> SensorCalibration:
    """A cubic on a clean recording (what a user's plain calibration would be)."""
    norm = Normalisation.fit(rec.r, rec.s)
    direction = DirectionSettings(deadzone=0.6, tau=0.5)
    model = Cubic.fit([Segment(rec.t, rec.r, rec.s)], norm, direction=direction)
    return SensorCalibration(
        name=rec.name, model="cubic", params=model.to_params(), normalisation=norm,
        valid_range=ValidRange(0.8 * rec.r.min(), 1.2 * rec.r.max(), -10.0, 40.0),
        direction=direction)


@pytest.fixture(scope="module")
def clean_calibration() -> Calibration:
    return Calibration({"s1": calibrate(make(None, seed=1))})


@pytest.mark.parametrize(("effect", "kind"), [
    ("relaxation", "relaxation"), ("drift", "elapsed"), ("temperature", "temperature"),
    ("mullins", "mullins")])
def test_finds_the_undeclared_effect(clean_calibration: Calibration, effect: str,
                                     kind: str) -> None:
    result = diagnose({"s1": make(effect, seed=2)}, clean_calibration)
    added = result.added
    assert added, result.summary()
    assert added[0].kind == kind, result.summary()
    drop = 1 - result.after["rmse"] / result.before["rmse"]
    print(f"{effect}: {added[0].name}, held-out RMSE {result.before['rmse']:.4f} -> "
          f"{result.after['rmse']:.4f} % ({drop:.0%} lower)")
    assert drop >= MIN_DROP
    # the added terms are in the output calibration, the engine applies them online
    effects = result.calibration.sensors["s1"].effects
    assert sorted(e["name"] for e in effects) == sorted(a.name for a in added)


def test_finds_crosstalk_between_array_neighbours() -> None:
    clean = make_array(0.0, seed=3)
    calibration = Calibration({n: calibrate(rec) for n, rec in clean.items()})
    result = diagnose(make_array(0.05, seed=4), calibration)
    b = result.sensors["b"]
    assert next(s.kind for s in result.added if s.sensor == "b") == "crosstalk", b.message
    assert 1 - b.after["rmse"] / b.before["rmse"] >= MIN_DROP
    assert {s.params["neighbour"] for s in b.scores if s.kind == "crosstalk"} == {"a", "c"}
    for name in ("a", "c"):  # the sensors without cross-talk get nothing
        assert not result.sensors[name].added, result.sensors[name].message


def test_no_missing_effect_adds_nothing(clean_calibration: Calibration, tmp_path: Path) -> None:
    result = diagnose({"s1": make(None, seed=5)}, clean_calibration)
    assert not result.added
    assert result.after == result.before
    assert "nothing added" in result.sensors["s1"].message
    assert result.calibration.sensors["s1"].effects == []
    assert write_plots(result, tmp_path) == []


def test_json_contract_validation_bag_and_cal2(clean_calibration: Calibration,
                                               tmp_path: Path) -> None:
    result = diagnose({"s1": make("drift", seed=6)}, clean_calibration,
                      validate_recordings={"s1": make("drift", seed=7)})
    record = json.loads(json.dumps(result.to_json()))
    assert set(record) >= {"before", "after", "effects", "validated_on"}
    assert record["validated_on"] == "validate"
    assert isinstance(record["before"]["rmse"], float)
    for entry in record["effects"]:
        assert isinstance(entry["name"], str)
        assert isinstance(entry["added"], bool)
        assert entry["score"] is None or isinstance(entry["score"], float)
    assert record["effects"][0]["added"] and record["effects"][0]["kind"] == "elapsed"
    assert record["after"]["rmse"] < 0.3 * record["before"]["rmse"]
    # CAL2: the input plus the added effects; the engine's online output reproduces "after"
    save_calibration(result.calibration, tmp_path / "cal2.yaml")
    cal2 = load_calibration(tmp_path / "cal2.yaml")
    val = make("drift", seed=7)
    engine = Engine(cal2)
    estimate = engine.run("s1", val.t, val.r).strain
    rmse = float(np.sqrt(np.mean((estimate - val.s) ** 2)))
    assert rmse == pytest.approx(record["after"]["rmse"], rel=1e-6)
    stepped = [engine.step("s1", t + DURATION + 10, r).strain for t, r in zip(val.t[:50],
                                                                              val.r[:50],
                                                                              strict=True)]
    assert np.all(np.isfinite(stepped))
    paths = write_plots(result, tmp_path / "plots")
    assert [p.name for p in paths] == ["diagnose_s1.png"] and paths[0].stat().st_size > 1000
