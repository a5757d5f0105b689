"""The input zero and span from a run's first cycle, fitted through the model's path.

Truth: a rig sensor (hysteresis, relaxation) whose resistance has since moved by a known
affine map (its rest level and its sensitivity); the calibration spanned on the moved
run's first cycle must read the moved run about as well as it read the sensor before.
"""

from __future__ import annotations

import pytest
from conftest import calibration_of

from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.rig import simulate

GAIN = 1.3
"""The moved sensor's sensitivity over the calibrated one's."""


def rig_run() -> Recording:
    return simulate("triangle", seed=2, duration=170.0)["s1"]


@pytest.mark.parametrize("model", ["cubic", "mpi", "apl"])
def test_span_from_the_first_cycle_reads_a_moved_sensor(model: str) -> None:
    from strain_comp.offline.session_start import recalibrate_recordings

    cal = calibration_of(model)
    rec = rig_run()
    rest = float(rec.r[0])
    moved = Recording("s1", rec.t, 1.05 * rest + GAIN * (rec.r - rest), rec.s)
    before = evaluate_recordings({"s1": rec}, cal).sensors["s1"].stats.rmse
    unspanned = evaluate_recordings({"s1": moved}, cal).sensors["s1"].stats.rmse
    spanned, _ = recalibrate_recordings(cal, {"s1": moved}, form="input", first=85.0)
    after = evaluate_recordings({"s1": moved}, spanned).sensors["s1"].stats.rmse
    k = spanned.sensors["s1"].input.zero_span[2]
    assert unspanned > 2.0 * before
    assert after < 1.25 * before + 0.2
    assert k == pytest.approx(1.0 / GAIN, rel=0.1)
