"""Baseline tracking (strain_comp.core.tracking) against a known drifting rest level."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    TRACK_R0,
    staircase,
    staircase_calibration,
    tracked_step_by_step,
    tracking_gauge,
)

from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tracking import BaselineTracker
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings


@pytest.fixture(scope="module")
def cubic() -> Calibration:
    return staircase_calibration()


def test_a_rest_level_that_falls_after_each_release_is_followed(cubic: Calibration) -> None:
    t = np.arange(0.0, 190.0, 0.1)
    s = staircase(t)
    released = np.clip(np.floor((t - 10.0) / 20.0), 0.0, None)  # releases so far
    rest_fall = 1.0 - 0.01 * released  # the rest falls 1 % after every release
    rec = Recording("s1", t, tracking_gauge(s) * rest_fall, s)
    off = evaluate_recordings({"s1": rec}, cubic, tracking="off").sensors["s1"]
    on = evaluate_recordings({"s1": rec}, cubic, tracking="on").sensors["s1"]
    at_rest = (s == 0.0) & (t > 100.0)
    err_off = np.sqrt(np.mean((off.estimate - s)[at_rest] ** 2))
    err_on = np.sqrt(np.mean((on.estimate - s)[at_rest] ** 2))
    assert err_on < 0.5 * err_off
    assert on.stats.rmse < off.stats.rmse
    assert on.to_dict()["baseline_tracking"]["correction"] > 0.02  # the gain rose
    assert "baseline_tracking" not in off.to_dict()
    engine = Engine(cubic)
    BaselineTracker(engine).run("s1", rec.t, rec.r)
    values = engine.health()["s1"].to_diagnostic()[2]
    assert float(values["baseline_correction"]) == pytest.approx(
        on.tracking["correction"] if on.tracking else 0.0)
    assert "baseline_correction" not in Engine(cubic).health()["s1"].to_diagnostic()[2]


def test_a_held_strain_is_not_tracked(cubic: Calibration) -> None:
    t = np.arange(0.0, 60.0, 0.1)
    s = np.where(t < 5.0, 0.0, np.clip((t - 5.0) / 3.0, 0.0, 1.0) * 15.0)  # then held
    rec = Recording("s1", t, tracking_gauge(s), s)
    on = evaluate_recordings({"s1": rec}, cubic, tracking="on").sensors["s1"]
    assert on.tracking == {"seconds": 0.0, "correction": 0.0}


def test_a_calibration_that_reads_its_rest_as_a_strain_is_not_tracked(
        cubic: Calibration) -> None:
    """A rest resistance the map reads as 10 % strain (taken while the sensor still relaxed,
    say): following it would move the zero, so nothing is tracked; the true rest is."""
    from dataclasses import replace

    from strain_comp.core.tracking import TRACKING, rest_is_read_as_rest

    sensor = cubic.sensors["s1"]
    assert rest_is_read_as_rest(sensor, TRACK_R0, TRACKING.band)
    at_10 = float(tracking_gauge(np.array(10.0)))
    assert not rest_is_read_as_rest(sensor, at_10, TRACKING.band)
    wrong = Calibration({"s1": replace(sensor, rest_resistance=at_10)})
    t = np.arange(0.0, 60.0, 0.1)
    rec = Recording("s1", t, np.full(t.size, 0.97 * TRACK_R0), np.zeros(t.size))  # a fallen rest
    assert evaluate_recordings({"s1": rec}, cubic).sensors["s1"].tracking["correction"] > 0
    on = evaluate_recordings({"s1": rec}, wrong).sensors["s1"]
    assert on.tracking == {"seconds": 0.0, "correction": 0.0}


def test_a_rest_on_the_strain_side_only_undoes_the_trackers_own_correction(
        cubic: Calibration) -> None:
    """A rest that fell (R 3 % low) is followed; when it comes back, the correction is
    undone to none and no further; a rest reading a small strain is never followed."""
    t = np.arange(0.0, 120.0, 0.1)
    fell = np.where(t < 40.0, 0.97 * TRACK_R0, TRACK_R0)  # fallen, then back where it was
    back = evaluate_recordings({"s1": Recording("s1", t, fell, np.zeros(t.size))}, cubic)
    tracked = back.sensors["s1"].tracking
    assert tracked is not None and tracked["seconds"] == pytest.approx(2 * 0.03 / 0.002 / 0.97,
                                                                      abs=0.5)  # there, back
    assert tracked["correction"] == pytest.approx(0.0, abs=1e-12)
    risen = np.full(t.size, float(tracking_gauge(np.array(0.5))))  # reads 0.5 % strain
    held = evaluate_recordings({"s1": Recording("s1", t, risen, np.zeros(t.size))}, cubic)
    assert held.sensors["s1"].tracking == {"seconds": 0.0, "correction": 0.0}


def test_stepped_tracking_equals_the_batch_with_a_pair_statistic_and_a_despiker(
        cubic: Calibration) -> None:
    """The node's path (``advance``, ``Engine.step``, ``observe``) tracks what the model read
    (the upper of each pair, after the despiker), as the batch path does: equal outputs.
    Tracking the raw input instead is off by up to about 1 % strain here."""
    from dataclasses import replace

    sensor = cubic.sensors["s1"]
    cal = Calibration({"s1": replace(sensor, input=replace(
        sensor.input, alternation=True, pair="upper", despike=8.0))})
    t = np.arange(0.0, 190.0, 0.1)
    s = staircase(t)
    fall = 1.0 - 0.01 * np.clip(np.floor((t - 10.0) / 20.0), 0.0, None)
    excitation = np.where(np.arange(t.size) % 2, 0.3, -0.3)  # alternating
    r = tracking_gauge(s) * fall + excitation
    r[500] += 40.0  # a spike
    batch_engine = Engine(cal)
    batch = BaselineTracker(batch_engine).run("s1", t, r)
    stepped, engine = tracked_step_by_step(cal, t, r)
    np.testing.assert_allclose(stepped, batch.strain, rtol=0, atol=1e-9)
    assert engine.input_gain("s1") == pytest.approx(batch_engine.input_gain("s1"), abs=1e-12)
    assert batch_engine.input_gain("s1") > 1.02  # the rest that fell was followed


def test_a_rest_that_relaxes_back_after_a_release_is_left_to_relax(cubic: Calibration) -> None:
    """After each release the resistance undershoots by 2 % and recovers with a 20 s time
    constant (a viscoelastic sensor): it is not a rest that moved, nothing is tracked."""
    t = np.arange(0.0, 190.0, 0.1)
    s = staircase(t)
    since = np.clip(t - 10.0, 0.0, None) % 20.0 - 13.0  # seconds since the last release
    undershoot = np.where((t > 10.0) & (since >= 0.0), 0.02 * np.exp(-since / 20.0), 0.0)
    rec = Recording("s1", t, tracking_gauge(s) * (1.0 - undershoot), s)
    on = evaluate_recordings({"s1": rec}, cubic).sensors["s1"]
    assert on.tracking == {"seconds": 0.0, "correction": 0.0}


def test_a_calibration_with_loop_terms_is_not_tracked(cubic: Calibration) -> None:
    """A temperature term (the residual loop's) already moves the reading with the rest
    level; tracking as well would correct twice: a fallen rest is left to the terms. An
    output gain and offset alone (``recalibrate``) is tracked."""
    from dataclasses import replace

    from strain_comp.offline.recalibrate import recalibrate

    t = np.arange(0.0, 60.0, 0.1)
    rec = Recording("s1", t, np.full(t.size, 0.97 * TRACK_R0), np.zeros(t.size))  # a fallen rest
    term = {"name": "temperature_offset", "kind": "temperature", "coef": 0.0,
            "params": {"form": "offset", "t_ref": 20.0}}
    sensor = cubic.sensors["s1"]
    with_term = Calibration({"s1": replace(sensor, effects=[term])})
    on = evaluate_recordings({"s1": rec}, with_term).sensors["s1"]
    assert on.tracking == {"seconds": 0.0, "correction": 0.0}
    at_10 = float(tracking_gauge(np.array(10.0)))
    mapped = recalibrate(cubic, points=[(TRACK_R0, 0.0), (at_10, 11.0)])[0]
    assert evaluate_recordings({"s1": rec}, mapped).sensors["s1"].tracking["correction"] > 0
