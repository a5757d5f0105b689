"""Tare and two-point recalibration against known truth on short synthetic runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from strain_comp.base.direction import DirectionSettings
from strain_comp.cli import main as cli
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tare import (
    MAX_REST_DRIFT,
    REST_WINDOW,
    rest_resistance_at_start,
    rest_resistance_from_reference,
    tare_engine,
    unsettled_start,
)
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.session_start import apply_map, map_from_pairs, recalibrate, steady_output

R0 = 1000.0


def strain_profile(t: np.ndarray, rest: float = 5.0) -> np.ndarray:
    """Rest for ``rest`` s, then 0 -> 20 % triangles of 10 s period."""
    phase = np.clip(t - rest, 0.0, None) % 10.0
    return np.where(t < rest, 0.0, 20.0 * (1.0 - np.abs(phase - 5.0) / 5.0))


def gauge(s: np.ndarray, r0: float = R0) -> np.ndarray:
    """A static sensor: R = r0 (1 + 0.02 S + 2e-4 S^2)."""
    return r0 * (1.0 + 0.02 * s + 2e-4 * s ** 2)


def run(r0: float = R0, *, alternation: float = 0.0, seconds: float = 40.0) -> Recording:
    t = np.arange(0.0, seconds, 0.1)
    s = strain_profile(t)
    r = gauge(s, r0) + alternation * (-1.0) ** np.arange(t.size)
    return Recording("s1", t, r, s)


@pytest.fixture(scope="module")
def cubic() -> Calibration:
    return Calibration({"s1": fit_sensor([run()], "cubic", name="s1")})


def test_fit_stores_the_rest_resistance_of_the_first_rest(cubic: Calibration) -> None:
    assert cubic.sensors["s1"].rest_resistance == pytest.approx(R0, rel=1e-9)


def test_rest_from_reference_uses_the_first_rest_when_the_run_starts_moving() -> None:
    t = np.arange(0.0, 30.0, 0.1)
    s = strain_profile(t, rest=0.0)
    s[(t > 10.0) & (t < 12.0)] = 0.0  # a rest after the first cycle
    r = gauge(s) + 30.0 * (t > 9.5)  # softened: rests higher after loading
    assert rest_resistance_from_reference(t, r, s) == pytest.approx(R0, abs=5.0)
    # not at rest at the start: the first stay at rest
    assert rest_resistance_from_reference(t[3:], r[3:], s[3:]) == pytest.approx(R0 + 30.0,
                                                                                abs=5.0)


def test_rest_at_start_cancels_alternation_and_spikes(cubic: Calibration) -> None:
    rec = run(1234.0, alternation=40.0)
    r = rec.r.copy()
    r[7] = 5e4  # an isolated spike
    r[3] = np.nan  # a bad sample
    rest = rest_resistance_at_start(rec.t, r, cubic.sensors["s1"].direction)
    assert rest == pytest.approx(1234.0, abs=1.0)


def test_the_tare_reads_the_samples_the_engine_feeds_its_model(cubic: Calibration) -> None:
    """A logger's buffer of the first 3 s sent twice more (its stamps stepping back, a stuck
    1.5x reading) is refused by the engine (time not increasing): the tare leaves it out as
    well, at start and from the reference."""
    rec = run(1234.0)
    head, tail = rec.t <= 3.0, rec.t > 3.0
    assert rec.s is not None and not rec.s[head].any()
    t = np.concatenate([rec.t[head], rec.t[head], rec.t[head], rec.t[tail]])
    r = np.concatenate([rec.r[head], 1.5 * rec.r[head], 1.5 * rec.r[head], rec.r[tail]])
    s = np.concatenate([rec.s[head], rec.s[head], rec.s[head], rec.s[tail]])
    assert rest_resistance_at_start(t, r, cubic.sensors["s1"].direction) == \
        pytest.approx(1234.0, rel=1e-12)
    assert rest_resistance_from_reference(t, r, s) == pytest.approx(1234.0, rel=1e-12)


def test_rest_at_start_refuses_a_run_that_starts_moving(cubic: Calibration) -> None:
    t = np.arange(0.0, 10.0, 0.1)
    with pytest.raises(InputError, match="does not start at rest"):
        rest_resistance_at_start(t, gauge(strain_profile(t, rest=0.0)),
                                 cubic.sensors["s1"].direction)


def test_rest_at_start_of_a_slow_instrument_counts_seconds_not_samples() -> None:
    """At 1 Hz a run that rests for 1 s shows two samples at rest before it moves: the
    tare reads their level (the first sample's R exactly, the second's 0.1 % above)."""
    t = np.arange(0.0, 60.0, 1.0)
    s = np.clip(t - 1.0, 0.0, None) * 0.5
    r = gauge(s, 1.3 * R0)
    detector = DirectionSettings(deadzone=1.0)  # ohm/s: the first movement is 10 ohm/s
    assert rest_resistance_at_start(t, r, detector) == pytest.approx(1.3 * R0, rel=2e-3)
    # the same two samples at 10 Hz (0.1 s of rest) are too few
    with pytest.raises(InputError, match="does not start at rest"):
        rest_resistance_at_start(t / 10.0, r, DirectionSettings(deadzone=10.0))


def test_rest_is_decided_once_the_detector_moves_or_the_window_is_full() -> None:
    """Until then the rule's answer on a longer start could differ (None); from then on every
    longer start gives the same rest resistance."""
    detector = DirectionSettings(deadzone=1.0)
    t = np.arange(0.0, 20.0, 0.1)
    resting = np.full(t.size, 1.3 * R0)
    inside = t < REST_WINDOW - 0.5
    assert rest_resistance_at_start(t[inside], resting[inside], detector, ended=False) is None
    assert rest_resistance_at_start(t, resting, detector, ended=False) == \
        rest_resistance_at_start(t, resting, detector)
    ramp = gauge(np.clip(t - 2.0, 0.0, None) * 2.0, 1.3 * R0)
    n = int(np.argmax(t > 3.0))
    assert rest_resistance_at_start(t[:n], ramp[:n], detector, ended=False) == \
        rest_resistance_at_start(t, ramp, detector)
    moving = gauge(t * 2.0, 1.3 * R0)
    with pytest.raises(InputError, match="does not start at rest"):
        rest_resistance_at_start(t[:n], moving[:n], detector, ended=False)


def test_rest_at_start_declines_a_start_that_still_relaxes() -> None:
    """A pre-stretched sensor decaying towards its rest level (R0 (1 + 0.2 exp(-t / 60 s)),
    1 % in the first 5 s, slower than the detector's dead zone) is no rest level; the same
    start once settled (0.1 % noise-free drift left) is tared."""
    t = np.arange(0.0, 20.0, 0.1)
    detector = DirectionSettings(deadzone=50.0)
    relaxing = R0 * (1.0 + 0.2 * np.exp(-t / 60.0))
    with pytest.raises(InputError, match="still drifts"):
        rest_resistance_at_start(t, relaxing, detector)
    settled = R0 * (1.0 + 0.2 * np.exp(-(t + 300.0) / 60.0))
    drift = settled[int(REST_WINDOW / 0.1)] / settled[0] - 1.0
    assert abs(drift) < MAX_REST_DRIFT
    assert rest_resistance_at_start(t, settled, detector) == pytest.approx(
        float(np.median(settled[t <= REST_WINDOW])), rel=1e-4)


def test_unsettled_start_is_the_relaxing_rest_before_the_reference_moves() -> None:
    """A run at rest for 40 s, still relaxing from an earlier stretch, then a ramp: the 40 s
    are unsettled; the same rest settled, or a run that starts moving, gives 0."""
    t = np.arange(0.0, 100.0, 0.1)
    s = np.clip(t - 40.0, 0.0, 20.0)
    relaxing = R0 * (1.0 + 0.01 * s + 0.2 * np.exp(-t / 60.0))
    seconds, drift = unsettled_start(t, relaxing, s)
    assert seconds == pytest.approx(40.4, abs=0.15)  # 2 % of the 20 % span at 1 %/s
    assert drift < -MAX_REST_DRIFT
    settled = R0 * (1.0 + 0.01 * s + 0.2 * np.exp(-(t + 300.0) / 60.0))
    assert unsettled_start(t, settled, s)[0] == 0.0
    moving = np.clip(t, 0.0, 20.0)
    assert unsettled_start(t, R0 * (1.0 + 0.01 * moving), moving)[0] == 0.0


def test_auto_tare_makes_a_shifted_run_read_like_the_calibrated_one(cubic: Calibration,
                                                                     ) -> None:
    same = evaluate_recordings({"s1": run()}, cubic).sensors["s1"].stats.rmse
    shifted = {"s1": run(1.4 * R0)}
    untared = evaluate_recordings(shifted, cubic).sensors["s1"].stats.rmse
    result = evaluate_recordings(shifted, cubic, tare="auto")
    assert same < 0.05
    assert untared > 5.0
    assert result.sensors["s1"].stats.rmse == pytest.approx(same, abs=0.02)
    assert any("40.0 % above calibration" in note for note in result.notes)


def test_failed_auto_tare_keeps_the_old_gain(cubic: Calibration) -> None:
    engine = Engine(cubic)
    engine.set_input_gain("s1", 0.5)
    t = np.arange(0.0, 10.0, 0.1)
    lines = tare_engine(engine, {"s1": (t, gauge(strain_profile(t, rest=0.0)))}, "auto")
    assert "not tared" in lines["s1"]
    assert engine.input_gain("s1") == 0.5


def test_two_point_recalibration_passes_through_both_points(cubic: Calibration) -> None:
    cal = cubic.sensors["s1"]
    points = [(float(gauge(np.array(2.0))), 3.0), (float(gauge(np.array(15.0))), 17.0)]
    new, lines = recalibrate(cubic, points=points)
    for r, s in points:
        assert steady_output(new.sensors["s1"], r) == pytest.approx(s, abs=1e-6)
    assert new.sensors["s1"].provenance["recalibrations"][0]["points"] == [list(p)
                                                                           for p in points]
    assert "output gain" in lines[0]
    assert cal.effects == []  # the input calibration is untouched


def test_recalibration_map_is_applied_alike_by_step_and_run(cubic: Calibration) -> None:
    new = Calibration({"s1": apply_map(cubic.sensors["s1"], 1.3, -0.7, {})})
    rec = run()
    batch = Engine(new).run("s1", rec.t, rec.r).strain
    engine = Engine(new)
    stepped = np.array([engine.step("s1", t, r).strain for t, r in zip(rec.t, rec.r,
                                                                          strict=True)])
    old = Engine(cubic).run("s1", rec.t, rec.r).strain
    np.testing.assert_allclose(batch, stepped, atol=1e-9)
    inside = (old > 1.0) & (old < 14.0)  # away from the clamp of the valid range
    np.testing.assert_allclose(batch[inside], 1.3 * old[inside] - 0.7, atol=1e-9)


def test_least_squares_map_recovers_a_known_gain_and_offset() -> None:
    estimate = np.linspace(0.0, 20.0, 50)
    reference = 0.8 * estimate + 1.5
    reference[3] = np.nan
    assert map_from_pairs(estimate, reference) == pytest.approx((0.8, 1.5))


def test_cli_recalibrate_refuses_its_input_as_output_and_keeps_it(cubic: Calibration,
                                                                  tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_calibration(cubic, path)
    before = path.read_bytes()
    code = cli(["recalibrate", str(path), "--point", "1040:2", "--point", "1300:15",
                "--out", str(path)])
    assert code == 2
    assert path.read_bytes() == before
    out = tmp_path / "cal2.yaml"
    assert cli(["recalibrate", str(path), "--point", "1040:2", "--point", "1300:15",
                "--out", str(out)]) == 0
    assert load_calibration(out).sensors["s1"].effects[-1]["name"] == "recalibration_offset"
    assert yaml.safe_load(out.read_text())["sensors"]["s1"]["provenance"]["recalibrations"]


def test_in_run_bound_is_the_same_model_fitted_on_the_evaluated_run(cubic: Calibration,
                                                                    tmp_path: Path) -> None:
    from strain_comp.offline.fit import in_run_bound

    other = {"s1": run(1.2 * R0)}
    result = evaluate_recordings(other, cubic)
    assert "in_run_rmse" not in result.to_json()["sensors"]["s1"]
    in_run_bound(result, other, cubic)
    own = fit_sensor([other["s1"]], "cubic", name="s1")
    expected = evaluate_recordings(other, Calibration({"s1": own})).sensors["s1"].stats.rmse
    assert result.sensors["s1"].in_run_rmse == pytest.approx(expected)
    assert result.sensors["s1"].in_run_rmse < 0.05 < result.sensors["s1"].stats.rmse
    assert result.to_json()["sensors"]["s1"]["in_run_rmse"] == pytest.approx(expected)


def test_cli_evaluate_tare_auto_with_bound_and_recalibrate_from_a_bag(cubic: Calibration,
                                                                       tmp_path: Path) -> None:
    import json

    from strain_comp.io.recording import write_recordings

    cal, bag = tmp_path / "cal.yaml", tmp_path / "shifted.mcap"
    save_calibration(cubic, cal)
    write_recordings({"s1": run(1.25 * R0)}, str(bag))
    out = tmp_path / "e.json"
    assert cli(["evaluate", str(bag), "--calibration", str(cal), "--tare", "auto",
                "--in-run-bound", "--json", str(out)]) == 0
    record = json.loads(out.read_text())["sensors"]["s1"]
    assert record["rmse"] < 0.05 and record["in_run_rmse"] < 0.05
    # without a tare the shifted run reads wrong; a recalibration from it repairs the
    # part inside the valid range, where the output map is affine
    cal2 = tmp_path / "cal2.yaml"
    assert cli(["recalibrate", str(cal), "--from", str(bag), "--out", str(cal2)]) == 0
    prov = load_calibration(cal2).sensors["s1"].provenance["recalibrations"][0]
    assert prov["from"] == str(bag) and prov["tare"] == "calibration"
    assert cli(["recalibrate", str(cal), "--from", str(bag), "--out", str(bag)]) == 2


def test_tare_reading_names_the_resistance_in_a_prefix_that_suits_it() -> None:
    from strain_comp.core.tare import tare_reading

    assert tare_reading(39_900.0, 35_100.0) == \
        "rest resistance 12.0 % below calibration (35.1 vs 39.9 kohm)"
    assert tare_reading(71.79, 66.13).endswith("(66.13 vs 71.79 ohm)")
    assert tare_reading(2.45e6, 2.41e6).endswith("(2.41 vs 2.45 Mohm)")
    assert tare_reading(0.53, 0.5512).endswith("above calibration (0.5512 vs 0.53 ohm)")


def test_a_point_outside_the_resistance_range_is_refused_not_fitted_to_the_clamp(
        cubic: Calibration, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A sensor whose resistance fell 40 %: its 0 % and 15 % points lie below the
    calibrated range, where the output is clamped; a map through clamped outputs would be
    wrong, so the points are refused with the range, and no file is written."""
    lo = cubic.sensors["s1"].valid_range.r_lo
    points = [(0.6 * float(gauge(np.array(0.0))), 0.0),
              (0.6 * float(gauge(np.array(15.0))), 15.0)]
    assert points[0][0] < lo
    with pytest.raises(InputError, match="outside the calibration's resistance range"):
        recalibrate(cubic, points=points)
    path = tmp_path / "cal.yaml"
    save_calibration(cubic, path)
    out = tmp_path / "cal2.yaml"
    flags = [f for r, s in points for f in ("--point", f"{r}:{s}")]
    assert cli(["recalibrate", str(path), *flags, "--out", str(out)]) == 2
    assert "resistance range" in capsys.readouterr().err and not out.exists()


def test_recalibration_reading_gives_the_offset_in_the_calibration_unit(
        cubic: Calibration) -> None:
    from dataclasses import replace

    mm = Calibration({"s1": replace(cubic.sensors["s1"], strain_unit="mm")})
    points = [(float(gauge(np.array(2.0))), 3.0), (float(gauge(np.array(15.0))), 17.0)]
    _, lines = recalibrate(mm, points=points)
    assert lines[0].split("offset ")[1].split(" (")[0].endswith(" mm"), lines
    _, lines = recalibrate(cubic, points=points)
    assert "% strain (through 2 points)" in lines[0], lines


def moved(s: np.ndarray) -> np.ndarray:
    """The gauge after its rest level rose 10 % and its sensitivity 40 %: an affine map of
    the calibrated resistance, reaching far above the calibrated range."""
    return 1100.0 + 1.4 * (gauge(s) - R0)


def test_input_zero_and_span_through_two_points_reads_the_moved_sensor(
        cubic: Calibration, tmp_path: Path) -> None:
    points = [(1100.0, 0.0), (float(moved(np.array(15.0))), 15.0)]
    new, lines = recalibrate(cubic, points=points, form="input")
    cal = new.sensors["s1"]
    assert cal.input.zero_span == pytest.approx((1100.0, R0, 1.0 / 1.4), rel=1e-3)
    assert "span gain" in lines[0] and cal.effects == []
    for s in (3.0, 10.0, 18.0):
        assert steady_output(cal, float(moved(np.array(s)))) == pytest.approx(s, abs=0.05)
    path = tmp_path / "span.yaml"
    save_calibration(new, path)
    assert load_calibration(path).sensors["s1"].input == cal.input
    text = path.read_text().replace("gain: ", "gain: -")
    path.write_text(text)
    with pytest.raises(Exception, match=r"zero_span\.gain"):
        load_calibration(path)


def test_cli_recalibrate_input_from_the_first_cycle_then_tare(cubic: Calibration,
                                                              tmp_path: Path) -> None:
    from strain_comp.io.recording import write_recordings

    rec = run()
    cal, bag, cal2 = tmp_path / "cal.yaml", tmp_path / "moved.mcap", tmp_path / "cal2.yaml"
    save_calibration(cubic, cal)
    write_recordings({"s1": Recording("s1", rec.t, moved(rec.s), rec.s)}, str(bag))
    assert cli(["recalibrate", str(cal), "--input", "--from", str(bag), "--first", "15",
                "--out", str(cal2)]) == 0
    spanned = load_calibration(cal2)
    before = evaluate_recordings({"s1": Recording("s1", rec.t, moved(rec.s), rec.s)}, cubic)
    after = evaluate_recordings({"s1": Recording("s1", rec.t, moved(rec.s), rec.s)}, spanned)
    assert before.sensors["s1"].stats.rmse > 2.0
    assert after.sensors["s1"].stats.rmse < 0.1
    # the rest moves again later: the tare still zeroes it, through the span
    again = Recording("s1", rec.t, 1.05 * moved(rec.s), rec.s)
    tared = evaluate_recordings({"s1": again}, spanned, tare="auto")
    assert tared.sensors["s1"].stats.rmse < 0.6
    assert evaluate_recordings({"s1": again}, spanned).sensors["s1"].stats.rmse > 1.0
    assert cli(["recalibrate", str(cal), "--input", "--point", "1100:0", "--first", "3",
                "--out", str(tmp_path / "x.yaml")]) == 2


def test_a_second_input_span_replaces_the_first(cubic: Calibration) -> None:
    points = [(1100.0, 0.0), (float(moved(np.array(15.0))), 15.0)]
    once = recalibrate(cubic, points=points, form="input")[0]
    twice = recalibrate(once, points=points, form="input")[0]
    assert twice.sensors["s1"].input.zero_span == pytest.approx(
        once.sensors["s1"].input.zero_span, rel=1e-12)


def test_the_drift_and_window_are_the_ones_applied(monkeypatch: pytest.MonkeyPatch) -> None:
    """The relaxing start the default declines (``MAX_REST_DRIFT`` 0.5 %) is tared with a
    5 % drift accepted (both read when called, as studies/policy_ablation.py sets them), at
    the median of its first ``REST_WINDOW`` seconds."""
    from strain_comp.core import tare

    t = np.arange(0.0, 20.0, 0.1)
    relaxing = R0 * (1.0 + 0.2 * np.exp(-t / 60.0))
    assert MAX_REST_DRIFT == 0.005 and REST_WINDOW == 5.0
    monkeypatch.setattr(tare, "REST_WINDOW", 3.0)
    with pytest.raises(InputError, match="no rest level"):
        rest_resistance_at_start(t, relaxing, DirectionSettings(deadzone=50.0))
    monkeypatch.setattr(tare, "MAX_REST_DRIFT", 0.05)
    rest = rest_resistance_at_start(t, relaxing, DirectionSettings(deadzone=50.0))
    assert rest == pytest.approx(float(np.median(relaxing[t <= 3.0])), rel=1e-3)
