"""Recordings from bags: per-sensor and array topics, alignment of reference and temperature."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from strain_comp.io.bag import BagWriter
from strain_comp.io.recording import align, load_recordings

T = np.arange(200) * 0.1


def test_align_exact_interpolated_and_nan_outside() -> None:
    v = np.sin(T)
    np.testing.assert_array_equal(align(T, T, v), v)
    t = np.array([-1.0, 0.05, 5.55, 19.9, 30.0])
    out = align(t, T, v)
    assert np.isnan(out[0]) and np.isnan(out[-1])
    np.testing.assert_allclose(out[1:4], np.interp(t[1:4], T, v))
    # unsorted source with a NaN sample: sorted, NaN dropped
    order = np.random.default_rng(0).permutation(T.size)
    vv = v.copy()
    vv[order[0]] = np.nan
    got = align(t[1:4], T[order], vv[order])
    keep = ~np.isnan(vv)
    np.testing.assert_allclose(got, np.interp(t[1:4], T[keep], v[keep]))


def test_per_sensor_and_array_topics(tmp_path: Path) -> None:
    path = tmp_path / "b.mcap"
    r2 = np.column_stack([10 + T, 20 + T, 30 + T])
    s2 = np.column_stack([T, 2 * T, 3 * T])
    with BagWriter(path) as w:
        w.write_float64("/robot/finger/resistance", T, 10 + T)
        w.write_float64("/robot/finger/strain_reference", T + 0.05, T + 0.05)  # offset stamps
        w.write_temperature("/robot/finger/temperature", T[::10], 20 + T[::10])
        w.write_float64_array("/arr/resistance", T, r2, ["x", "y", "z"])
        w.write_float64_array("/arr/strain_reference", T, s2[:, ::-1], ["z", "y", "x"])
        w.write_float64("/lonely/strain_reference", T, T)
    recs, problems = load_recordings(path)
    assert set(recs) == {"robot/finger", "x", "y", "z"}
    finger = recs["robot/finger"]
    np.testing.assert_array_equal(finger.r, 10 + T)
    assert np.isnan(finger.s[0])  # before the reference's first stamp
    np.testing.assert_allclose(finger.s[1:], T[1:], atol=1e-9)
    np.testing.assert_allclose(finger.temperature[:191], 20 + T[:191], atol=1e-9)
    assert np.isnan(finger.temperature[-1])
    for j, name in enumerate("xyz"):
        rec = recs[name]
        assert (rec.array, rec.index) == ("arr", j)
        np.testing.assert_array_equal(rec.r, r2[:, j])
        np.testing.assert_array_equal(rec.s, s2[:, j])  # matched by label, exact stamps
    assert any("/lonely/strain_reference" in p for p in problems)


def test_resistance_without_reference(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    with BagWriter(path) as w:
        w.write_float64("/s1/resistance", T, 10 + T)
        w.write_float64_array("/a/resistance", T, np.ones((T.size, 2)), ["p", "q"])
    recs, problems = load_recordings(path)
    assert recs["s1"].s is None and recs["p"].s is None and recs["q"].temperature is None
    assert problems == []


def test_array_sensors_read_their_own_temperature(tmp_path: Path) -> None:
    """An array's sensors read /NAME/temperature each, as replay and the node do
    (docs/design.md, "Topics"); an /ARRAY/temperature names no sensor."""
    path = tmp_path / "arr.mcap"
    with BagWriter(path) as w:
        w.write_float64_array("/arr/resistance", T, np.ones((T.size, 2)), ["p", "q"])
        w.write_temperature("/p/temperature", T, 20 + T)
        w.write_temperature("/arr/temperature", T, 99 + 0 * T)
    recs, _ = load_recordings(path)
    np.testing.assert_array_equal(recs["p"].temperature, 20 + T)
    assert recs["q"].temperature is None
