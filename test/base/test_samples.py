"""Sample screening against a slow sample-by-sample reference of the rules."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from strain_comp.base.samples import Status, classify


def classify_slow(t: list[float], r: list[float]) -> list[int]:
    last_good = -math.inf
    out = []
    for ti, ri in zip(t, r, strict=True):
        if not (math.isfinite(ri) and math.isfinite(ti)):
            out.append(Status.NOT_FINITE)
        elif ri <= 0:
            out.append(Status.NON_POSITIVE)
        elif last_good > -math.inf and (ti <= last_good - 5.0 or ti - last_good > 5.0):
            out.append(Status.GAP_RESET)  # a jump longer than the gap: start afresh
            last_good = ti
        elif ti <= last_good:
            out.append(Status.TIME_NOT_INCREASING)
        else:
            out.append(Status.GOOD)
            last_good = ti
    return out


values = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64),
                   st.floats(min_value=0.1, max_value=100.0))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-5, 5), values), max_size=40))
def test_classify_matches_reference(samples: list[tuple[float, float]]) -> None:
    t = [s[0] for s in samples]
    r = [s[1] for s in samples]
    assert classify(t, r).tolist() == [int(v) for v in classify_slow(t, r)]


def test_bag_loop_rejects_only_the_samples_that_go_back() -> None:
    t = np.array([0.0, 1.0, 2.0, 0.5, 1.5, 2.5, 3.0])
    r = np.ones_like(t)
    assert classify(t, r).tolist() == [0, 0, 0, 3, 3, 0, 0]


def test_a_step_back_longer_than_the_gap_starts_afresh_as_in_the_engine() -> None:
    t = np.array([10.0, 11.0, 12.0, 2.0, 3.0, 11.5, 20.0])
    r = np.ones_like(t)
    assert classify(t, r).tolist() == [0, 0, 0, 6, 0, 6, 6]
    assert classify(t, r, gap=100.0).tolist() == [0, 0, 0, 3, 3, 3, 0]
