"""The Python API (strain_comp.api) gives the command line's numbers: evaluate, fit,
recalibrate and diagnose against ``strain-comp``'s JSON and files on the same data, estimate
against ``replay``'s output bag; its errors carry the line the command prints; it writes
no file unless asked."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import strain_comp as sc
from strain_comp.cli import main
from strain_comp.io.bag import read_bag
from strain_comp.offline.session_start import calibration_stretch

ROOT = Path(__file__).resolve().parents[1]
BAG = str(ROOT / "bags" / "demo_rates.mcap")
CAL = str(ROOT / "config" / "demo_calibration.yaml")
TRAIN = [str(ROOT / "bags" / "train_patterns.mcap"), str(ROOT / "bags" / "train_random.mcap")]


def cli_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The message after ``strain-comp: error:`` of a command that must fail."""
    capsys.readouterr()
    assert main(argv) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("strain-comp: error: ") and "\n" not in line
    return line.removeprefix("strain-comp: error: ")


def test_evaluate_gives_the_commands_json(tmp_path: Path) -> None:
    assert main(["evaluate", BAG, "--calibration", CAL, "--json", str(tmp_path / "e.json"),
                 "-q"]) == 0
    by_cli = json.loads((tmp_path / "e.json").read_text())
    ev = sc.evaluate(CAL, BAG)
    assert ev.to_json() == by_cli
    row = by_cli["sensors"]["s1"]
    assert ev.scores["s1"]["n"] == row["n"] == 14451
    for key in ("rmse", "mae", "max_abs", "r2"):
        assert ev.scores["s1"][key] == row[key]


def test_estimate_is_replays_output(tmp_path: Path) -> None:
    out = tmp_path / "replayed.mcap"
    assert main(["replay", BAG, "--calibration", CAL, "--out", str(out), "-q"]) == 0
    replayed = read_bag(out)
    run = sc.read_recordings(BAG)["s1"]
    strain, direction = sc.estimate(CAL, run.t, run.r)
    np.testing.assert_array_equal(replayed.series["/s1/strain"].values, strain)
    np.testing.assert_array_equal(replayed.series["/s1/direction"].values, direction)
    # and its error is evaluate's, computed here from the reference
    error = strain - run.s
    rmse = float(np.sqrt(np.mean(error[np.isfinite(error)] ** 2)))
    assert rmse == pytest.approx(sc.evaluate(CAL, BAG).scores["s1"]["rmse"], rel=1e-12)


def test_evaluate_on_recordings_equals_on_the_bag() -> None:
    from_bag = sc.evaluate(CAL, BAG).scores["s1"]
    run = sc.read_recordings(BAG)["s1"]
    again = sc.Recording.from_arrays(list(run.t), run.r, run.s, name="s1")
    from_arrays = sc.evaluate(CAL, again).scores["s1"]
    for key in ("n", "rmse", "mae", "max_abs", "r2"):
        assert from_arrays[key] == pytest.approx(from_bag[key], rel=1e-12)


def test_fit_gives_the_commands_calibration(tmp_path: Path) -> None:
    out = tmp_path / "cli.yaml"
    assert main(["fit", *TRAIN, "--model", "cubic", "--sensor", "s1", "--out", str(out),
                 "-q"]) == 0
    by_cli = sc.load_calibration(out).sensors["s1"]
    by_api = sc.fit(TRAIN, "cubic").sensors["s1"]
    assert by_api.params == by_cli.params
    assert by_api.valid_range == by_cli.valid_range
    assert by_api.provenance["bags"] == by_cli.provenance["bags"] == TRAIN
    # the same runs as arrays: the same fit
    runs = [sc.read_recordings(b)["s1"] for b in TRAIN]
    from_arrays = sc.fit(runs, "cubic").sensors["s1"]
    assert from_arrays.params == by_api.params
    assert from_arrays.provenance["bags"] == ["(arrays: s1, run 1)", "(arrays: s1, run 2)"]


def test_fit_options_and_unit(tmp_path: Path) -> None:
    runs = [sc.read_recordings(b)["s1"] for b in TRAIN]
    cal = sc.fit(runs, "rational", strain_unit="mm", mode="split")
    assert cal.sensors["s1"].strain_unit == "mm"
    assert cal.sensors["s1"].provenance["options"] == {"mode": "split"}
    sc.save_calibration(cal, tmp_path / "r.yaml")
    assert sc.load_calibration(tmp_path / "r.yaml").sensors["s1"].params == \
        cal.sensors["s1"].params


def test_recalibrate_prints_the_commands_readings(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    out = tmp_path / "span.yaml"
    assert main(["recalibrate", CAL, "--input", "--from", BAG, "--first", "30", "--out",
                 str(out), "-q"]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    spanned = sc.recalibrate(CAL, BAG, form="input", first=30)
    assert spanned.readings == printed
    assert spanned.calibration.to_dict() == sc.load_calibration(out).to_dict()
    assert main(["recalibrate", str(out), "--from", BAG, "--first", "30", "--out",
                 str(tmp_path / "field.yaml"), "-q"]) == 0
    session = sc.session_start(CAL, BAG, first=30)
    assert session.calibration.to_dict() == \
        sc.load_calibration(tmp_path / "field.yaml").to_dict()
    # the README's procedure: the calibration stretch after a warm-up one (--window)
    run = sc.read_recordings(BAG)["s1"]
    window = calibration_stretch(run.t, run.s)
    assert window is not None and window[0] > 0.0
    flag = ["--window", f"{window[0]!r}:{window[1]!r}"]
    assert main(["recalibrate", CAL, "--input", "--from", BAG, *flag, "--out", str(out),
                 "-q"]) == 0
    assert main(["recalibrate", str(out), "--from", BAG, *flag, "--out",
                 str(tmp_path / "field.yaml"), "-q"]) == 0
    warmed = sc.session_start(CAL, BAG, window=window)
    assert warmed.calibration.to_dict() == \
        sc.load_calibration(tmp_path / "field.yaml").to_dict()
    assert warmed.calibration.to_dict() != session.calibration.to_dict()


def test_diagnose_gives_the_commands_report(tmp_path: Path) -> None:
    assert main(["diagnose", BAG, "--calibration", CAL, "--out", str(tmp_path / "v2.yaml"),
                 "--json", str(tmp_path / "d.json"), "-q"]) == 0
    by_cli = json.loads((tmp_path / "d.json").read_text())
    found = sc.diagnose(CAL, sc.read_recordings(BAG))
    assert found.before["rmse"] == pytest.approx(by_cli["before"]["rmse"], rel=1e-9)
    assert found.after["rmse"] == pytest.approx(by_cli["after"]["rmse"], rel=1e-9)
    added = [e for e in by_cli["effects"] if e["added"]]
    assert [(e["name"], e["reading"]) for e in found.effects] == \
        [(e["name"], e["reading"]) for e in added]
    assert found.calibration.to_dict()["sensors"]["s1"]["effects"] == \
        sc.load_calibration(tmp_path / "v2.yaml").to_dict()["sensors"]["s1"]["effects"]


def test_the_api_writes_nothing_unless_asked(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    cal = sc.fit(TRAIN, "cubic")
    run = sc.read_recordings(BAG)["s1"]
    sc.estimate(cal, run.t, run.r)
    sc.evaluate(cal, BAG, in_run_bound=True)
    sc.session_start(cal, BAG, first=30)
    assert list(tmp_path.iterdir()) == []
    sc.evaluate(cal, BAG, csv=tmp_path / "series.csv")
    assert [p.name for p in tmp_path.iterdir()] == ["series.csv"]


@pytest.mark.parametrize("argv, call", [
    (["evaluate", BAG, "--calibration", "missing.yaml"],
     lambda: sc.evaluate("missing.yaml", BAG)),
    (["fit", *TRAIN, "--model", "cubic", "--sensor", "s1", "--out", "x.yaml", "--option",
      "N=3"], lambda: sc.fit(TRAIN, "cubic", N=3)),
    (["fit", *TRAIN, "--model", "cubic", "--sensor", "nope", "--out", "x.yaml"],
     lambda: sc.fit(TRAIN, "cubic", sensors=["nope"])),
    (["evaluate", BAG, "--calibration", CAL, "--tare", "sometimes"],
     lambda: sc.evaluate(CAL, BAG, tare="sometimes")),
])
def test_errors_carry_the_commands_line(argv: list[str], call: object, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    line = cli_error(argv, capsys)
    with pytest.raises(sc.StrainCompError) as err:
        call()  # type: ignore[operator]
    if "--tare" in argv:  # argparse refuses the choice first; the API names the value
        assert "sometimes" in line and "sometimes" in str(err.value)
    else:
        assert " ".join(str(err.value).split()) == line


def test_recording_from_arrays_and_tables() -> None:
    t = np.arange(5.0)
    rec = sc.Recording.from_arrays(t, [1, 2, 3, 4, 5], name="a")
    assert rec.s is None and rec.r.dtype == np.float64 and len(rec) == 5
    table = {"time_s": t, "resistance_ohm": t + 1, "reference": t * 2}
    from_table = sc.Recording.from_frame(table, name="a")
    np.testing.assert_array_equal(from_table.s, t * 2)
    with pytest.raises(sc.StrainCompError, match="r has 4 samples, t has 5"):
        sc.Recording.from_arrays(t, t[:4])
    with pytest.raises(sc.StrainCompError, match="must be 1-D"):
        sc.Recording.from_arrays(t, np.ones((5, 2)))
    with pytest.raises(sc.StrainCompError, match="no column 'resistance_ohm'"):
        sc.Recording.from_frame({"time_s": t})
    with pytest.raises(sc.StrainCompError, match="not numbers"):
        sc.Recording.from_arrays(t, ["a"] * 5)


def test_dataframes_in_and_out() -> None:
    pd = pytest.importorskip("pandas")
    run = sc.read_recordings(BAG)["s1"]
    frame = pd.DataFrame({"time_s": run.t, "resistance_ohm": run.r, "reference": run.s})
    ev = sc.evaluate(CAL, sc.Recording.from_frame(frame, name="s1"))
    table = ev.to_frame()
    assert table.loc[("apl", "recordings", "s1"), "rmse"] == pytest.approx(
        sc.evaluate(CAL, BAG).scores["s1"]["rmse"], rel=1e-12)


def test_version_and_help_do_not_load_numpy() -> None:
    code = ("import sys, strain_comp; strain_comp.__version__; "
            "print('numpy' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    assert out.stdout.strip() == "False"
    assert callable(sc.estimate) and "estimate" in sc.__all__


# ------------------------------------------------- round five: what the API refuses, and how

def _fit_args(run: sc.Recording) -> list[tuple[str, object]]:
    """Calls with an argument of the wrong type, each with the argument the line names."""
    cal = sc.load_calibration(CAL)
    return [
        ("strain_unit", lambda: sc.fit(run, strain_unit=5)),
        ("sensor", lambda: sc.estimate(cal, run.t, run.r, sensor=["s1"])),
        ("plot_points", lambda: sc.evaluate(cal, run, plot_points="50")),
        ("window", lambda: sc.recalibrate(cal, run, window="20:45")),
        ("first", lambda: sc.recalibrate(cal, run, first="30")),
        ("point", lambda: sc.recalibrate(cal, points=["11.5,0", (19.0, 20.0)])),
        ("data", lambda: sc.fit(run.t, run.r)),
        ("Recording", lambda: sc.fit({"s1": 5})),
        ("Recording", lambda: sc.evaluate(cal, {"s1": run.t})),
        ("Recording", lambda: sc.session_start(cal, {"s1": None})),
        ("'n/a'", lambda: sc.Recording.from_frame(
            {"time_s": [0.0, 1.0], "resistance_ohm": ["11.5", "n/a"]})),
        ("DataFrame", lambda: sc.Recording.from_frame([[0.0, 11.5], [1.0, 11.6]])),
    ]


def test_arguments_of_the_wrong_type_raise_one_line_naming_them() -> None:
    run = sc.read_recordings(BAG)["s1"]
    for words, call in _fit_args(run):
        with pytest.raises(sc.StrainCompError) as err:
            call()  # type: ignore[operator]
        assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("words, call", [
    ("strain_unit=None", lambda run: sc.fit(run, strain_unit=None)),
    ("input_unit=None", lambda run: sc.fit(run, input_unit=None)),
    ("data: expected", lambda run: sc.fit(None)),
    ("tare=None", lambda run: sc.estimate(CAL, run.t, run.r, tare=None)),
    ("out_of_range=None", lambda run: sc.evaluate(CAL, run, out_of_range=None)),
    ("plot_points=None", lambda run: sc.evaluate(CAL, run, plot_points=None)),
    ("tare=None", lambda run: sc.session_start(CAL, run, tare=None)),
    ("t (the time) is required", lambda run: sc.estimate(CAL, None, run.r)),
    ("r (the resistance) is required", lambda run: sc.estimate(CAL, run.t, None)),
    ("t (the time) is required", lambda run: sc.Recording.from_frame(
        {"time_s": run.t, "resistance_ohm": run.r}, time=None)),
    ("r (the resistance) is required", lambda run: sc.fit(sc.Recording.from_frame(
        {"time_s": run.t, "resistance_ohm": run.r}, resistance=None))),
])
def test_none_for_an_argument_with_a_value_as_default_is_refused_naming_it(
        words: str, call: object) -> None:
    """What ``fuzz.py --target api`` found: None where the argument's default is a value
    (a unit, a tare mode, the data, the time or resistance column) reached ``len``, an
    assert or the command line's ``--tare`` wording."""
    run = sc.read_recordings(BAG)["s1"]
    with pytest.raises(sc.StrainCompError) as err:
        call(run)  # type: ignore[operator]
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("call", [
    lambda bags, tmp: sc.recalibrate(CAL, bags, first=20.0),
    lambda bags, tmp: sc.session_start(CAL, bags),
    lambda bags, tmp: sc.diagnose(CAL, bags),
    lambda bags, tmp: sc.replay(CAL, bags, out=tmp / "out.mcap"),
])
def test_one_run_given_as_several_bags_is_refused_not_read_from_the_first(
        call: object, tmp_path: Path) -> None:
    """Where a function reads one run, two bag paths are refused in one line (recalibrate,
    session_start and replay read the first and dropped the second without a word)."""
    with pytest.raises(sc.StrainCompError, match=r"^(bag: )?expected .*one .* got 2 (bag )?paths$"):
        call([BAG, str(ROOT / "bags" / "steps.mcap")], tmp_path)  # type: ignore[operator]


def test_none_still_means_the_default_where_the_default_is_none() -> None:
    run = sc.read_recordings(BAG)["s1"]
    given = sc.estimate(CAL, run.t, run.r, sensor=None, temperature=None)
    np.testing.assert_array_equal(given.strain, sc.estimate(CAL, run.t, run.r).strain)


def test_from_frame_takes_import_csvs_scales() -> None:
    t = np.arange(5.0)
    table = {"time_ms": t * 1000.0, "r_kohm": (t + 11.0) / 1000.0, "fraction": t / 100.0}
    rec = sc.Recording.from_frame(table, time="time_ms", resistance="r_kohm",
                                  reference="fraction",
                                  scales={"time": 1e-3, "resistance": 1000.0, "strain": 100.0})
    np.testing.assert_allclose(rec.t, t)
    np.testing.assert_allclose(rec.r, t + 11.0)
    np.testing.assert_allclose(rec.s, t)
    with pytest.raises(sc.StrainCompError, match="unknown scale key 'temp'"):
        sc.Recording.from_frame(table, scales={"temp": 2.0})


def test_recalibrate_through_points_too_close_is_refused_as_the_command_refuses(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    points = [(11.5, 0.0), (11.5 + 1e-10, 20.0)]
    line = cli_error(["recalibrate", CAL, "--input", "--out", str(tmp_path / "x.yaml"),
                      *(f"--point={r!r}:{s!r}" for r, s in points)], capsys)
    with pytest.raises(sc.StrainCompError) as err:
        sc.recalibrate(CAL, points=points, form="input")
    assert str(err.value) == line and "span gain" in line
    assert not (tmp_path / "x.yaml").exists()


def test_nan_in_gives_nan_out_with_a_validity_mask() -> None:
    run = sc.read_recordings(BAG)["s1"]
    r = run.r.copy()
    r[100:110] = np.nan
    est = sc.estimate(CAL, run.t, r)
    assert np.isnan(est.strain[100:110]).all() and not est.valid[100:110].any()
    assert est.valid.sum() == run.t.size - 10 and np.isfinite(est.strain[est.valid]).all()
    # elsewhere the node's numbers: the clean run's strain up to the gap
    clean = sc.estimate(CAL, run.t, run.r)
    np.testing.assert_array_equal(est.strain[:100], clean.strain[:100])
    strain, direction = est  # unpacks as before
    assert strain is est.strain and direction is est.direction


def test_time_that_does_not_increase_is_refused() -> None:
    run = sc.read_recordings(BAG)["s1"]
    with pytest.raises(sc.StrainCompError, match="time stamps must increase"):
        sc.estimate(CAL, run.t[::-1], run.r)


def test_evaluate_says_how_many_samples_it_left_out_for_want_of_a_reference() -> None:
    run = sc.read_recordings(BAG)["s1"]
    s = run.s.copy()
    s[100:110] = np.nan
    ev = sc.evaluate(CAL, sc.Recording.from_arrays(run.t, run.r, s, name="s1"))
    assert ev.scores["s1"]["n"] == run.t.size - 10
    assert any(note.startswith(f"s1: 10 of {run.t.size} samples without a finite reference")
               for note in ev.notes), ev.notes


def test_a_reference_beyond_what_a_calibration_holds_is_refused_as_fit_refuses(
        tmp_path: Path) -> None:
    run = sc.read_recordings(BAG)["s1"]
    s = run.s.copy()
    s[50] = 1e200
    huge = sc.Recording.from_arrays(run.t, run.r, s, name="s1")
    with pytest.raises(sc.StrainCompError, match=r"reaches 1e\+200, beyond the \+/- 1e\+06"):
        sc.evaluate(CAL, huge)
    with pytest.raises(sc.StrainCompError, match=r"reaches 1e\+200, beyond the \+/- 1e\+06"):
        sc.fit(huge, "cubic")
    from strain_comp.io.recording import write_recordings
    write_recordings({huge.name: huge}, tmp_path / "huge.mcap")
    out = tmp_path / "e.json"
    assert main(["evaluate", str(tmp_path / "huge.mcap"), "--calibration", CAL, "--json",
                 str(out), "-q"]) == 2  # the streamed bag too
    assert not out.exists()


def test_references_every_below_the_sampling_interval_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "e.json"
    line = cli_error(["evaluate", BAG, "--calibration", CAL, "--references-every", "1e-6",
                      "--json", str(out)], capsys)
    assert "below the sampling interval (0.04 s)" in line and not out.exists()
    with pytest.raises(sc.StrainCompError) as err:
        sc.evaluate(CAL, sc.read_recordings(BAG), references_every=1e-6)
    assert str(err.value) == line


def test_stacked_frames_of_models_and_runs_keep_a_unique_index() -> None:
    pd = pytest.importorskip("pandas")
    cubic = sc.fit(TRAIN, "cubic")
    run = sc.read_recordings(BAG)["s1"]
    frames = [sc.evaluate(cal, data).to_frame(run=label)
              for cal in (CAL, cubic) for label, data in (("bag", BAG), ("arrays", run))]
    table = pd.concat(frames)
    assert table.index.is_unique and table.index.names == ["model", "run", "sensor"]
    assert table.loc[("cubic", "bag", "s1"), "rmse"] == sc.evaluate(cubic, BAG).scores["s1"][
        "rmse"]
    assert list(table.columns) == ["n", "rmse", "mae", "max_abs", "r2", "unit"]


def test_the_score_names_are_one_set_in_the_table_json_and_python() -> None:
    ev = sc.evaluate(CAL, BAG)
    keys = ["n", "rmse", "mae", "max_abs", "r2"]
    assert [k for k in ev.scores["s1"] if k in keys] == keys
    assert set(keys) <= set(ev.to_json()["sensors"]["s1"])
    header = ev.table().splitlines()[0].split()
    assert header[2:] == ["n", "RMSE", "MAE", "max_abs", "r2"]


def test_a_notebook_sees_the_names_and_short_reprs() -> None:
    code = ("import sys, strain_comp; names = dir(strain_comp); "
            "print('fit' in names and 'StrainEstimator' in names and 'Any' not in names, "
            "'numpy' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    assert out.stdout.split() == ["True", "False"]
    import pydoc
    text = pydoc.plain(pydoc.render_doc(sc))
    assert "FUNCTIONS" in text and "\n    evaluate(" in text
    cal = sc.load_calibration(CAL)
    assert repr(cal) == "Calibration(1 sensor: s1 (apl, fit RMSE 0.5303 % strain))"
    ev = sc.evaluate(cal, BAG)
    assert repr(ev) == f"Evaluation({BAG}: s1 (apl, n 14451, RMSE 0.4433 % strain))"
    assert ev._repr_html_().startswith("<table") and "<td>s1</td>" in cal._repr_html_()


def test_an_estimator_fits_predicts_and_scores_as_the_functions() -> None:
    run = sc.read_recordings(BAG)["s1"]
    model = sc.StrainEstimator("cubic").fit(TRAIN)
    direct = sc.fit(TRAIN, "cubic")
    assert model.calibration_ is not None
    assert model.calibration_.sensors["s1"].params == direct.sensors["s1"].params
    np.testing.assert_array_equal(model.predict(run.t, run.r),
                                  sc.estimate(direct, run.t, run.r).strain)
    assert model.score(BAG) == sc.evaluate(direct, BAG).scores
    given = sc.StrainEstimator.from_calibration(CAL)
    assert given.score(run)["s1"]["rmse"] == pytest.approx(0.4433, abs=5e-5)
    with pytest.raises(sc.StrainCompError, match="call fit"):
        sc.StrainEstimator().predict(run.t, run.r)


def test_a_resistance_that_looks_like_a_ratio_is_warned_about_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = sc.read_recordings(TRAIN[0])["s1"]
    ratio = sc.Recording.from_arrays(run.t, run.r / run.r[0], run.s, name="s1")
    with pytest.warns(UserWarning, match=r"looks like|ratio \(R/R0\)") as caught:
        sc.fit(ratio, "cubic")
    assert len(caught) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sc.fit(ratio, "cubic", input_unit="R/R0")  # said so: no warning
        sc.fit(run, "cubic")  # ohm: none
    from strain_comp.io.recording import write_recordings
    write_recordings({ratio.name: ratio}, tmp_path / "ratio.mcap")
    assert main(["fit", str(tmp_path / "ratio.mcap"), "--model", "cubic", "--sensor", "s1",
                 "--out", str(tmp_path / "c.yaml")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "R/R0" in line]
    assert len(err) == 1 and err[0].startswith("sensor 's1': its resistance spans 0.88")
