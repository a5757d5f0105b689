"""The reduction of long training runs (strain_comp.offline.reduce) against truth: known
reversal and hold times, a tone the decimation would alias, and the full-data error of a
fit on the reduction against the fit on every sample."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from strain_comp.io.recording import Recording
from strain_comp.models import Segment
from strain_comp.offline import rig
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.reduce import (
    REVERSAL_FRACTION,
    lowpass,
    reduce_segment,
    reduce_segments,
    turning_points,
)

FS = 1000.0
FACTOR = 20


def _protocol() -> tuple[np.ndarray, np.ndarray, list[float], list[float]]:
    """t, strain of ramps (10 %/s) between levels, with holds: reversal times, hold edges."""
    levels = [0.0, 12.0, 4.0, 20.0, 20.0, 6.0, 15.0, 0.0]  # the 20 -> 20 leg is a 3 s hold
    t_knots, s_knots = [0.0], [0.0]
    for a, b in itertools.pairwise(levels):
        t_knots.append(t_knots[-1] + (abs(b - a) / 10.0 if b != a else 3.0))
        s_knots.append(b)
    t = np.arange(0.0, t_knots[-1], 1.0 / FS)
    s = np.interp(t, t_knots, s_knots)
    reversals = [t_knots[i] for i in (1, 2, 4, 5, 6)]  # 12, 4, 20 (end of hold), 6, 15
    holds = [t_knots[3], t_knots[4]]
    return t, s, reversals, holds


def test_reversals_and_holds_survive_where_they_were() -> None:
    t, s, reversals, holds = _protocol()
    rng = np.random.default_rng(0)
    r = 100.0 + 2.0 * s + 0.05 * rng.standard_normal(t.size)
    reduced = reduce_segment(Segment(t, r, s), FACTOR)
    assert reduced.t.size < t.size / FACTOR * 1.2
    span = float(np.ptp(s))
    for when in reversals + holds:
        i = int(np.argmin(np.abs(reduced.t - when)))
        assert abs(reduced.t[i] - when) <= FACTOR / FS, when  # a sample at the corner
        true = float(np.interp(when, t, s))
        assert abs(reduced.s[i] - true) <= 0.01 * span, when  # at its value
    # and the reduced reference peaks where the full one does
    assert np.isclose(reduced.s.max(), s.max(), atol=1e-9)
    assert np.isclose(reduced.s.min(), s.min(), atol=1e-9)


def test_turning_points_against_a_slow_scan() -> None:
    """The peak-valley scan equals a plain Python one (alternating extremes that swing at
    least ``swing`` to the next) on a noisy multi-level signal."""
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.standard_normal(3000))
    swing = 5.0

    def slow(x: np.ndarray) -> list[int]:
        out: list[int] = []
        trend, hi, lo = 0, 0, 0
        for i in range(1, x.size):
            hi = i if (trend >= 0 and x[i] > x[hi]) else hi
            lo = i if (trend <= 0 and x[i] < x[lo]) else lo
            if trend == 0 and x[hi] - x[lo] >= swing:
                out.append(min(hi, lo))
                trend = 1 if hi > lo else -1
                hi, lo = (hi, i) if trend > 0 else (i, lo)
            elif trend > 0 and x[hi] - x[i] >= swing:
                out.append(hi)
                trend, lo = -1, i
            elif trend < 0 and x[i] - x[lo] >= swing:
                out.append(lo)
                trend, hi = 1, i
        return out

    got = turning_points(x, swing)
    assert got.tolist() == slow(x)
    assert np.all(np.abs(np.diff(x[got])) >= swing)


def test_decimation_is_anti_aliased() -> None:
    """A tone at the new sample rate fs / f would alias to a constant offset in every f-th
    sample; the low-pass removes it (and keeps a slow ramp)."""
    t = np.arange(20000) / FS
    ramp = 3.0 * t
    tone = np.sin(2 * np.pi * (FS / FACTOR) * t + 0.7)
    plain = (ramp + tone)[::FACTOR] - ramp[::FACTOR]
    assert abs(plain.mean()) > 0.6  # what plain decimation does
    filtered = lowpass(ramp + tone, FACTOR)[FACTOR:-FACTOR:FACTOR] - ramp[FACTOR:-FACTOR:FACTOR]
    assert np.abs(filtered).max() < 1e-6


def test_below_the_budget_nothing_changes() -> None:
    seg = Segment(np.arange(100.0), np.arange(100.0) + 1.0, np.arange(100.0))
    segments, factor = reduce_segments([seg, seg], budget=200)
    assert factor == 1 and segments[0] is seg
    assert reduce_segments([seg, seg], budget=199)[1] == 2
    assert REVERSAL_FRACTION < 0.05


def test_reduced_fit_error_on_the_full_data_is_close_to_the_full_fit() -> None:
    """APL on the rig's rates run resampled to 125 Hz with read-out noise (15 000 samples):
    fitted on a reduction by 7 and on every sample, both scored on every sample (the
    ``fit_rmse`` the provenance reports)."""
    run = rig.simulate("rates", seed=0, duration=120.0)
    s1 = run["s1"]
    t = np.arange(0.0, s1.t[-1], 0.008)
    rng = np.random.default_rng(1)
    r = np.interp(t, s1.t, s1.r) + 0.002 * np.std(s1.r) * \
        rng.standard_normal(t.size)
    rec = Recording("s1", t, r, np.interp(t, s1.t, s1.s))
    full = fit_sensor([rec], "apl", name="s1")
    reduced = fit_sensor([rec], "apl", name="s1", options={"fit_budget": t.size // 7})
    assert "fit_reduction" not in full.provenance
    assert reduced.provenance["fit_reduction"]["factor"] >= 7
    assert reduced.provenance["n_samples"] == full.provenance["n_samples"] == t.size
    # close: within 5 % of the full fit's error plus 0.1 % of the 20 % strain span
    span = float(np.ptp(rec.s))
    assert reduced.provenance["fit_rmse"] <= 1.05 * full.provenance["fit_rmse"] + 1e-3 * span
    assert full.provenance["fit_rmse"] < 0.01 * span  # and both are good fits


def test_fit_budget_option() -> None:
    """``--option fit_budget=N`` sets the budget; a bad value is an InputError naming it."""
    from strain_comp.errors import InputError

    t, s, _, _ = _protocol()
    rec = Recording("s1", t, 100.0 + 2.0 * s + 0.01 * np.sin(t), s)
    cal = fit_sensor([rec], "cubic", name="s1", options={"fit_budget": 2000})
    assert cal.provenance["fit_reduction"]["factor"] == -(-t.size // 2000)
    assert "fit_budget" not in cal.provenance["options"]
    for bad in (10, "many", 5000.5, True):
        with pytest.raises(InputError, match="fit_budget"):
            fit_sensor([rec], "cubic", name="s1", options={"fit_budget": bad})


def test_a_noisy_signal_cannot_inflate_the_reduction() -> None:
    """White noise far above the reversal swing: the reduction stays near n / f samples."""
    rng = np.random.default_rng(2)
    n = 100_000
    t = np.arange(n) / FS
    seg = Segment(t, 100.0 + rng.standard_normal(n), rng.standard_normal(n))
    reduced = reduce_segment(seg, FACTOR)
    assert reduced.t.size <= 4 * n // FACTOR
