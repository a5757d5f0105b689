"""The residual loop on another day (docs/results.md, "Residual loop"): a calibration made
on day 1, used on day-2 runs after their session start (``strain-comp start``), where the
sensor's sensitivity now drifts in time.

Day 1 is a clean virtual-rig run (``rig.simulate``, viscous branches off, as
test_diagnose.py), a cubic fitted on it. A day-2 run is another rig run whose resistance
change from rest is scaled by 1 + k t: its sensitivity drifts by k per second, which no
session start at the run's beginning removes. Where every day-2 run drifts alike, the loop
must find the drift, add it and lower a day-2 run it never saw by a quarter or more
(given three validation runs: two tell one more run's gain only where they nearly agree);
where the validation runs drift differently, it must add nothing and say in one line why
and what to record instead.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.loop import diagnose
from strain_comp.diagnosis.session import session_errors
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.rig import RigEffects, simulate

CLEAN = RigEffects(hysteresis=0.0, relaxation=0.0)
DRIFT = -0.1 / 60.0
"""The day-2 sensitivity drift: -10 % per minute (1/s)."""


def day_run(seed: int, drift: float) -> dict[str, Recording]:
    """A rig run of the ``random`` scenario (300 s) whose sensitivity drifts by ``drift``
    per second from its first sample."""
    sim = simulate("random", seed=seed, effects=CLEAN)["s1"]
    rest = float(sim.r[0])
    r = rest + (sim.r - rest) * (1.0 + drift * (sim.t - sim.t[0]))
    return {"s1": Recording("s1", sim.t, r, sim.s)}


@pytest.fixture(scope="module")
def day1() -> Calibration:
    sim = simulate("patterns", seed=0, effects=CLEAN)["s1"]
    return Calibration({"s1": fit_sensor([sim], "cubic", name="s1")})


def started_rmse(calibration: Calibration, run: dict[str, Recording]) -> float:
    """RMSE over the whole run after its session start (``strain-comp start``, then
    ``evaluate``)."""
    return float(np.sqrt(np.mean(session_errors(calibration, run, "s1") ** 2)))


def test_a_sensitivity_drift_every_day_2_run_shares_is_added_and_carries(
        day1: Calibration) -> None:
    """Three validation runs that drift alike: the drift is added and lowers an unseen
    day-2 run by a quarter or more. Two are too few to tell one more run's gain (their
    gains differ with the profile, -43 % and -53 % here): the line asks for more."""
    two = diagnose(day_run(2, DRIFT), day1,
                   validate_recordings=[day_run(3, DRIFT), day_run(4, DRIFT)])
    assert two.added == []
    assert "record more validation runs" in two.sensors["s1"].message
    result = diagnose(day_run(2, DRIFT), day1,
                      validate_recordings=[day_run(seed, DRIFT) for seed in (3, 4, 6)])
    added = result.added
    assert [a.kind for a in added][:1] == ["elapsed"], result.summary()
    assert added[0].params["form"] == "linear_strain"  # a sensitivity that drifts in time
    test = day_run(5, DRIFT)  # a day-2 run the loop never saw
    before, after = started_rmse(day1, test), started_rmse(result.calibration, test)
    print(f"{added[0].name}: {added[0].reading()}; unseen day-2 run after its start "
          f"{before:.3f} -> {after:.3f} %")
    assert after <= 0.75 * before


def test_validation_runs_that_drift_apart_get_no_term_and_one_line(day1: Calibration) -> None:
    result = diagnose(day_run(2, DRIFT), day1,
                      validate_recordings=[day_run(3, DRIFT), day_run(4, -DRIFT)])
    assert result.added == []
    assert result.calibration.sensors["s1"].effects == day1.sensors["s1"].effects
    message = result.sensors["s1"].message
    assert "\n" not in message
    assert "the change differs between the validation runs" in message, message
    assert "record known strains during the run (evaluate --references-every SECONDS)" \
        in message
    # the term the diagnosed run asks for lowers one validation run and raises the other
    changes = re.search(r"changes them by ([+-]\d+) %, ([+-]\d+) %", message)
    assert changes is not None, message
    assert int(changes[1]) < 0 < int(changes[2]), message
