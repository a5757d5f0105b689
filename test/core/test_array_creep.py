"""The fused array tick with creep_pi sensors (``strain_comp.core.array.family_tick``), alone
and beside APL-family sensors: each sensor's published strain, direction, status and
counters equal that sensor stepped alone through ``Engine.step`` (the per-sample path),
over a run with bad samples, an outage longer than the gap reset, out-of-range samples,
a voltage-divider input and a tare part-way."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import DIRECTION, NORM, R_HI, R_LO, S_HI, S_LO, cubic_cal, engine_of

from strain_comp.core.calibration import InputSettings, SensorCalibration, ValidRange
from strain_comp.core.engine import Engine
from strain_comp.models import Segment, model_class

GAP = 0.5
TARE_AT = 300


def fitted(model: str, seed: int) -> SensorCalibration:
    """A ``model`` sensor fitted to a lagging, creeping loop (its own per seed)."""
    t = np.arange(1500) * 0.01
    r = 150.0 + (35.0 + 3 * seed) * np.sin(2 * np.pi * (0.3 + 0.05 * seed) * t)
    s = 0.5 * (r - R_LO) + 2.0 * np.sin(2 * np.pi * 0.3 * t - 0.6)
    options = ({"taus": [0.3, 3.0], "n_play": 4} if model == "creep_pi"
               else {"N": 3, "M": 3, "sigma_grid": [1.0], "p_grid": [1.0], "refine": False,
                     "progress": False})
    fit = model_class(model).fit([Segment(t, r, s)], NORM, direction=DIRECTION, **options)
    return SensorCalibration(name=f"{model}{seed}", model=model, params=fit.to_params(),
                             normalisation=NORM, valid_range=ValidRange(R_LO, R_HI, S_LO, S_HI),
                             direction=DIRECTION, rest_resistance=150.0)


def as_divider(cal: SensorCalibration, r1: float = 100.0, vin: float = 3.3
               ) -> SensorCalibration:
    """``cal`` read through a voltage divider (V across R1)."""
    return replace(cal, input=InputSettings(kind="divider", r1=r1, vin=vin))


def stream(k: int, n: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """(t, R) of ``k`` sensors at 100 Hz with every kind of fault: bad samples, a long
    outage on sensor 1 (a gap reset for it alone), out of range on sensor 0."""
    rng = np.random.default_rng(7)
    t = np.arange(n) * 0.01
    r = np.stack([150 + 40 * np.sin(2 * np.pi * (0.4 + 0.1 * j) * t + j)
                  + rng.normal(0, 0.3, n) for j in range(k)], axis=1)
    r[rng.random(r.shape) < 0.04] = np.nan
    r[rng.random(r.shape) < 0.01] = -1.0
    r[150:200, 1] = np.nan
    r[400:430, 0] += 120.0
    return t, r


def raw_of(cal: SensorCalibration, r: np.ndarray) -> np.ndarray:
    """What the sensor's input reads for resistance ``r`` (the divider's V_R1)."""
    if cal.input.kind != "divider":
        return r
    r1, vin = cal.input.divider()
    return vin * r1 / (r1 + r)


def compare(cals: list[SensorCalibration]) -> Engine:
    """Run ``cals`` as one array and each alone; assert they agree. The array engine."""
    names = [c.name for c in cals]
    t, r = stream(len(cals))
    raw = np.stack([raw_of(c, r[:, j]) for j, c in enumerate(cals)], axis=1)
    array = engine_of(*cals, arrays={"arr": names}, gap_reset=GAP)
    assert array._arrays["arr"].fused
    singles = [engine_of(c, gap_reset=GAP) for c in cals]
    outs = []
    for i, (ti, ri) in enumerate(zip(t, raw, strict=True)):
        if i == TARE_AT:
            for j, name in enumerate(names):
                array.tare(name, 147.0 + j)
        outs.append(array.step_array("arr", ti, ri))
    for j, (name, single) in enumerate(zip(names, singles, strict=True)):
        ref = []
        for i, (ti, ri) in enumerate(zip(t, raw[:, j], strict=True)):
            if i == TARE_AT:
                single.tare(name, 147.0 + j)
            ref.append(single.step(name, ti, ri))
        np.testing.assert_allclose([o.strain[j] for o in outs], [o.strain for o in ref],
                                   rtol=1e-9, atol=1e-9)
        assert [o.status[j] for o in outs] == [o.status for o in ref]
        assert [o.direction[j] for o in outs] == [o.direction for o in ref]
        assert [o.out_of_range[j] for o in outs] == [o.out_of_range for o in ref]
        assert array.health()[name] == single.health()[name]
    health = array.health()
    assert health[names[1]].n_gaps == 1 and health[names[0]].n_out_of_range > 0
    return array


@pytest.fixture(scope="module")
def creep() -> list[SensorCalibration]:
    return [fitted("creep_pi", seed) for seed in range(3)]


def test_creep_array_tick_equals_each_sensor_alone(creep: list[SensorCalibration]) -> None:
    cals = [creep[0], creep[1], as_divider(creep[2])]
    array = compare(cals)
    kernels = array._arrays["arr"].kernels
    assert [type(kern).__name__ for _, kern in kernels] == ["CreepPIArray"]


def test_mixed_families_run_one_tick_each_and_equal_each_sensor_alone(
        creep: list[SensorCalibration]) -> None:
    cals = [creep[0], fitted("apl", 1), creep[1], fitted("apl", 2)]
    array = compare(cals)
    kernels = array._arrays["arr"].kernels
    assert [(type(kern).__name__, idx.tolist()) for idx, kern in kernels] == [
        ("APLArray", [1, 3]), ("CreepPIArray", [0, 2])]


def test_a_sensor_without_array_kernel_keeps_the_loop(creep: list[SensorCalibration]) -> None:
    engine = engine_of(creep[0], cubic_cal("c"), arrays={"arr": [creep[0].name, "c"]})
    assert not engine._arrays["arr"].fused
