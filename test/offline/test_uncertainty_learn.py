"""The uncertainty learned from runs left out, and the standard deviation where the
commands give it (replay's bag, sc.estimate, evaluate's coverage)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import cubic_cal

import strain_comp as sc
from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.metrics import Z_95
from strain_comp.core.uncertainty import FEATURES, Uncertainty
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_auto, fit_sensor
from strain_comp.offline.replay import replay_bag
from strain_comp.offline.uncertainty import fit_weights

BAND = Uncertainty.from_weights({"bias": -2.0, "loading": 0.5, "level": 1.5})


def test_the_likelihood_finds_a_known_variance_model() -> None:
    """Residuals drawn from N(0, exp(w . x)): the weights come back, and the band holds 95 %
    of them."""
    rng = np.random.default_rng(1)
    truth = np.array([-1.0, 0.8, -0.4, 0.3, 0.0, 0.2, 1.2])
    runs = []
    for _ in range(3):
        n = 20_000
        d = rng.choice([-1.0, 0.0, 1.0], n)
        x = np.column_stack([np.ones(n), d > 0, d < 0, rng.uniform(0, 3, n), np.zeros(n),
                             rng.uniform(0, 2, n), rng.uniform(0, 1, n)])
        runs.append((x, rng.normal(0.0, np.exp(0.5 * x @ truth))))
    w, factor = fit_weights(runs)
    assert factor == pytest.approx(1.0, abs=0.03)  # Gaussian: the likelihood's band is right
    keep = [i for i, f in enumerate(FEATURES) if f != "outside"]
    np.testing.assert_allclose(w[keep], truth[keep], atol=0.05)
    assert w[FEATURES.index("outside")] == pytest.approx(0.0, abs=1e-6)  # never varied
    x = np.concatenate([r[0] for r in runs])
    e = np.concatenate([r[1] for r in runs])
    assert np.mean(np.abs(e) <= Z_95 * np.exp(0.5 * x @ w)) == pytest.approx(0.95, abs=0.002)


def test_the_factor_is_the_geometric_mean_of_the_runs_left_out() -> None:
    """Three runs of constant noise, sigma 1, 1 and 4 (bias only): each run's factor is the
    95 % quantile of its |e| over the sigma the other two give (by hand: their pooled
    variance, each run weighing the same), over 1.96; the factor is their geometric mean
    (0.34, 0.34, 4 -> 0.78; the median, 0.34, ignored the wide run), and the bias weight
    the pooled variance of all three times it squared."""
    rng = np.random.default_rng(3)
    sigmas = (1.0, 1.0, 4.0)
    runs = []
    for sd in sigmas:
        x = np.zeros((20_000, len(FEATURES)))
        x[:, 0] = 1.0
        runs.append((x, rng.normal(0.0, sd, 20_000)))
    var = [float(np.mean(e ** 2)) for _, e in runs]
    by_hand = [float(np.quantile(np.abs(e), 0.95)) / Z_95
               / np.sqrt(np.mean([v for k, v in enumerate(var) if k != j]))
               for j, (_, e) in enumerate(runs)]
    w, factor = fit_weights(runs)
    assert factor == pytest.approx(np.exp(np.mean(np.log(by_hand))), rel=1e-4)
    assert factor == pytest.approx((0.343 ** 2 * 4.0) ** (1 / 3), rel=0.05)
    assert w[0] == pytest.approx(np.log(np.mean(var) * factor ** 2), abs=1e-4)
    np.testing.assert_allclose(w[1:], 0.0, atol=1e-6)


def run(seed: int, gain: float) -> Recording:
    """Two load cycles of the conftest gauge at 20 Hz, its sensitivity ``gain`` x."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 0.05)
    s = 20.0 * np.sin(np.pi * t / 15.0) ** 2
    r = 100.0 + gain * 2.0 * s + rng.normal(0.0, 0.3, t.size)
    return Recording("s1", t, r, s)


def test_fit_learns_a_band_from_several_runs_only() -> None:
    """``fit --model auto`` on one group: a band learned from two runs or more by leaving
    each out; a plain fit learns none."""
    runs = [run(i, g) for i, g in enumerate((1.0, 1.1, 0.9))]
    assert fit_auto(runs[:1], name="s1", candidates=("cubic",)).uncertainty is None
    assert fit_sensor(runs, "cubic", name="s1").uncertainty is None
    cal = fit_auto(runs, name="s1", candidates=("cubic",), groups=["1"] * len(runs))
    assert cal.uncertainty is not None and cal.uncertainty.runs == 3
    assert cal.uncertainty.samples > 3000
    ev = evaluate_recordings({"s1": run(7, 1.05)}, Calibration({"s1": cal})).sensors["s1"]
    assert ev.coverage_95 is not None and 0.0 <= ev.coverage_95 <= 1.0
    assert ev.to_dict()["coverage_95"] == ev.coverage_95
    assert ev.std.size == ev.t.size


def test_replay_and_estimate_give_the_engines_std(tmp_path: Path) -> None:
    cal = Calibration({"s1": replace(cubic_cal("s1"), uncertainty=BAND)})
    t = 100.0 + np.arange(400) * 0.01
    r = 150.0 + 40.0 * np.sin(t)
    with BagWriter(tmp_path / "in.mcap") as w:
        w.write_float64("/s1/resistance", t, r)
    replay_bag(tmp_path / "in.mcap", cal, tmp_path / "out.mcap")
    out = read_bag(tmp_path / "out.mcap")
    expected = Engine(cal).run("s1", t, r).std
    assert expected is not None
    np.testing.assert_allclose(out.series["/s1/strain_std"].values, expected, rtol=1e-12)
    assert "/s1/strain_std_stamped" in out.types
    np.testing.assert_allclose(sc.estimate(cal, t, r).std, expected, rtol=1e-12)
    plain = Calibration({"s1": cubic_cal("s1")})
    replay_bag(tmp_path / "in.mcap", plain, tmp_path / "plain.mcap")
    assert "/s1/strain_std" not in read_bag(tmp_path / "plain.mcap").types
    assert np.isnan(sc.estimate(plain, t, r).std).all()
