"""The session start the loop and the benchmark share (``session.warmup_start``), against
known truth: a sensor whose first load and unload reads another sensitivity than the rest
of the run (the first stretch after a long rest), and a run with one stretch only."""

from __future__ import annotations

import numpy as np
import pytest

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.session import Stretches, session_errors, session_start, warmup_start
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor

R0 = 100.0
"""Rest resistance [ohm] of the synthetic sensor."""


def triangles(t: np.ndarray) -> np.ndarray:
    """Strain [%]: a 5 s rest, then 0 -> 30 -> 0 % over 10 s, every 20 s."""
    return np.interp(t % 20.0, [0.0, 5.0, 10.0, 15.0, 20.0], [0.0, 0.0, 30.0, 0.0, 0.0])


def linear_run(t: np.ndarray, s: np.ndarray, gain: np.ndarray) -> Recording:
    """A linear sensor, R = R0 (1 + gain s / 100), with the reference ``s``."""
    return Recording("s1", t, R0 * (1.0 + gain * s / 100.0), s)


@pytest.fixture(scope="module")
def calibration() -> Calibration:
    t = np.arange(0.0, 100.0, 0.05)
    return Calibration({"s1": fit_sensor([linear_run(t, triangles(t), np.full(t.size, 1.0))],
                                         "cubic", name="s1")})


def test_the_warm_up_start_reads_the_run_after_its_first_stretch(calibration: Calibration
                                                                 ) -> None:
    """Sensitivity 1.5 on the first stretch, 1.2 after it: the start on the second stretch
    reads the rest of the run as it is (the first stretch's error only), the start on the
    first does not."""
    t = np.arange(0.0, 120.0, 0.05)
    s = triangles(t)
    stretches = Stretches.of(t, s)
    assert stretches is not None and stretches.second is not None
    gain = np.where(t < stretches.first, 1.5, 1.2)
    rec = linear_run(t, s, gain)
    started = warmup_start(calibration, {"s1": rec}, stretches)
    assert started.window == stretches.second and started.steps == ["input", "output"]
    errors = session_errors(calibration, {"s1": rec}, "s1", stretches)
    later = rec.t[np.isfinite(rec.s)] >= stretches.first
    assert errors.size == later.size
    assert np.sqrt(np.mean(errors[later] ** 2)) < 0.05  # % strain, against 30 % of travel
    # on the first stretch its sensitivity is read into the whole run: the later strains
    # read 1.2 / 1.5 = 0.8 of the truth, an RMS error of 0.2 x RMS(s) (about 3 % strain)
    first = session_start(calibration, {"s1": rec}, (0.0, stretches.first))
    assert first.window == (0.0, stretches.first) and first.steps == ["input", "output"]
    ev = evaluate_recordings({"s1": rec}, first.calibration).sensors["s1"]
    first_errors = ev.estimate[ev.scored] - ev.reference[ev.scored]
    assert np.sqrt(np.mean(first_errors[later] ** 2)) == pytest.approx(
        0.2 * np.sqrt(np.mean(s[later] ** 2)), rel=0.2)


def test_a_run_with_one_stretch_is_started_on_it(calibration: Calibration) -> None:
    """One load and unload, then rest: what follows the first stretch (the last of its
    return) holds no load, so the start there is refused and the first stretch's is used,
    the same start as made on it; the same where the reference never returns (no second
    stretch at all)."""
    t = np.arange(0.0, 40.0, 0.05)
    for s in (np.where(t < 20.0, triangles(t), 0.0), np.minimum(t, 30.0)):
        stretches = Stretches.of(t, s)
        assert stretches is not None
        rec = linear_run(t, s, np.full(t.size, 1.2))
        if stretches.second is not None:
            assert not session_start(calibration, {"s1": rec}, stretches.second).steps
        at_first = session_start(calibration, {"s1": rec}, (0.0, stretches.first))
        assert at_first.steps == ["input", "output"]
        assert warmup_start(calibration, {"s1": rec}, stretches, at_first) is at_first
        errors = session_errors(calibration, {"s1": rec}, "s1", stretches)
        assert np.sqrt(np.mean(errors ** 2)) < 0.05
