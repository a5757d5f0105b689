"""The session-start recalibration of a memory model recovers a known change of the sensor.

Truth: a sensor that *is* a known MPI operator ([Electrolycra] eq. (2), (6)) with a lagging
loop (negative cell weights, the silver-nylon thread's loop: R lower on loading than on
unloading), calibrated exactly. On a later run its resistance has moved by a known affine
map (rest level and sensitivity). ``recalibrate --input --from RUN --first S`` on that
run's first load and unload must find the map (R' = R_rest,cal + k (R - R_rest,run): k =
1 / the sensitivity change) and read the whole run as the calibration read the sensor
before. A memory model is not on its constant-resistance map in use, so that map, which
for this sensor spans a fraction of the strain range, must not decide the span.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.base.compensator import Normalisation
from strain_comp.base.direction import DirectionSettings
from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.engine import Engine
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.session_start import recalibrate_recordings

NORM = Normalisation(r0=0.5, alpha=-3.0, s0=25.0, beta=-1.0)
"""R/R0 in [1, 2] -> xi in [-1, 1]; psi in [-1, 1] -> strain 0..50 %."""
CELLS = np.array([0.02, 0.06, 0.08, 0.08, 0.06, 0.04])
GAIN, REST = 1.3, 1.08
"""The later run: its sensitivity over the calibrated one and its rest level (R/R0)."""


def truth() -> SensorCalibration:
    """The sensor itself: MPI, six play operators of negative weight (a lagging loop as wide
    as the nylon thread's: held at a constant resistance from the relaxed state it outputs
    only 27 to 50 % strain while its loop spans 0 to 50 %)."""
    params = {"N": 6, "M": 1, "w": [2.5, *(-6.0 * CELLS), 0.54], "mu": [1.0]}
    return SensorCalibration(name="s1", model="mpi", params=params, normalisation=NORM,
                             valid_range=ValidRange(1.0, 2.0, 0.0, 50.0),
                             direction=DirectionSettings(deadzone=0.01))


def session(cal: SensorCalibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t [s], calibrated R/R0 and the strain the sensor reads: 10 Hz, a first cycle to
    the top, then cycles of random depth, from the relaxed state (the engine's at the
    start of a run)."""
    rng = np.random.default_rng(4)
    tops = [2.0, *rng.uniform(1.3, 2.0, 7)]
    turns = np.array([*np.ravel([[1.0, top] for top in tops]), 1.0])
    t_turn = np.arange(turns.size) * 20.0
    t = np.arange(0.0, t_turn[-1], 0.1)
    r = np.interp(t, t_turn, turns)
    return t, r, Engine(Calibration({"s1": cal})).run("s1", t, r).strain


@pytest.mark.parametrize("gain", [GAIN, 1.0 / GAIN])
def test_input_span_of_a_memory_model_recovers_a_sensitivity_change(gain: float,
                                                                       tmp_path: Path) -> None:
    cal = truth()
    t, r, s = session(cal)
    moved = Recording("s1", t, REST + gain * (r - 1.0), s)
    spanned, _ = recalibrate_recordings(Calibration({"s1": cal}), {"s1": moved},
                                        form="input", first=40.0)
    rest, rest_cal, k = spanned.sensors["s1"].input.zero_span
    assert k == pytest.approx(1.0 / gain, rel=0.02)
    assert rest_cal + k * (REST - rest) == pytest.approx(1.0, abs=0.01)
    before = evaluate_recordings({"s1": moved}, Calibration({"s1": cal})).sensors["s1"]
    after = evaluate_recordings({"s1": moved}, spanned).sensors["s1"]
    print(f"\nsensitivity x{gain:.3g}: RMSE {before.stats.rmse:.3f} % unspanned, "
          f"{after.stats.rmse:.4f} % spanned on the first cycle")
    assert after.stats.rmse < 0.05 * before.stats.rmse
    # what it writes loads again (the load's probe reads the model's own resistance)
    save_calibration(spanned, tmp_path / "spanned.yaml")
    assert load_calibration(tmp_path / "spanned.yaml").sensors["s1"].input.zero_span == \
        pytest.approx((rest, rest_cal, k))


def test_branch_resistance_inverts_a_branch_and_takes_the_nearest_output_beyond_it() -> None:
    """Truth: a branch S = 10 (R - 1) on R in [1, 2] with a dip below its end value: the
    first crossing from the rest end, linear between grid points; a strain the branch never
    outputs reads at the resistance of its nearest output."""
    from strain_comp.offline.session_start import branch_resistance

    grid = np.linspace(1.0, 2.0, 11)
    out = 10.0 * (grid - 1.0)
    assert branch_resistance(grid, out, 4.25) == pytest.approx(1.425)
    assert branch_resistance(grid, out, 12.0) == pytest.approx(2.0)
    dipped = out.copy()
    dipped[:3] = [2.0, 1.5, 2.5]
    assert branch_resistance(grid, dipped, 0.0) == pytest.approx(1.1)
