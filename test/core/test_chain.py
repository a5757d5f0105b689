"""Measurement-chain statistics and the engine's alternation correction, against injected
effects of known size on short synthetic runs."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import fitted, training_recording

from strain_comp.core.calibration import Calibration, InputSettings, SensorCalibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.chain import (
    DESPIKE_K,
    SPIKE,
    alternation,
    correct,
    pair_branch,
    pair_values,
    quantisation,
)
from strain_comp.core.engine import Engine
from strain_comp.core.health import COUNTERS, HealthCounter
from strain_comp.errors import CalibrationError, FitError
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
        out = pair_values(base + 7.0 * (-1.0) ** (np.arange(11) + phase))
        np.testing.assert_allclose(out[1:], 0.5 * (base[1:] + base[:-1]))


def test_quantisation_step_is_read() -> None:
    _, r, _ = smooth_run(3)
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


def assert_step_run_and_pieces_agree(cal: Calibration, t: np.ndarray, r: np.ndarray, *,
                                     cut: int) -> None:
    """Sensor s1's strain from one ``run``, from two ``run`` calls split at ``cut`` and from
    ``step`` sample by sample is the same (the input path keeps its state)."""
    whole = Engine(cal).run("s1", t, r).strain
    engine = Engine(cal)
    halves = np.concatenate([engine.run("s1", t[:cut], r[:cut]).strain,
                             engine.run("s1", t[cut:], r[cut:]).strain])
    engine = Engine(cal)
    stepped = np.array([engine.step("s1", a, b).strain for a, b in zip(t, r, strict=True)])
    np.testing.assert_allclose(halves, whole, atol=1e-12)
    np.testing.assert_allclose(stepped, whole, atol=1e-12)


def test_alternation_filter_is_identical_in_step_and_run_and_across_batches() -> None:
    t, r, s = smooth_run(6, n=400)
    r = r + 30.0 * (-1.0) ** np.arange(t.size)
    r[50] = np.nan  # a bad sample: skipped, not averaged
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    assert_step_run_and_pieces_agree(cal, t, r, cut=123)


def corrected(cal: Calibration, **settings: object) -> Calibration:
    name, sensor = next(iter(cal.sensors.items()))
    return Calibration({name: replace(sensor, input=replace(sensor.input, **settings))})


def test_spikes_are_replaced_before_the_model_and_the_error_falls() -> None:
    t, r, s = smooth_run(7)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    t2, r2, s2 = smooth_run(8)
    spiky = r2.copy()
    rng = np.random.default_rng(9)
    at = 60 + 48 * np.arange(40) + rng.integers(0, 20, 40)  # isolated spikes
    spiky[at] += rng.choice([-1.0, 1.0], at.size) * rng.uniform(50.0, 300.0, at.size)
    test = {"s1": Recording("s1", t2, spiky, s2)}
    raw = evaluate_recordings(test, cal).sensors["s1"].stats.rmse
    fixed = evaluate_recordings(test, corrected(cal, despike=8.0)).sensors["s1"].stats.rmse
    clean = evaluate_recordings({"s1": Recording("s1", t2, r2, s2)}, cal).sensors["s1"]
    assert fixed < 0.3 * raw
    assert fixed < 1.2 * clean.stats.rmse
    seen, _, corrector = correct(t2, spiky, alternating=False)
    assert corrector.n_spikes == at.size
    assert np.max(np.abs(seen - r2)) < 8.0 * 2.0 * np.sqrt(2.0)  # within the threshold


def test_a_spike_on_alternating_input_is_removed_from_the_pair_means() -> None:
    t, r, _ = smooth_run(10)
    r = r + 30.0 * (-1.0) ** np.arange(t.size)
    r[[300, 900]] += [500.0, -400.0]
    seen, _, corrector = correct(t, r, alternating=alternation(r).present)
    assert corrector.n_spikes == 2
    truth = pair_values(r - 30.0 * (-1.0) ** np.arange(t.size))
    truth[[300, 301, 900, 901]] = np.nan  # the spikes' pair means
    assert np.nanmax(np.abs(seen - pair_values(r))[[300, 301, 900, 901]]) > 100.0
    assert abs(seen[300] - truth[299]) < 30.0 and abs(seen[901] - truth[902]) < 30.0


@pytest.mark.parametrize("size", [150.0, -80.0])
def test_a_baseline_step_is_found_its_size_recovered_and_the_error_falls(size: float) -> None:
    t, r, s = smooth_run(11)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    t2, r2, s2 = smooth_run(12)
    stepped = r2 + size * (t2 >= 97.0)
    _, _, corrector = correct(t2, stepped, step_k=16.0,
                              alternating=alternation(stepped).present)
    assert len(corrector.steps) == 1
    found = corrector.steps[0]
    assert found.size == pytest.approx(size, abs=6.0)  # 3 noise sigmas
    assert 97.0 <= found.t < 97.0 + 2.0
    assert found.reading() == (f"baseline step {found.size:+.3g} ohm at t={found.t:.4g} s, "
                               "connector re-seated?")
    test = {"s1": Recording("s1", t2, stepped, s2)}
    raw = evaluate_recordings(test, cal).sensors["s1"].stats.rmse
    fixed = evaluate_recordings(test, corrected(cal, baseline_step=16.0)).sensors["s1"]
    assert fixed.stats.rmse < 0.3 * raw


def test_no_step_on_ramps_and_no_change_without_spikes() -> None:
    t, r, _ = smooth_run(13)
    seen, events, corrector = correct(t, r, step_k=16.0, alternating=alternation(r).present)
    assert not corrector.steps and corrector.n_spikes == 0
    assert np.count_nonzero(events) < 0.005 * t.size
    assert np.max(np.abs(seen - r)) < 8.0 * 2.0 * np.sqrt(2.0)


def test_corrector_is_identical_in_step_and_run_and_across_batches_and_gaps() -> None:
    t, r, s = smooth_run(14, n=600)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    cal = corrected(cal, alternation=True, despike=8.0, baseline_step=16.0)
    r = r + 20.0 * (-1.0) ** np.arange(t.size) + 200.0 * (t > 30.0)
    r[[100, 400]] += 300.0
    r[50] = np.nan
    t = t + 10.0 * (t > 45.0)  # a gap reset
    assert_step_run_and_pieces_agree(cal, t, r, cut=237)


def test_health_counts_the_corrections_alike_in_step_run_and_replay_ticks() -> None:
    """The spikes kept from the model and the steps re-based are health counters (the
    node's /diagnostics): the same from ``step``, from ``run`` in pieces, and from
    ``HealthCounter`` (replay's diagnostics) at any tick."""
    t, r, s = smooth_run(16, n=600)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    cal = corrected(cal, despike=8.0, baseline_step=16.0)
    r = r + 150.0 * (t > 30.0)
    r[[100, 400, 500]] += 300.0
    engine = Engine(cal)
    for a, b in zip(t, r, strict=True):
        engine.step("s1", a, b)
    stepped = engine.health()["s1"]
    assert stepped.n_spikes == 3 and stepped.n_baseline_steps == 1
    engine = Engine(cal)
    before = engine.health()["s1"]
    out = engine.run("s1", t[:450], r[:450])
    assert out.corrections is not None
    ticks = np.array([t[99], t[101], t[449]])
    at = HealthCounter(before, t[:450], out).at(ticks, stale_after=1.0).counters
    spikes, steps = COUNTERS.index("n_spikes"), COUNTERS.index("n_baseline_steps")
    assert at[:, spikes].tolist() == [0, 1, 2]
    assert at[-1, steps] == 1
    assert at[-1, spikes] == engine.health()["s1"].n_spikes
    engine.run("s1", t[450:], r[450:])
    run = engine.health()["s1"]
    assert (run.n_spikes, run.n_baseline_steps) == (stepped.n_spikes, stepped.n_baseline_steps)
    assert Engine(corrected(cal, despike=None, baseline_step=None)).run(
        "s1", t, r).corrections is None
    values = stepped.to_diagnostic()[2]
    assert values["n_spikes"] == "3" and values["n_baseline_steps"] == "1"


def test_input_corrections_round_trip_and_bad_values_name_the_field(tmp_path) -> None:
    t, r, s = smooth_run(15, n=400)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    cal = corrected(cal, despike=6.5, baseline_step=20.0)
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    assert load_calibration(path).sensors["s1"].input == cal.sensors["s1"].input
    text = path.read_text()
    assert text.replace("despike: 6.5", "despike: true").count("despike: true") == 1
    path.write_text(text.replace("despike: 6.5", "despike: true"))
    assert load_calibration(path).sensors["s1"].input.despike == DESPIKE_K
    for bad in ("despike: -1", "despike: many", "despike: .nan"):
        path.write_text(text.replace("despike: 6.5", bad))
        with pytest.raises(CalibrationError, match=r"cal.yaml.*sensors.s1.input.despike"):
            load_calibration(path)


@pytest.mark.parametrize("alternating", [False, True])
def test_a_tare_during_a_run_is_not_taken_for_a_baseline_step(alternating: bool) -> None:
    """The node's auto tare changes the input gain mid-run: the models then see the tared
    level, as an engine tared before the run does (a cubic has no memory)."""
    t, r, s = smooth_run(17, n=400)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    cal = corrected(cal, alternation=alternating, despike=8.0, baseline_step=12.0)
    rest = cal.sensors["s1"].rest_resistance
    rng = np.random.default_rng(3)
    t2 = 0.1 * np.arange(300)
    r2 = 1.05 * rest + 2.0 * rng.standard_normal(t2.size)  # at rest, reading 5 % high
    if alternating:
        r2 = r2 + 20.0 * (-1.0) ** np.arange(t2.size)
    live = Engine(cal)
    for a, b in zip(t2[:100], r2[:100], strict=True):
        live.step("s1", a, b)
    live.tare("s1", 1.05 * rest)
    late = [live.step("s1", a, b).strain for a, b in zip(t2[100:], r2[100:], strict=True)]
    tared = Engine(cal)
    tared.tare("s1", 1.05 * rest)
    truth = tared.run("s1", t2, r2).strain[100:]
    assert live.health()["s1"].n_baseline_steps == 0
    np.testing.assert_allclose(late[30:], truth[30:], atol=0.05)


def test_a_pair_side_without_alternation_is_refused_at_load_and_fit(tmp_path) -> None:
    t, r, s = smooth_run(15, n=400)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1")})
    assert not cal.sensors["s1"].input.alternation
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    text = path.read_text()
    assert "kind: resistance" in text
    # the tare would read pair maxima while the models see the samples themselves
    path.write_text(text.replace("kind: resistance", "kind: resistance, pair: upper"))
    with pytest.raises(CalibrationError, match=r"cal.yaml: sensors.s1.input.pair: .*alternation"):
        load_calibration(path)
    with pytest.raises(FitError, match="pair=upper needs an alternating input"):
        fit_sensor([Recording("s1", t, r, s)], "cubic", name="s1",
                   options={"alternation": False, "pair": "upper"})


def test_an_array_with_a_corrected_sensor_steps_as_its_sensors_do() -> None:
    base = fitted("apl")
    cals = {n: SensorCalibration(**{**vars(base), "name": n}) for n in ("a1", "a2")}
    cals["a2"] = replace(cals["a2"], input=replace(cals["a2"].input, despike=8.0))
    cal = Calibration(cals)
    rec = training_recording()
    t, r = rec.t[:400], np.array(rec.r[:400], dtype=float)
    r[[150, 300]] *= 1.5  # spikes
    engine = Engine(cal, arrays={"pair": ["a1", "a2"]})
    assert not engine._arrays["pair"].fused  # the per-sensor path
    ticks = np.array([engine.step_array("pair", a, np.array([b, b])).strain
                      for a, b in zip(t, r, strict=True)])
    for j, name in enumerate(("a1", "a2")):
        np.testing.assert_allclose(ticks[:, j], Engine(cal).run(name, t, r).strain,
                                   atol=1e-12)
    assert np.max(np.abs(ticks[:, 1] - Engine(cal).run("a1", t, rec.r[:400]).strain)) < \
        np.max(np.abs(ticks[:, 0] - Engine(cal).run("a1", t, rec.r[:400]).strain))


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
    mean = pair_values(one_sided(t, r))[1:]
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


def test_range_flags_follow_the_pair_values_the_model_reads() -> None:
    """An alternation larger than the margin of the valid range flags no sample once the
    pair means are read inside the range, in run and step alike; a level truly outside
    is still flagged."""
    t, r, s = smooth_run(8, n=600)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, r + 60.0 * (-1.0) ** np.arange(
        t.size), s)], "cubic", name="s1")})
    vr = cal.sensors["s1"].valid_range
    assert cal.sensors["s1"].input.alternation and 60.0 > 0.05 * (vr.r_hi - vr.r_lo)
    t2, r2, _ = smooth_run(9, n=600)
    wobbled = r2 + 80.0 * (-1.0) ** np.arange(t2.size)
    wobbled[300:320] += 5.0 * (vr.r_hi - vr.r_lo)  # a stretch truly out of range
    out = Engine(cal).run("s1", t2, wobbled)
    engine = Engine(cal)
    stepped = [engine.step("s1", a, b).out_of_range for a, b in zip(t2, wobbled, strict=True)]
    np.testing.assert_array_equal(out.out_of_range, stepped)
    outside = np.zeros(t2.size, bool)
    outside[300:321] = True  # the pair mean of the first sample after the stretch too
    raw_outside = (wobbled < vr.r_lo) | (wobbled > vr.r_hi)
    assert np.sum(raw_outside & ~outside) > 50  # the raw samples would have been flagged
    assert not np.any(out.out_of_range[~outside])
    assert np.all(out.out_of_range[301:320])


def test_one_adc_step_of_flicker_in_a_quiet_hold_is_no_spike() -> None:
    """A 12-bit divider read-out whose steps exceed its noise (the rig's steps run: long
    holds at 40 %): a hold flickering by one ADC step is quantisation, not spikes; spikes
    of 0.5 ohm injected on the same run are still all found."""
    from strain_comp.offline.rig import RigEffects, simulate

    clean = RigEffects(relaxation=0.0)
    run = simulate("steps", seed=13, effects=clean)["s1"]
    hold = run.r[(run.s == 40.0)]
    changes = np.abs(np.diff(hold))
    assert np.mean(changes == 0.0) > 0.3  # stuck on one ADC step for runs of samples
    assert np.min(changes[changes > 0]) > 2.0 * clean.noise  # a step exceeds the noise
    _, events, corrector = correct(run.t, run.r, alternating=False)
    assert corrector.n_spikes == 0 and not np.any(events == SPIKE)
    spiky = simulate("steps", seed=13, effects=replace(clean, spikes=0.002))["s1"]
    injected = np.count_nonzero(np.abs(spiky.r - run.r) > 0.25)
    _, _, corrector = correct(spiky.t, spiky.r, alternating=False)
    assert injected > 10 and corrector.n_spikes == injected
