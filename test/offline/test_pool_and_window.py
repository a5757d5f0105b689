"""Pooled fits in one input space and the session start on a window, against known truth:
runs of one static gauge seen through a different input zero and sensitivity each (and,
for the stretch session start, a sensitivity that moves after every run's calibration
stretch)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main as cli
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.errors import InputError
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import Pooled, fit_sensor, gate, pooled_input
from strain_comp.offline.session_start import (
    calibration_stretch,
    choose_space,
    recalibrate_recordings,
    session_forms,
    start_or_keep,
    stretch_and_return,
)


def gauge(s: np.ndarray) -> np.ndarray:
    """The sensor's true curve: R = 1000 (1 + 0.02 S + 2e-4 S^2) [ohm]."""
    return 1000.0 * (1.0 + 0.02 * s + 2e-4 * s ** 2)


def triangles(top: float, seconds: float = 60.0, period: float = 10.0) -> tuple[
        np.ndarray, np.ndarray]:
    """2 s of rest, then 0 -> ``top`` % triangles."""
    t = np.arange(0.0, seconds, 0.05)
    phase = np.clip(t - 2.0, 0.0, None) % period
    return t, np.where(t < 2.0, 0.0, top * (1.0 - np.abs(phase - period / 2) / (period / 2)))


def run(zero: float, gain: float, top: float) -> Recording:
    """The gauge read through R = zero + gain (R_true - 1000): its own zero and sensitivity."""
    t, s = triangles(top)
    return Recording("s1", t, zero + gain * (gauge(s) - 1000.0), s)


RUNS = [run(1000.0, 1.0, 30.0), run(1080.0, 1.5, 20.0), run(950.0, 0.7, 40.0)]
NEW = run(1120.0, 1.25, 30.0)


def test_pooled_input_puts_every_run_onto_the_anchor_curve() -> None:
    reading, joint = gate(RUNS)
    assert joint is not None
    assert reading["curve_rmse"]["spanned"] < 0.01 * reading["curve_rmse"]["raw"]
    pooled = pooled_input(RUNS, "joint")
    assert pooled_input(RUNS, "joint", joint).maps == pooled.maps  # the gate's, reused
    maps = pooled.maps
    assert pooled.record == {"pool": "joint"} and pooled.stretch_line is None
    truth = ((1000.0, 1.0, 30.0), (1080.0, 1.5, 20.0), (950.0, 0.7, 40.0))
    anchor = [i for i, m in enumerate(maps) if m["span_gain"] == 1.0
              and m["rest"] == m["rest_calibrated"]]
    assert len(anchor) == 1  # the run of median sensitivity is the space
    za, ga, _ = truth[anchor[0]]
    for (z, g, top), m in zip(truth, maps, strict=True):
        s = np.linspace(0.0, top, 9)  # over the strains the run saw
        through = m["rest_calibrated"] + m["span_gain"] * (z + g * (gauge(s) - 1000.0)
                                                             - m["rest"])
        expected = za + ga * (gauge(s) - 1000.0)
        assert through == pytest.approx(expected, abs=1e-3 * np.ptp(expected))
    assert pooled_input(RUNS, "raw") == Pooled(RUNS, [], {"pool": "raw"})
    # runs of one gauge with no difference of zero or sensitivity: nothing to map
    rng = np.random.default_rng(1)
    same = [run(1000.0, 1.0, top) for top in (20.0, 30.0, 40.0)]
    same = [Recording("s1", r.t, r.r + rng.normal(0.0, 2.0, r.t.size), r.s) for r in same]
    assert gate(same)[1] is None
    assert fit_sensor(same, "cubic", name="s1").provenance["pooling"]["pool"] == "raw"
    for pool in ("median", "spanned"):  # spanned is the fit's choice, not a space
        with pytest.raises(InputError, match="--pool"):
            pooled_input(RUNS, pool)


def moving(zero: float, gain: float) -> Recording:
    """The gauge 30 % more sensitive after the run's calibration stretch (its second
    triangle, 12 to 22 s), as the thread's sensitivity moves after its stretch."""
    t, s = triangles(30.0, seconds=90.0)
    later = np.where(t > 22.0, 1.3, 1.0)
    return Recording("s1", t, zero + gain * later * (gauge(s) - 1000.0), s)


INPUTS = ((1000.0, 1.0), (1080.0, 1.5), (950.0, 0.7))
MOVING = [moving(zero, gain) for zero, gain in INPUTS]


def test_the_stretch_start_keeps_the_line_the_mapped_stretches_share() -> None:
    pooled = pooled_input(MOVING, "stretch")
    assert pooled.record == {"pool": "stretch"}
    assert pooled.maps == pooled_input(MOVING, "joint").maps  # the same space
    r0, slope = pooled.stretch_line or (0.0, 0.0)
    s = np.linspace(0.0, 30.0, 31)  # the runs differ by an exact affine map of R
    for (zero, gain), m in zip(INPUTS, pooled.maps, strict=True):
        through = m["rest_calibrated"] + m["span_gain"] * (zero + gain * (gauge(s) - 1000.0)
                                                             - m["rest"])
        assert through == pytest.approx(gauge(s), rel=1e-6)
    # the line is the anchor's (sensitivity 1) least-squares line over its second triangle
    # (the stretch ends where the reference is back within 10 % of its span)
    t, tri = MOVING[0].t, MOVING[0].s
    assert tri is not None
    start, end = calibration_stretch(t, tri) or (0.0, 0.0)
    assert (start, end) == pytest.approx((11.5, 21.5), abs=0.1)
    stretch = (t >= start) & (t <= end)
    assert (slope, r0) == pytest.approx(np.polyfit(tri[stretch], gauge(tri[stretch]), 1),
                                        rel=1e-6)


def test_the_choice_of_space_follows_the_runs_left_out() -> None:
    """Runs of other amplitudes whose sensitivity holds: the steady outputs place a new run
    exactly and a stretch's line (a secant of the curve that depends on the amplitude) does
    not; a sensitivity that moves after every stretch: only the stretch line places the
    run as the training runs were placed."""
    def cubic(runs: list[Recording]) -> object:
        return fit_sensor(runs, "cubic", name="s1", pool="stretch")

    for runs, wanted in ((RUNS, "joint"), (MOVING, "stretch")):
        space, record = choose_space(runs, cubic)  # type: ignore[arg-type]
        errors = record["left_out_rmse"]
        assert space == wanted and errors[wanted] < 0.5 * errors[
            "stretch" if wanted == "joint" else "joint"]
        assert record["runs_left_out"] == 3
        # two runs: a run left out leaves no pooled fit, so the fit keeps the joint start
        two = fit_sensor(runs[:2], "cubic", name="s1")
        assert two.provenance["pooling"]["pool"] == "joint"
        assert "fewer than 3 runs" in two.provenance["pooling"]["chosen_by"]["why"]
        assert two.input.stretch_line is None
        fitted = fit_sensor(runs, "cubic", name="s1")
        assert fitted.provenance["pooling"]["pool"] == wanted
        assert fitted.provenance["pooling"]["chosen_by"] == record
    new = moving(1120.0, 1.25)
    errors = {}
    for space in ("joint", "stretch"):
        cal = fit_sensor(MOVING, "cubic", name="s1", pool=space)
        assert session_forms(cal) == (("input",) if space == "stretch" else ("input", "output"))
        started = start_or_keep(Calibration({"s1": cal}), {"s1": new}).calibration
        errors[space] = evaluate_recordings({"s1": new}, started).sensors["s1"].stats.rmse
    assert errors["stretch"] < 0.5 * errors["joint"]


@pytest.mark.parametrize("pool, limit", [("spanned", 0.1), ("raw", None)])
def test_a_pooled_fit_carries_to_a_new_run_after_its_session_start(pool: str,
                                                                   limit: float | None
                                                                   ) -> None:
    cal = Calibration({"s1": fit_sensor(RUNS, "cubic", name="s1", pool=pool)})
    fit_rmse = cal.sensors["s1"].provenance["fit_rmse"]
    started, _ = recalibrate_recordings(cal, {"s1": NEW}, form="input", span=(0.0, 12.0))
    error = evaluate_recordings({"s1": NEW}, started).sensors["s1"].stats.rmse
    if limit is not None:  # one space: the fit is exact and the session start finds the map
        assert fit_rmse < 0.05 and error < limit
        assert len(cal.sensors["s1"].provenance["pooled_runs"]) == 3
    else:  # as recorded: the fit is an average of three curves and misreads every run
        assert fit_rmse > 1.0 and error > 0.5


def test_a_window_spans_on_the_cycle_after_a_warm_up(tmp_path: Path) -> None:
    """The first stretch reads 30 % more sensitive (a warm-up); the second is the sensor's."""
    cal = Calibration({"s1": fit_sensor(RUNS[:1], "cubic", name="s1")})
    t, s = triangles(30.0)
    r = 1120.0 + 1.25 * (gauge(s) - 1000.0)
    r = np.where(t < 12.0, 1120.0 + 1.25 * 1.3 * (gauge(s) - 1000.0), r)
    rec = Recording("s1", t, r, s)
    first, _ = recalibrate_recordings(cal, {"s1": rec}, form="input", first=12.0)
    second, lines = recalibrate_recordings(cal, {"s1": rec}, form="input", span=(12.0, 22.0))
    late = Recording("s1", t[t > 12.0], r[t > 12.0], s[t > 12.0])
    assert evaluate_recordings({"s1": late}, second).sensors["s1"].stats.rmse < 0.1
    assert evaluate_recordings({"s1": late}, first).sensors["s1"].stats.rmse > 1.0
    assert "12 to 22 s" in lines[0]
    # --first S is --window 0:S
    a = recalibrate_recordings(cal, {"s1": rec}, first=12.0)[0]
    b = recalibrate_recordings(cal, {"s1": rec}, span=(0.0, 12.0))[0]
    assert a.sensors["s1"].effects == b.sensors["s1"].effects


def test_a_stretch_and_return_is_a_load_and_unload() -> None:
    _, s = triangles(30.0)
    assert stretch_and_return(s[:240], 30.0)  # rest, up, down
    assert not stretch_and_return(s[40:140], 30.0)  # up only
    assert not stretch_and_return(np.full(100, 5.0), 30.0)
    assert not stretch_and_return(0.01 * np.sin(np.arange(100.0)), 30.0)  # a hold's noise


@pytest.mark.parametrize("window, words", [("50:90", "runs beyond"), ("20:10", "after START"),
                                           ("0:1.5", "no stretch and return"),
                                           ("x:3", "START:END")])
def test_cli_refuses_a_bad_window_in_one_line(window: str, words: str, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    from strain_comp.io.recording import write_recordings

    path, bag, out = tmp_path / "cal.yaml", tmp_path / "run.mcap", tmp_path / "out.yaml"
    save_calibration(Calibration({"s1": fit_sensor(RUNS[:1], "cubic", name="s1")}), path)
    write_recordings({NEW.name: NEW}, str(bag))
    assert cli(["recalibrate", str(path), "--input", "--from", str(bag), "--window", window,
                "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("strain-comp: error:") and words in err[0]
    assert not out.exists()
    assert cli(["recalibrate", str(path), "--from", str(bag), "--window", "12:22",
                "--out", str(out)]) == 0
    assert load_calibration(out).sensors["s1"].provenance["recalibrations"][0]["window"] == [
        12.0, 22.0]


def test_cli_fit_pools_in_one_space_unless_asked_raw(tmp_path: Path) -> None:
    from strain_comp.io.recording import write_recordings

    bags = []
    for i, rec in enumerate(RUNS):
        bags.append(str(tmp_path / f"run{i}.mcap"))
        write_recordings({rec.name: rec}, bags[-1])
    for pool in ("spanned", "joint", "stretch", "raw"):
        out = tmp_path / f"{pool}.yaml"
        assert cli(["fit", *bags, "--model", "cubic", "--sensor", "s1", "--pool", pool,
                    "--out", str(out), "--quiet"]) == 0
        cal = load_calibration(out).sensors["s1"]
        assert ("pooled_runs" in cal.provenance) == (pool != "raw")
        assert cal.provenance["pooling"]["pool"] == ("joint" if pool == "spanned" else pool)
        assert (cal.input.stretch_line is not None) == (pool == "stretch")


def test_a_window_keeps_the_warm_up_unreferenced_for_the_engine() -> None:
    """The engine runs from the bag's start (a memory model enters the window in the state
    the warm-up left); only the window's reference is fitted to."""
    from strain_comp.offline.session_start import window_of as window

    cal = Calibration({"s1": fit_sensor(RUNS[:1], "cubic", name="s1")})
    part = window({"s1": NEW}, (12.0, 22.0), cal)["s1"]
    assert part.t[0] == NEW.t[0] and part.t[-1] == pytest.approx(22.0, abs=0.05)
    assert part.s is not None and NEW.s is not None
    assert np.isnan(part.s[part.t < 12.0]).all()
    assert part.s[part.t >= 12.0] == pytest.approx(NEW.s[(NEW.t >= 12.0) & (NEW.t <= 22.0)])


def test_the_session_start_of_a_stretch_calibration_is_its_input_step(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``recalibrate --input`` puts a new run's stretch line onto the calibration's (exact
    for a run that differs by an affine map of R) and says it is the whole session start;
    ``session_start`` from Python makes no output step; a stretch whose resistance falls
    with strain is refused in one line."""
    import strain_comp as sc
    from strain_comp.io.recording import write_recordings

    path, bag, out = tmp_path / "cal.yaml", tmp_path / "start.mcap", tmp_path / "out.yaml"
    save_calibration(Calibration({"s1": fit_sensor(MOVING, "cubic", name="s1",
                                                   pool="stretch")}), path)
    new = moving(1120.0, 1.25)
    write_recordings({new.name: new}, str(bag))
    assert cli(["recalibrate", str(path), "--input", "--from", str(bag), "--window",
                "11.5:21.5", "--out", str(out)]) == 0
    assert "no output step" in capsys.readouterr().out
    started = load_calibration(out).sensors["s1"]
    space = started.input.stretch_line
    assert space is not None and started.input.zero_span is not None
    rest, rest_cal, k = started.input.zero_span
    s = np.linspace(0.0, 30.0, 7)  # the new run mapped reads as the anchor run (the gauge)
    assert rest_cal + k * (1120.0 + 1.25 * (gauge(s) - 1000.0) - rest) == pytest.approx(
        gauge(s), rel=1e-6)
    python = sc.session_start(str(path), str(bag), window=(11.5, 21.5))
    assert len(python.readings) == 1 and python.calibration.sensors["s1"].effects == []
    assert python.calibration.sensors["s1"].input.zero_span == pytest.approx(
        started.input.zero_span, rel=1e-12)
    falling = Recording("s1", new.t, 3000.0 - new.r, new.s)
    write_recordings({falling.name: falling}, str(bag))
    assert cli(["recalibrate", str(path), "--input", "--from", str(bag), "--window",
                "11.5:21.5", "--out", str(tmp_path / "no.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not move with the reference strain" in err[0]
    assert not (tmp_path / "no.yaml").exists()


def test_the_stretches_count_from_the_runs_first_sample() -> None:
    """A reference that starts late (NaN for the first 5 s) moves the stretches by those
    5 s: seconds count from the run's first sample, as ``--window`` and ``cut`` count."""
    t, tri = MOVING[0].t, MOVING[0].s
    assert tri is not None
    late = np.concatenate([np.full(100, np.nan), tri])
    t_late = np.concatenate([0.05 * np.arange(100), t + 5.0])
    assert calibration_stretch(t, tri) == pytest.approx((11.5, 21.5), abs=0.1)
    assert calibration_stretch(t_late, late) == pytest.approx((16.5, 26.5), abs=0.1)


def test_a_stretch_line_too_flat_for_the_calibrated_range_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A stretch line of slope 1e-9 ohm per % (the range's slope is ~1 ohm per %) would
    read every resistance alike: the reader refuses it, so recalibrate cannot start from
    it; the line the fit gave loads."""
    import yaml

    path = tmp_path / "cal.yaml"
    save_calibration(Calibration({"s1": fit_sensor(MOVING, "cubic", name="s1",
                                                   pool="stretch")}), path)
    assert load_calibration(path).sensors["s1"].input.stretch_line is not None
    data = yaml.safe_load(path.read_text())
    data["sensors"]["s1"]["input"]["stretch_line"]["slope"] = 1e-9
    path.write_text(yaml.safe_dump(data))
    bag = tmp_path / "start.mcap"
    from strain_comp.io.recording import write_recordings
    write_recordings({"s1": moving(1120.0, 1.25)}, str(bag))
    assert cli(["recalibrate", str(path), "--input", "--from", str(bag), "--window",
                "11.5:21.5", "--out", str(tmp_path / "out.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "stretch_line.slope: 1e-09 ohm per strain unit" in err and "\n" not in err
    assert not (tmp_path / "out.yaml").exists()


def test_recalibrate_refuses_a_sensor_the_calibration_lacks(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from strain_comp.io.recording import write_recordings

    path, bag = tmp_path / "cal.yaml", tmp_path / "run.mcap"
    save_calibration(Calibration({"s1": fit_sensor(RUNS[:1], "cubic", name="s1")}), path)
    write_recordings({NEW.name: NEW}, str(bag))
    before = path.read_bytes()
    assert cli(["recalibrate", str(path), "--from", str(bag), "--sensor", "S2", "--out",
                str(path.with_name("out.yaml"))]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "strain-comp: error: sensor 'S2' is not in the calibration (its sensors: s1)"
    assert not path.with_name("out.yaml").exists() and path.read_bytes() == before
