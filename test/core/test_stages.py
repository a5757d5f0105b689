"""The per-sample stages (``strain_comp.core.stages``) against independent numpy
references, and each lift over a batch against its scalar kernel sample by sample: the
one rule ``Engine.step``, ``Engine.run`` and the array tick share."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strain_comp.base import samples as sc
from strain_comp.core.stages import (
    RANGE_COLUMNS,
    bound,
    bound_all,
    clamp,
    hold,
    model_read,
    saturate_all,
)

RNG = np.random.default_rng(7)


def _row(**values: float) -> np.ndarray:
    base = {"r_lo": 95.0, "r_hi": 205.0, "s_lo": -1.0, "s_hi": 51.0, "slope_lo": 0.0,
            "slope_hi": 0.0, "reach_lo": -math.inf, "reach_hi": math.inf, "saturate": 0.0}
    base.update(values)
    return np.array([base[name] for name in RANGE_COLUMNS])


def _bound_reference(ohm: np.ndarray, strain: np.ndarray, row: np.ndarray) -> np.ndarray:
    """The range stage as the engine wrote it with numpy: clip, plus the slope times the
    resistance beyond the range, clipped to the reach."""
    r_lo, r_hi, s_lo, s_hi, lo, hi, reach_lo, reach_hi, _ = row
    out = np.clip(strain, s_lo, s_hi)
    out = out + np.where(ohm > r_hi, hi * (ohm - r_hi), 0.0) \
        + np.where(ohm < r_lo, lo * (ohm - r_lo), 0.0)
    return np.clip(out, reach_lo, reach_hi)


@pytest.mark.parametrize("row", [
    _row(),
    _row(slope_lo=0.3, slope_hi=0.5, reach_lo=-3.0, reach_hi=80.0),
    _row(slope_lo=-0.2, slope_hi=0.1, reach_lo=0.0, reach_hi=60.0, saturate=1.0),
], ids=["clamp", "extend", "extend-saturate"])
def test_bound_is_the_numpy_range_rule_and_its_lift_the_scalar(row: np.ndarray) -> None:
    ohm = RNG.uniform(20.0, 400.0, 2000)
    strain = RNG.uniform(-20.0, 90.0, 2000)
    lifted = bound_all(ohm, strain, row)
    np.testing.assert_array_equal(lifted, _bound_reference(ohm, strain, row))
    assert lifted.tolist() == [bound(o, s, row) for o, s in zip(ohm, strain, strict=True)]


def test_model_read_clips_only_when_saturating() -> None:
    ohm = RNG.uniform(20.0, 400.0, 1000)
    plain, saturating = _row(), _row(saturate=1.0)
    np.testing.assert_array_equal(saturate_all(ohm, plain), ohm)
    np.testing.assert_array_equal(saturate_all(ohm, saturating), np.clip(ohm, 95.0, 205.0))
    assert [model_read(o, saturating) for o in ohm] == np.clip(ohm, 95.0, 205.0).tolist()
    assert math.isnan(clamp(math.nan, 0.0, 1.0))


def test_hold_forward_fills_the_used_samples_and_counts_statuses() -> None:
    status = np.array([sc.NOT_FINITE, sc.GOOD, sc.NON_POSITIVE, sc.OUT_OF_RANGE, sc.GAP_RESET,
                       sc.TIME_NOT_INCREASING], dtype=np.int8)
    reset = np.array([False, False, False, False, True, False])
    idx = np.array([1, 3, 4])
    strain, direction, oor, counts = hold(status, reset, idx, np.array([1.0, 2.0, 3.0]),
                                          np.array([1, -1, 0], dtype=np.int8), 9.0, 1)
    assert strain.tolist() == [9.0, 1.0, 1.0, 2.0, 3.0, 3.0]
    assert direction.tolist() == [1, 1, 1, -1, 0, 0]
    assert oor.tolist() == [False, False, False, True, False, False]
    assert counts.tolist() == [*np.bincount(status, minlength=len(sc.Status)).tolist(), 1]
