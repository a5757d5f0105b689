"""Fitting orchestration: screening, segments, ranges, dead zone, provenance, round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.base.samples import DEFAULT_GAP_RESET
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.metrics import error_stats
from strain_comp.errors import FitError, InputError, ParameterError
from strain_comp.io.recording import Recording
from strain_comp.offline.deadzone import DEADZONE_FRACTION, find_hold, movement_rate
from strain_comp.offline.fit import (
    MIN_SEGMENT,
    TRAINING_WIDENING,
    fit_sensor,
    parse_options,
    split_segments,
)

C_TRUE = np.array([-40.0, 0.5, -2e-3, 1e-5])  # S = c0 + c1 R + c2 R^2 + c3 R^3, R in ohm


def cubic_strain(r: np.ndarray) -> np.ndarray:
    return C_TRUE[0] + C_TRUE[1] * r + C_TRUE[2] * r**2 + C_TRUE[3] * r**3


def triangles(duration: float = 120.0, dt: float = 0.05, *, hold: tuple[float, float] | None
              = None) -> tuple[np.ndarray, np.ndarray]:
    """Time and a 0..20 % triangle strain with period 20 s, optionally held still."""
    t = np.arange(0.0, duration, dt)
    s = 20.0 * np.abs((t / 10.0) % 2.0 - 1.0)
    if hold is not None:
        inside = (t >= hold[0]) & (t < hold[1])
        s[inside] = s[np.searchsorted(t, hold[0])]
    return t, s


def recording(t: np.ndarray, r: np.ndarray, s: np.ndarray | None, name: str = "s1") -> Recording:
    return Recording(name=name, t=t, r=r, s=s, temperature=None, array=None, index=None)


def resistance_of(s: np.ndarray) -> np.ndarray:
    """Invert the cubic numerically (it is increasing on the range used)."""
    grid = np.linspace(80.0, 200.0, 20001)
    return np.interp(s, cubic_strain(grid), grid)


def test_fit_recovers_cubic_and_round_trips(tmp_path: Path) -> None:
    t, s = triangles()
    r = resistance_of(s)
    cal = fit_sensor([recording(t, r, s)], "cubic", name="s1", bags=["a.mcap"])
    assert np.allclose(cal.params["c"], C_TRUE, rtol=1e-5, atol=1e-8)
    assert cal.provenance["fit_rmse"] < 1e-6
    assert cal.provenance["bags"] == ["a.mcap"]
    assert cal.provenance["n_samples"] == t.size
    # valid range: training range widened by the documented margin
    r_pad = TRAINING_WIDENING * (r.max() - r.min())
    s_pad = TRAINING_WIDENING * (s.max() - s.min())
    vr = cal.valid_range
    assert (vr.r_lo, vr.r_hi) == pytest.approx((r.min() - r_pad, r.max() + r_pad))
    assert (vr.s_lo, vr.s_hi) == pytest.approx((s.min() - s_pad, s.max() + s_pad))
    # no hold, hardly any noise: the dead zone is far below the rate of R while moving
    assert cal.provenance["direction_from"] in ("noise", "floor")
    assert 0 < cal.direction.deadzone < 0.01 * np.median(np.abs(np.diff(r) / np.diff(t)))
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration({"s1": cal}), path)
    loaded = load_calibration(path)
    assert loaded.sensors["s1"] == cal
    assert np.array_equal(loaded.sensors["s1"].build_model().run(t, r),
                          cal.build_model().run(t, r))


def test_fit_rmse_is_the_training_error_over_good_samples() -> None:
    t, s = triangles()
    rng = np.random.default_rng(3)
    r = resistance_of(s) + 0.3 * rng.standard_normal(t.size)
    r[[10, 500, 501]] = [np.nan, -1.0, np.inf]
    s_bad = s.copy()
    s_bad[700] = np.nan
    cal = fit_sensor([recording(t, r, s_bad)], "cubic", name="s1")
    keep = np.isfinite(r) & (r > 0) & np.isfinite(s_bad)
    estimate = cal.build_model().run(t[keep], r[keep])
    expected = error_stats(estimate, s[keep])
    assert cal.provenance["fit_rmse"] == pytest.approx(expected.rmse, rel=1e-12)
    assert cal.provenance["n_samples"] == expected.n == t.size - 4


def test_fit_rmse_equals_evaluate_on_the_training_data() -> None:
    from strain_comp.offline.evaluate import evaluate_recordings

    t, s = triangles(200.0, hold=(100.0, 130.0))
    r = resistance_of(s) + 0.2 * np.random.default_rng(2).standard_normal(t.size)
    rec = recording(t, r, s)
    cal = fit_sensor([rec], "cubic", name="s1")
    result = evaluate_recordings({"s1": rec}, Calibration({"s1": cal}))
    assert result.sensors["s1"].stats.rmse == pytest.approx(cal.provenance["fit_rmse"],
                                                           rel=1e-12)


def test_segments_cut_at_gaps_not_at_isolated_bad_samples() -> None:
    t = np.arange(0.0, 30.0, 0.1)
    r = 100.0 + t
    s = t.copy()
    r[50] = np.nan  # isolated bad sample: no cut
    gap = (t > 10.0) & (t < 10.0 + DEFAULT_GAP_RESET + 1.0)  # a long stretch of bad samples: cut
    r[gap] = 0.0
    t_short = t.copy()
    segments = split_segments(t_short, r, s)
    assert len(segments) == 2
    assert segments[0].t[-1] <= 10.0 and segments[1].t[0] >= 10.0 + DEFAULT_GAP_RESET
    assert segments[0].t.size == np.sum(t <= 10.0) - 1
    # a stretch shorter than MIN_SEGMENT samples between two gaps is dropped
    t2 = np.concatenate([np.arange(0, 5, 0.1), 20 + 0.1 * np.arange(MIN_SEGMENT - 1),
                         np.arange(40, 45, 0.1)])
    assert len(split_segments(t2, 100 + t2, t2)) == 2


def test_dead_zone_from_hold_is_k_sigma_of_derivative_noise() -> None:
    dt, sigma_r = 0.05, 0.05
    t, s = triangles(200.0, dt, hold=(100.0, 160.0))
    rng = np.random.default_rng(7)
    r = resistance_of(s) + sigma_r * rng.standard_normal(t.size)
    segments = split_segments(t, r, s)
    hold_t, _ = find_hold(segments)
    assert hold_t[0] >= 100.0 and hold_t[-1] < 160.0 and hold_t.size > 200
    cal = fit_sensor([recording(t, r, s)], "cubic", name="s1",
                     options={"k_sigma": 3.0, "tau": 0.0})
    assert cal.provenance["direction_from"] == "hold"
    expected = 3.0 * sigma_r * np.sqrt(2.0) / dt  # sigma of (r_i - r_i-1) / dt
    assert cal.direction.deadzone == pytest.approx(expected, rel=0.15)
    assert cal.direction.k_sigma == 3.0


def test_dead_zone_without_hold_from_robust_noise() -> None:
    dt, sigma_r = 0.05, 0.05
    t, s = triangles(200.0, dt)
    rng = np.random.default_rng(11)
    r = resistance_of(s) + sigma_r * rng.standard_normal(t.size)
    cal = fit_sensor([recording(t, r, s)], "cubic", name="s1", options={"tau": 0.0})
    assert cal.provenance["direction_from"] == "noise"
    assert cal.direction.deadzone == pytest.approx(4.0 * sigma_r * np.sqrt(2.0) / dt, rel=0.2)


def test_derivative_filter_is_chosen_so_the_detector_sees_the_ramps() -> None:
    """With noise that puts the raw-difference dead zone above the ramps' dR/dt, the fit
    picks a longer filter, and the detector then follows the reference's direction."""
    dt, sigma_r = 0.02, 0.2
    t, s = triangles(200.0, dt, hold=(100.0, 160.0))
    rng = np.random.default_rng(3)
    r = resistance_of(s) + sigma_r * rng.standard_normal(t.size)
    segments = split_segments(t, r, s)
    raw = fit_sensor([recording(t, r, s)], "cubic", name="s1", options={"tau": 0.0})
    assert raw.direction.deadzone > movement_rate(segments)  # tau = 0: blind to the ramps
    cal = fit_sensor([recording(t, r, s)], "cubic", name="s1")
    assert cal.direction.tau > 0.0
    assert cal.direction.deadzone <= DEADZONE_FRACTION * movement_rate(segments)
    published = Engine(Calibration({"s1": cal})).run("s1", t, r).direction
    truth = np.sign(np.gradient(s, t))
    moving = np.abs(np.gradient(s, t)) > 0.05
    agree = np.mean(published[moving] == truth[moving])
    assert agree > 0.9, agree


def test_direction_options_are_not_passed_to_the_model() -> None:
    t, s = triangles()
    cal = fit_sensor([recording(t, resistance_of(s), s)], "cubic", name="s1",
                     options={"deadzone": 0.25, "tau": 0.1})
    assert (cal.direction.deadzone, cal.direction.tau, cal.direction.k_sigma) == (0.25, 0.1, None)
    assert cal.provenance["direction_from"] == "given"
    assert cal.provenance["options"] == {}


def test_parse_options_reads_yaml_values() -> None:
    options = parse_options(["N=11", "sigma=0.5", "mode=split", "grid=[1, 2]", "flag=true"])
    assert options == {"N": 11, "sigma": 0.5, "mode": "split", "grid": [1, 2], "flag": True}
    with pytest.raises(InputError, match="key=value"):
        parse_options(["N"])


def test_fit_errors_are_clear() -> None:
    t, s = triangles(10.0)
    r = resistance_of(s)
    with pytest.raises(FitError, match="no strain_reference"):
        fit_sensor([recording(t, r, None)], "cubic", name="s1")
    with pytest.raises(FitError, match="no stretch"):
        fit_sensor([recording(t[:3], r[:3], s[:3])], "cubic", name="s1")
    with pytest.raises(FitError, match="no range"):
        fit_sensor([recording(t, np.full(t.size, 100.0), s)], "cubic", name="s1")
    with pytest.raises(ParameterError, match="unknown model"):
        fit_sensor([recording(t, r, s)], "quintic", name="s1")


def test_samples_stamped_in_bursts_get_a_filter_of_two_intervals_and_a_working_detector(
        ) -> None:
    """The rig's random run with arrival-time stamps (each sample 0-35 ms late, kept in
    order: bursts microseconds apart, as a bag's log time has them): the fit no longer
    takes the raw difference, whose dead zone there is thousands of ohm/s and leaves the
    detector in hold (agreement 0.10), and the detector follows the reference's direction
    on 4 moving samples of 5 (0.96 on the regular stamps; the bursts' noise stays)."""
    from strain_comp.offline.rig import simulate

    sim = simulate("random", seed=1)["s1"]
    rng = np.random.default_rng(3)
    late = np.maximum.accumulate(sim.t + rng.uniform(0.0, 0.035, sim.t.size))
    late += 1e-6 * np.arange(sim.t.size)
    agree = {}
    for name, t in (("regular", sim.t), ("bursts", late)):
        cal = fit_sensor([recording(t, sim.r, sim.s)], "cubic", name="s1")
        if name == "bursts":
            assert cal.direction.tau >= 2.0 * np.median(np.diff(t))
        published = Engine(Calibration({"s1": cal})).run("s1", t, sim.r).direction
        rate = np.gradient(sim.s, sim.t)
        moving = np.abs(rate) > 0.05
        agree[name] = float(np.mean(published[moving] == np.sign(rate[moving])))
    print(f"\ndetector agreement with the reference's direction: {agree}")
    assert agree["bursts"] > 0.75 and agree["regular"] > 0.9, agree


def test_a_slow_instrument_is_fitted_and_run_without_a_reset_at_every_sample(
        tmp_path: Path) -> None:
    """A 0.1 Hz logger (every 50th sample of the rig's hour at 5 Hz): its 10 s intervals
    exceed the default 5 s gap, so the fit found no segment at all and the engine reset
    the model at every sample. The fit now counts gaps in sample intervals, the calibration
    carries the interval, and the engine runs the memory model through (no GAP_RESET)
    with the error it had in training; a pause of 20 intervals still resets."""
    from strain_comp.base.samples import Status
    from strain_comp.offline.rig import RigEffects, simulate

    sim = simulate("long", seed=1, effects=RigEffects())["s1"]
    t, r, s = sim.t[::50], sim.r[::50], sim.s[::50]
    cal = fit_sensor([recording(t, r, s)], "pl", name="s1")
    assert cal.sample_interval == pytest.approx(10.0)
    path = tmp_path / "slow.yaml"
    save_calibration(Calibration({"s1": cal}), path)
    loaded = load_calibration(path)
    assert loaded.sensors["s1"].sample_interval == pytest.approx(10.0)
    out = Engine(loaded).run("s1", t, r)
    assert not np.any(out.status == int(Status.GAP_RESET))
    rmse = error_stats(out.strain, s).rmse
    assert rmse == pytest.approx(cal.provenance["fit_rmse"], rel=1e-9)
    assert rmse < 0.5 * np.std(s)
    paused = np.where(np.arange(t.size) >= 100, t + 200.0, t)
    status = Engine(loaded).run("s1", paused, r).status
    assert np.flatnonzero(status == int(Status.GAP_RESET)).tolist() == [100]
    engine = Engine(loaded, stale_after=1.0)  # stale after two intervals, not after 1 s
    engine.run("s1", t[:10], r[:10])
    assert not engine.health(now=t[9] + 15.0)["s1"].stale
    assert engine.health(now=t[9] + 25.0)["s1"].stale


def test_fit_all_leaves_out_a_sensor_that_cannot_be_fitted_and_says_so(tmp_path: Path) -> None:
    """An array of two where one sensor's reference is NaN throughout: ``--sensor all``
    fits the other and reports the one left out; naming it alone is still an error."""
    from strain_comp.io.bag import BagWriter
    from strain_comp.offline.fit import fit_bags

    t, s = triangles()
    r = resistance_of(s)
    path = tmp_path / "two.mcap"
    with BagWriter(path) as writer:
        for name, ref in (("s1", s), ("s2", np.full(s.size, np.nan))):
            writer.write_float64(f"/{name}/resistance", t, r)
            writer.write_float64(f"/{name}/strain_reference", t, ref)
    lines: list[str] = []
    cal = fit_bags([path], "cubic", ["all"], report=lines.append)
    assert list(cal.sensors) == ["s1"]
    assert len(lines) == 1 and "s2" in lines[0], lines
    with pytest.raises(FitError, match="s2"):
        fit_bags([path], "cubic", ["s2"])
