"""Baseline tracking over many stretches per engine call (strain_comp.core.tracking) against
the slow reference: one engine call per judged stretch, judged before the next runs.

Bit for bit: strain, direction, status, resistance, resets and corrector events, the
counters and /diagnostics values, the tare gain and what the tracker remembers.
"""

from __future__ import annotations

from dataclasses import fields, replace
from itertools import pairwise

import numpy as np
import pytest
from conftest import TRACK_R0, staircase, staircase_calibration, tracking_gauge

from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.outputs import BatchOutput, concatenate
from strain_comp.core.tracking import BaselineTracker, _Stretch


def chunked_run(tracker: BaselineTracker, name: str, t: np.ndarray, r: np.ndarray
                ) -> BatchOutput:
    """The reference: ``engine.run`` once per piece ending with a stretch of two samples
    or more, the kept stretch judged (``advance``) before each piece runs."""
    index = np.floor((t - tracker.origin.setdefault(name, float(t[0])))
                     / tracker.policy.chunk_seconds)
    edges = np.flatnonzero(np.diff(index)) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [t.size]])
    judged = ends - starts >= 2
    if name in tracker.pending and index[0] == tracker.pending[name].index:
        judged[0] = True
    outs = []
    for a, b in pairwise([0, *ends[judged & (ends < t.size)].tolist(), t.size]):
        tracker.advance(name, float(t[a]))
        out = tracker.engine.run(name, t[a:b], r[a:b])
        last = int(np.searchsorted(index[a:b], index[b - 1]))
        if last > 0:
            tracker.pending.pop(name, None)
            tracker.last_hold.pop(name, None)
        stretch = tracker.pending.setdefault(name, _Stretch(float(index[b - 1])))
        stretch.add(t[a + last:b], replace(out, **{
            f.name: getattr(out, f.name)[last:] for f in fields(out)
            if getattr(out, f.name) is not None}))
        outs.append(out)
    return concatenate(outs)


def drifting_rest(seed: int, seconds: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """The staircase at ``rate`` samples a second, jittered, whose rest falls by a random
    step after every release, drifts back up between, with noise, a few gaps, repeated
    and backwards stamps and bad samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate) + rng.uniform(0.0, 0.3 / rate)
    t = np.sort(t)
    s = staircase(t)
    released = np.clip(np.floor((t - 10.0) / 20.0), 0.0, None)
    falls = 1.0 - np.cumsum(rng.uniform(0.0, 0.02, int(released.max()) + 1))
    rest = falls[released.astype(int)] * (1.0 + 1e-4 * ((t - 10.0) % 20.0))
    r = tracking_gauge(s) * rest + rng.normal(0.0, 0.05, t.size)
    for k in rng.integers(1, t.size - 1, 6):
        t[k] = t[k - 1]  # a repeated stamp
    for k in rng.integers(1, t.size - 1, 3):
        t[k] = t[k - 1] - 0.5  # a stamp that runs back
    r[rng.integers(0, t.size, 5)] = np.nan
    gap = rng.integers(t.size // 3, t.size)
    t[gap:] += 30.0  # a gap long enough to reset
    return t, r


def assert_same(cal: Calibration, t: np.ndarray, r: np.ndarray, windows: list[int]) -> int:
    """Run ``t``, ``r`` in ``windows`` (split points) both ways; assert equal; return how
    many corrections the tracker made."""
    ref_engine, new_engine = Engine(cal), Engine(cal)
    ref, new = BaselineTracker(ref_engine), BaselineTracker(new_engine)
    bounds = [0, *windows, t.size]
    want = concatenate([chunked_run(ref, "s1", t[a:b], r[a:b]) for a, b in pairwise(bounds)])
    got = concatenate([new.run("s1", t[a:b], r[a:b]) for a, b in pairwise(bounds)])
    for f in fields(BatchOutput):
        a, b = getattr(want, f.name), getattr(got, f.name)
        assert (a is None) == (b is None), f.name
        if a is not None:
            assert a.dtype == b.dtype, f.name
            np.testing.assert_array_equal(a, b, err_msg=f.name, strict=True)
    assert new_engine.health() == ref_engine.health()
    assert new_engine.health()["s1"].to_diagnostic() == ref_engine.health()["s1"].to_diagnostic()
    assert new_engine.input_gain("s1") == ref_engine.input_gain("s1")
    assert (new.applied, new.last_hold) == (ref.applied, ref.last_hold)
    assert new.pending.keys() == ref.pending.keys()
    for name, kept in ref.pending.items():
        assert kept.index == new.pending[name].index
        assert [c.tobytes() for c in kept.columns] == [
            c.tobytes() for c in new.pending[name].columns]
    return round(ref_engine.health()["s1"].baseline_tracked_s)


@pytest.mark.parametrize("seed", range(6))
def test_many_stretches_per_call_equal_one_call_per_stretch(seed: int) -> None:
    """Drifting rests (many corrections, some undone), noise, gaps, repeated and backwards
    stamps and bad samples, in one call and in random streamed windows, at 10 and 3 samples
    a second and at one sample every 0.7 s (stretches too short to judge)."""
    cal = staircase_calibration()
    rng = np.random.default_rng(100 + seed)
    rate = (10.0, 3.0, 1.0 / 0.7)[seed % 3]
    t, r = drifting_rest(seed, 250.0, rate)
    tracked = assert_same(cal, t, r, [])
    windows = sorted(set(rng.integers(1, t.size - 1, 12).tolist()))
    assert assert_same(cal, t, r, windows) == tracked
    if rate > 2.0:
        assert tracked > 5  # the rest was followed: corrections were made


def test_many_stretches_per_call_equal_with_a_pair_statistic_and_a_despiker() -> None:
    """The input corrector's state (pair means, despiker) rewinds with the model's."""
    sensor = staircase_calibration().sensors["s1"]
    cal = Calibration({"s1": replace(sensor, input=replace(
        sensor.input, alternation=True, pair="upper", despike=8.0))})
    t, r = drifting_rest(7, 250.0, 10.0)
    r = r + np.where(np.arange(t.size) % 2, 0.3, -0.3)
    r[800] += 40.0  # a spike
    assert assert_same(cal, t, r, [333, 1200]) > 5


def test_a_long_steady_rest_is_run_in_few_engine_calls() -> None:
    """A fallen rest held for 2000 s at 10 samples a second: the tracker corrects it, then
    the engine runs far fewer calls than the 2000 judged stretches."""
    cal = staircase_calibration()
    t = np.arange(0.0, 2000.0, 0.1)
    r = np.full(t.size, 0.99 * TRACK_R0)
    engine = Engine(cal)
    calls = 0
    run = engine.run

    def counted(*args: object, **kwargs: object) -> BatchOutput:
        nonlocal calls
        calls += 1
        return run(*args, **kwargs)  # type: ignore[arg-type]

    engine.run = counted  # type: ignore[method-assign]
    BaselineTracker(engine).run("s1", t, r)
    assert engine.input_gain("s1") == pytest.approx(1.0 / 0.99, rel=1e-9)
    assert calls < 200
    assert_same(cal, t, r, [5000])


def test_many_stretches_per_call_equal_without_a_rest_resistance() -> None:
    """A calibration that stores no rest resistance is never corrected: equal outputs, and
    the holds remembered end alike."""
    sensor = staircase_calibration().sensors["s1"]
    cal = Calibration({"s1": replace(sensor, rest_resistance=None)})
    t, r = drifting_rest(8, 120.0, 10.0)
    assert assert_same(cal, t, r, [400]) == 0
