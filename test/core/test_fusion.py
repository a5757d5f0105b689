"""Sparse references fused into the output gain and offset (strain_comp.core.fusion),
against a run whose true gain and offset are known."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from strain_comp.core.fusion import GAIN_SD, NOISE_SHARE, OFFSET_SHARE, OutputFusion, SparseFusion

GAIN, OFFSET = 1.25, -1.5
"""The truth: reference = GAIN x estimate + OFFSET (+ noise)."""


def _fusion(span: float) -> OutputFusion:
    """A filter scaled for a calibrated strain span of ``span``."""
    return OutputFusion(span)


def run(seconds: float = 1200.0, rate: float = 20.0, seed: int = 3
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, estimate, reference) of a sensor cycled between 0 and 40 % strain whose
    estimate reads a gain and offset off, with noise on the reference."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    truth = 20.0 * (1.0 - np.cos(2 * np.pi * t / 17.0))
    estimate = (truth - OFFSET) / GAIN
    reference = truth + rng.normal(0.0, 0.5, t.size)
    return t, estimate, reference


def test_sparse_noisy_references_recover_the_gain_and_offset() -> None:
    t, estimate, reference = run()
    sparse = SparseFusion(_fusion(40.0), every=20.0)
    fused = sparse.run(t, estimate, reference, np.ones(t.size, bool))
    fusion = sparse.fusion
    assert fusion.n_used == 59 and fusion.n_refused == 0
    assert fusion.gain == pytest.approx(GAIN, abs=0.02)
    assert fusion.offset == pytest.approx(OFFSET, abs=0.5)
    truth = GAIN * estimate + OFFSET
    late = t > 600.0
    raw_error = np.sqrt(np.mean((estimate - truth)[late] ** 2))
    fused_error = np.sqrt(np.mean((fused - truth)[late] ** 2))
    assert fused_error < 0.1 * raw_error
    st = fusion.state()
    assert st["gain_sd"] < 0.5 * GAIN_SD
    assert st["last_reference_t"] == pytest.approx(1180.0)


def test_a_reference_changes_nothing_before_its_time() -> None:
    t, estimate, reference = run(seconds=300.0)
    every = np.ones(t.size, bool)
    base = SparseFusion(_fusion(40.0), every=30.0).run(t, estimate, reference,
                                                                      every)
    cut = 150.0
    changed = np.where(t > cut - 1e-9, reference + 7.0, reference)  # from the 150 s one on
    other = SparseFusion(_fusion(40.0), every=30.0).run(t, estimate, changed,
                                                                       every)
    at_or_before = t <= cut + 1e-9
    assert np.array_equal(base[at_or_before], other[at_or_before])
    assert not np.allclose(base[~at_or_before], other[~at_or_before])
    # before the first reference (30 s) the output is the engine's
    assert np.array_equal(base[t <= 30.0 + 1e-9], estimate[t <= 30.0 + 1e-9])
    assert not np.array_equal(base[t > 30.0 + 1e-9], estimate[t > 30.0 + 1e-9])


def test_pieces_give_the_one_run_and_the_nearest_sample_is_used() -> None:
    t, estimate, reference = run(seconds=300.0, rate=3.0)
    ok = np.ones(t.size, bool)
    ok[::7] = False  # some samples not eligible (bad, or no reference)
    whole = SparseFusion(_fusion(40.0), every=25.0)
    one = whole.run(t, estimate, reference, ok)
    pieces = SparseFusion(_fusion(40.0), every=25.0)
    edges = [0, 1, 74, 75, 76, 300, 301, 640, t.size]
    parts = [pieces.run(t[a:b], estimate[a:b], reference[a:b], ok[a:b])
             for a, b in itertools.pairwise(edges)]
    assert np.array_equal(one, np.concatenate(parts))
    assert whole.fusion.gain == pieces.fusion.gain
    # a slow independent reading of the rule: the used references' times
    times = []
    for k in range(1, 12):
        target = k * 25.0
        cand = np.flatnonzero(ok)
        i = cand[np.argmin(np.abs(t[cand] - target))]
        times.append(t[i])
    assert whole.fusion.n_used == len(times)
    assert whole.fusion.last_reference_t == pytest.approx(times[-1])


def test_one_reference_at_rest_moves_the_offset_and_one_at_strain_mostly_the_gain() -> None:
    rest = _fusion(40.0)
    assert rest.update(1.0, 0.0, 1.0) is None
    # eq. (3) with h = (0, 1): K_b = P_b / (P_b + R), the first reference has no walk
    k_b = OFFSET_SHARE ** 2 / (OFFSET_SHARE ** 2 + NOISE_SHARE ** 2)
    assert rest.gain == 1.0 and rest.offset == pytest.approx(k_b * 1.0)
    strained = _fusion(40.0)
    assert strained.update(1.0, 30.0, 36.0) is None  # a sensitivity 20 % low
    assert strained.gain - 1.0 > 0.15
    assert abs(strained.offset) < 0.1 * 30.0 * (strained.gain - 1.0)


def test_the_gate_refuses_an_outlier_and_the_state_stays() -> None:
    t, estimate, reference = run(seconds=600.0)
    sparse = SparseFusion(_fusion(40.0), every=30.0)
    sparse.run(t, estimate, reference, np.ones(t.size, bool))
    fusion = sparse.fusion
    before = fusion.state()
    reason = fusion.update(700.0, 20.0, 400.0)
    assert reason is not None and reason.startswith("beyond the gate")
    assert fusion.refused["beyond the gate"] == 1 and fusion.n_used == before["n_used"]
    assert (fusion.gain, fusion.offset) == (before["gain"], before["offset"])
    assert fusion.update(701.0, 20.0, GAIN * 20.0 + OFFSET) is None  # a good one still goes


@pytest.mark.parametrize("reference, reason", [
    (math.nan, "non-finite reference"), (math.inf, "non-finite reference"),
    ("12.0", "not a number"), (None, "not a number"), (True, "not a number")])
def test_non_finite_or_wrong_typed_references_are_refused(reference: object, reason: str
                                                          ) -> None:
    fusion = _fusion(40.0)
    assert fusion.update(1.0, 10.0, reference) == reason
    assert fusion.refused[reason] == 1 and fusion.n_used == 0
    assert (fusion.gain, fusion.offset) == (1.0, 0.0)
    assert fusion.update(2.0, math.nan, 10.0) == "no estimate yet"
    assert fusion.update(3.0, 10.0, 11.0) is None
    assert fusion.update(2.5, 10.0, 11.0) == "time before the previous reference"
    values = fusion.diagnostic_values()
    assert values["fusion_n_used"] == "1" and values["fusion_n_refused"] == "3"


def _fused_by_filtering(fusion: SparseFusion, t: np.ndarray, estimate: np.ndarray,
                        reference: np.ndarray, eligible: np.ndarray) -> np.ndarray:
    """``SparseFusion.run`` as first written: the eligible samples filtered after each
    reference used (a slow, independent reading of the same rule)."""
    out = np.array(estimate, dtype=np.float64)
    if fusion.origin is None:
        fusion.origin = float(t[0])
    idx, pos, half = np.flatnonzero(eligible), 0, 0.5 * fusion.every
    while True:
        target = fusion.origin + fusion.k * fusion.every
        j = int(np.searchsorted(t[idx], target, side="left"))
        if j == idx.size:
            if idx.size:
                last = int(idx[-1])
                fusion.before = (float(t[last]), float(estimate[last]), float(reference[last]))
            break
        after = int(idx[j])
        candidates = []
        if j > 0:
            i = int(idx[j - 1])
            candidates.append((target - t[i], i, (t[i], estimate[i], reference[i])))
        elif fusion.before is not None:
            candidates.append((target - fusion.before[0], -1, fusion.before))
        candidates.append((t[after] - target, after,
                           (t[after], estimate[after], reference[after])))
        distance, index, (t_ref, s_hat, y) = min(candidates, key=lambda c: c[0])
        if distance <= half:
            out[pos:index + 1] = fusion.fusion.apply(estimate[pos:index + 1])
            pos = index + 1
            fusion.fusion.update(float(t_ref), float(s_hat), float(y))
            idx = idx[idx > index]
            fusion.before = None
        fusion.k = max(fusion.k + 1, math.floor((t_ref - fusion.origin) / fusion.every) + 1)
    out[pos:] = fusion.fusion.apply(estimate[pos:])
    return out


def test_run_equals_the_samples_filtered_reference_by_reference() -> None:
    """The bisection over the eligible samples not yet passed (a cost linear in the
    samples, however many references a piece holds) gives the same outputs and state,
    piece by piece, with gaps, ineligible samples and time running back."""
    t, estimate, reference = run(seconds=900.0, rate=4.0, seed=5)
    rng = np.random.default_rng(1)
    t = t + np.where(rng.random(t.size) < 0.01, -0.3, 0.0)  # a few steps back
    t[1500:] += 40.0  # a silence longer than the spacing
    ok = rng.random(t.size) > 0.2
    reference = np.where(rng.random(t.size) < 0.02, reference + 300.0, reference)  # gated
    fast = SparseFusion(_fusion(40.0), every=2.5)
    slow = SparseFusion(_fusion(40.0), every=2.5)
    for a, b in itertools.pairwise([0, 1, 700, 701, 2000, t.size]):
        part = (t[a:b], estimate[a:b], reference[a:b], ok[a:b])
        assert np.array_equal(fast.run(*part), _fused_by_filtering(slow, *part))
        assert fast.fusion.state() == slow.fusion.state()
        assert (fast.k, fast.before) == (slow.k, slow.before)
    assert fast.fusion.n_used > 300 and fast.fusion.n_refused > 0


def test_the_filter_on_a_calibrations_output_map_fuses_as_one_on_top() -> None:
    """A calibration with an output map (a0, b0): the filter that carries the sensor's
    output map itself (``start``) fuses every sample as a filter of a second map on the
    engine's estimate would (the relative filter, prior (1, 0), written out here), and its
    state is that map composed: gain g a0, offset g b0 + b."""
    a0, b0 = 0.8, 2.5
    t, estimate, reference = run(seconds=600.0)
    engine_out = a0 * estimate + b0  # the engine's estimate, through the calibration's map
    on_top, itself = OutputFusion(40.0), OutputFusion(40.0, start=(a0, b0))
    assert itself.apply(engine_out[5]) == pytest.approx(engine_out[5], rel=1e-12)
    for k in range(0, t.size, 97):  # references now and then, some beyond the gate
        y = reference[k] + (60.0 if k % 5 == 0 else 0.0)
        assert (on_top.update(t[k], engine_out[k], y) is None) == \
            (itself.update(t[k], engine_out[k], y) is None)
        g, b = on_top.gain, on_top.offset
        np.testing.assert_allclose(itself.apply(engine_out), g * engine_out + b,
                                   rtol=1e-9, atol=1e-9)
        assert itself.gain == pytest.approx(g * a0, rel=1e-9)
        assert itself.offset == pytest.approx(g * b0 + b, rel=1e-9, abs=1e-9)
    assert on_top.n_used > 20 and on_top.n_refused > 5
