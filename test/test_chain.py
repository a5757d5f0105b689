"""Measurement-chain statistics and the engine's alternation correction, against injected
effects of known size on short synthetic runs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from strain_comp.core.calibration import (
    Calibration,
    InputSettings,
    load_calibration,
    save_calibration,
)
from strain_comp.core.chain import (
    alternation,
    pair_branch,
    pair_means,
    pair_values,
    quantisation,
    spikes,
)
from strain_comp.core.engine import Engine
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor


def smooth_run(seed: int, n: int = 2000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, R, S): slow triangles at 10 Hz with white noise of 2 ohm on R = 1000 (1 + 0.02 S)."""
    rng = np.random.default_rng(seed)
    t = 0.1 * np.arange(n)
    s = 10.0 * (1.0 - np.abs((t % 40.0) - 20.0) / 20.0)
    return t, 1000.0 * (1.0 + 0.02 * s) + 2.0 * rng.standard_normal(n), s


@pytest.mark.parametrize("amplitude", [5.0, -12.0, 40.0])
def test_alternation_amplitude_is_recovered(amplitude: float) -> None:
    t, r, _ = smooth_run(1)
    found = alternation(r + amplitude * (-1.0) ** np.arange(t.size))
    assert found.present
    assert found.amplitude == pytest.approx(amplitude, abs=0.5)
    assert found.noise == pytest.approx(2.0, rel=0.2)


def test_no_alternation_in_white_noise_or_below_the_noise() -> None:
    t, r, _ = smooth_run(2)
    assert not alternation(r).present
    assert not alternation(r + 0.5 * (-1.0) ** np.arange(t.size)).present


def test_pair_means_cancel_alternation_whatever_its_phase() -> None:
    base = np.linspace(100.0, 200.0, 11)
    for phase in (0, 1):
        out = pair_means(base + 7.0 * (-1.0) ** (np.arange(11) + phase))
        np.testing.assert_allclose(out[1:], 0.5 * (base[1:] + base[:-1]))


def test_spikes_and_quantisation_are_counted() -> None:
    _, r, _ = smooth_run(3)
    r[[100, 700, 1500]] += 400.0
    assert spikes(r) == 3
    assert quantisation(r) is None
    assert quantisation(np.round(r / 5.0) * 5.0) == pytest.approx(5.0)


def test_fit_finds_the_alternation_and_the_engine_cancels_it() -> None:
    t, r, s = smooth_run(4)
    wobble = 30.0 * (-1.0) ** np.arange(t.size)
    clean = fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")
    cal = fit_sensor([Recording("s1", t, r + wobble, s)], "cubic", name="s1")
    assert cal.input.alternation and not clean.input.alternation
    assert "alternation +-30" in cal.provenance["measurement_chain"]
    t2, r2, s2 = smooth_run(5)
    test = {"s1": Recording("s1", t2, r2 - wobble, s2)}  # other phase, other noise
    fixed = evaluate_recordings(test, Calibration({"s1": cal})).sensors["s1"].stats.rmse
    off = replace(cal, input=InputSettings())
    raw = evaluate_recordings(test, Calibration({"s1": off})).sensors["s1"].stats.rmse
    assert fixed < 0.3 * raw


def test_alternation_filter_is_identical_in_step_and_run_and_across_batches() -> None:
    t, r, s = smooth_run(6, n=400)
    r = r + 30.0 * (-1.0) ** np.arange(t.size)
    r[50] = np.nan  # a bad sample: skipped, not averaged
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    whole = Engine(cal).run("s1", t, r).strain
    engine = Engine(cal)
    halves = np.concatenate([engine.run("s1", t[:123], r[:123]).strain,
                             engine.run("s1", t[123:], r[123:]).strain])
    engine = Engine(cal)
    stepped = np.array([engine.step("s1", a, b).strain for a, b in zip(t, r, strict=True)])
    np.testing.assert_allclose(halves, whole, atol=1e-12)
    np.testing.assert_allclose(stepped, whole, atol=1e-12)


def held_run(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, R, S): 0 -> 10 % ramps of 20 s with 80 s holds, 10 Hz, noise 2 ohm."""
    rng = np.random.default_rng(seed)
    t = 0.1 * np.arange(4000)
    phase = t % 200.0
    s = np.interp(phase, [0.0, 20.0, 100.0, 120.0, 200.0], [0.0, 10.0, 10.0, 0.0, 0.0])
    return t, 1000.0 * (1.0 + 0.02 * s) + 2.0 * rng.standard_normal(t.size), s


def one_sided(t: np.ndarray, r: np.ndarray, drop: float = 300.0) -> np.ndarray:
    """Every other sample reads ``drop`` ohm low except for 40 s in each loaded hold
    (``held_run``): an alternation on one side of the signal that switches off and on
    with the sensor's state."""
    return r - drop * ((np.arange(t.size) % 2 == 1) & ~on_window(t))


def on_window(t: np.ndarray) -> np.ndarray:
    return (t % 200.0 >= 40.0) & (t % 200.0 < 80.0)


def test_pair_branch_reads_the_side_from_steps_in_holds() -> None:
    t, r, s = held_run(7)
    still = np.abs(np.gradient(s, t)) < 1e-9
    assert pair_branch(one_sided(t, r), still) == "upper"
    assert pair_branch(2 * r.mean() - one_sided(t, r), still) == "lower"  # high samples
    symmetric = r + np.where(on_window(t), 20.0, 150.0) * (-1.0) ** np.arange(t.size)
    assert pair_branch(symmetric, still) == "mean"
    assert pair_branch(r, still) == "mean"  # no alternation
    # steps while moving do not count (the level moves with them)
    assert pair_branch(one_sided(t, r), np.zeros(t.size, dtype=bool)) == "mean"
    # the upper pair value follows the truth through the steps; the mean steps by half
    upper = pair_values(one_sided(t, r), branch="upper")[1:]
    mean = pair_means(one_sided(t, r))[1:]
    inside = still[1:] & still[:-1]
    assert np.max(np.abs(upper - r[1:])[inside]) < 15.0  # max of two of 2 ohm noise
    assert np.max(np.abs(mean - r[1:])[inside]) > 140.0


def test_fit_reads_a_one_sided_alternation_through_the_upper_pair_value(tmp_path) -> None:
    t, r, s = held_run(8)
    cal = fit_sensor([Recording("s1", t, one_sided(t, r), s)], "cubic", name="s1")
    assert cal.input.alternation and cal.input.pair == "upper"
    assert "read through the pair upper" in cal.provenance["measurement_chain"]
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration({"s1": cal}), path)
    assert load_calibration(path).sensors["s1"].input == cal.input
    t2, r2, s2 = held_run(9)
    test = {"s1": Recording("s1", t2, one_sided(t2, r2), s2)}
    upper = evaluate_recordings(test, Calibration({"s1": cal})).sensors["s1"].stats.rmse
    mean = replace(cal, input=replace(cal.input, pair="mean"))
    stepped = evaluate_recordings(test, Calibration({"s1": mean})).sensors["s1"].stats.rmse
    assert upper < 0.2  # % strain; 2 ohm of noise is 0.01 % strain
    assert stepped > 3.0 * upper
    engine = Engine(Calibration({"s1": cal}))
    steps = np.array([engine.step("s1", a, b).strain for a, b in zip(t2, test["s1"].r,
                                                                       strict=True)])
    np.testing.assert_allclose(steps, Engine(Calibration({"s1": cal})).run(
        "s1", t2, test["s1"].r).strain, atol=1e-12)
