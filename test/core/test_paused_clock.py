"""Bounded state whatever the clock does: a stopped clock (repeated stamps) or one that runs
backwards holds O(1) state per sensor, and tracking over a slow stream run in one batch,
in windows or sample by sample gives the same numbers."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest
from conftest import staircase, staircase_calibration, tracked_step_by_step, tracking_gauge

from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tracking import BaselineTracker


def held_bytes() -> int:
    """Bytes Python holds now (tracemalloc)."""
    gc.collect()
    return tracemalloc.get_traced_memory()[0]



@pytest.fixture(scope="module")
def cubic() -> Calibration:
    return staircase_calibration()

@pytest.mark.parametrize("clock", ["stopped", "backwards"])
def test_the_tracker_holds_constant_state_when_time_stands_still_or_runs_back(
        cubic: Calibration, clock: str) -> None:
    engine = Engine(cubic)
    tracker = BaselineTracker(engine)
    for ti in np.arange(0.0, 3.05, 0.1):  # a normal start: the stretch [3, 4) holds one
        tracker.advance("s1", float(ti))
        tracker.observe("s1", float(ti), engine.step("s1", float(ti), R0_REST))
    t = np.full(5000, 3.0) if clock == "stopped" else 2.5 - 1e-5 * np.arange(5000)
    tracemalloc.start()
    try:
        before = held_bytes()
        for i in range(20_000):  # the node's path
            ti = 3.0 if clock == "stopped" else 3.0 - 1e-4 * (i + 1)
            tracker.advance("s1", ti)
            tracker.observe("s1", ti, engine.step("s1", ti, R0_REST))
        for _ in range(4):  # the batch path (replay, evaluate)
            tracker.run("s1", t, np.full(t.size, R0_REST))
        grown = held_bytes() - before
    finally:
        tracemalloc.stop()
    assert grown < 64 * 1024, grown  # 40 000 inputs: under 2 bytes each


R0_REST = float(tracking_gauge(np.zeros(1))[0])


def slow_and_fast(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The staircase with a rest that falls after each release, sampled at 10 Hz in places
    and every 1.3-2.5 s in others (stretches of one sample), with repeated stamps."""
    rng = np.random.default_rng(seed)
    t, now = [], 0.0
    while now < 250.0:
        fast = (now // 40.0) % 2 == 0
        now += 0.1 if fast else rng.uniform(1.3, 2.5)
        t.append(now)
        if rng.random() < 0.02:
            t.append(now)  # a repeated stamp
    times = np.array(t)
    fall = 1.0 - 0.01 * np.clip(np.floor((times - 10.0) / 20.0), 0.0, None)
    return times, tracking_gauge(staircase(times)) * fall


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tracking_a_slow_stream_is_alike_in_one_batch_in_windows_and_stepped(
        cubic: Calibration, seed: int) -> None:
    t, r = slow_and_fast(seed)
    batch_engine = Engine(cubic)
    batch = BaselineTracker(batch_engine).run("s1", t, r)
    window_engine = Engine(cubic)
    windows = BaselineTracker(window_engine)
    cuts = np.sort(np.random.default_rng(seed).choice(t.size, 12, replace=False))
    windowed = np.concatenate([windows.run("s1", t[a:b], r[a:b]).strain for a, b in
                               zip([0, *cuts], [*cuts, t.size], strict=True) if b > a])
    stepped, engine = tracked_step_by_step(cubic, t, r)
    np.testing.assert_allclose(windowed, batch.strain, rtol=0, atol=1e-9)
    np.testing.assert_allclose(stepped, batch.strain, rtol=0, atol=1e-9)
    assert window_engine.input_gain("s1") == pytest.approx(batch_engine.input_gain("s1"),
                                                           abs=1e-12)
    assert engine.input_gain("s1") == pytest.approx(batch_engine.input_gain("s1"), abs=1e-12)
    assert batch_engine.input_gain("s1") > 1.005  # the falling rest was followed
