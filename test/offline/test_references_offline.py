"""``evaluate --references-every`` and ``replay --references-every``: the bag's own
reference fused at a spacing, on a sensor whose sensitivity changed by a known factor."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import BAGS, CHANGED_SENSITIVITY, CONFIG, changed_run, line_calibration

from strain_comp.cli import main
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.errors import InputError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.recording import Recording, load_recordings
from strain_comp.offline.evaluate import evaluate_bag, evaluate_recordings
from strain_comp.offline.replay import replay_bag


def write(path: Path, *, reference: bool = True) -> Path:
    t, r, s = changed_run()
    with BagWriter(path, chunk_size=500) as w:
        w.write_float64("/s1/resistance", t, r)
        if reference:
            w.write_float64("/s1/strain_reference", t, s)
    return path


def test_references_every_30_s_recover_a_changed_sensitivity(tmp_path: Path) -> None:
    t, r, s = changed_run()
    rec = {"s1": Recording("s1", t, r, s)}
    plain = evaluate_recordings(rec, line_calibration()).sensors["s1"]
    fused = evaluate_recordings(rec, line_calibration(), references_every=30.0).sensors["s1"]
    assert plain.stats.rmse > 2.0  # a 20 % gain error on strains up to 25 %
    assert fused.stats.rmse < 0.35 * plain.stats.rmse
    late = t > 100.0  # after three references
    assert np.sqrt(np.mean((fused.estimate - s)[late] ** 2)) < 0.15 * np.sqrt(
        np.mean((plain.estimate - s)[late] ** 2))
    assert fused.references is not None
    assert fused.references["n_used"] == 9 and fused.references["n_refused"] == 0
    assert fused.references["gain"] == pytest.approx(1.0 / CHANGED_SENSITIVITY, rel=0.05)
    # before the first reference the estimate is the engine's own
    first = t <= 30.0
    assert np.array_equal(fused.estimate[first], plain.estimate[first])
    # streamed in pieces, the same numbers
    streamed, _ = evaluate_bag(write(tmp_path / "run.mcap"), line_calibration(), window=700,
                               references_every=30.0)
    got = streamed.sensors["s1"]
    assert got.stats.rmse == pytest.approx(fused.stats.rmse, rel=1e-9)
    assert got.references == fused.references
    record = json.loads(json.dumps(fused.to_dict()))
    assert record["references"]["every"] == 30.0 and record["references"]["n_used"] == 9


@pytest.mark.parametrize(("bag", "cal"), [("demo_rates", "demo_calibration"),
                                          ("array", "array_calibration")])
def test_streamed_fusion_of_the_bundled_bags_equals_the_whole_series(bag: str, cal: str
                                                                      ) -> None:
    calibration = load_calibration(CONFIG / f"{cal}.yaml")
    recordings, _ = load_recordings(BAGS / f"{bag}.mcap")
    whole = evaluate_recordings(recordings, calibration, references_every=5.0)
    pieces, _ = evaluate_bag(BAGS / f"{bag}.mcap", calibration, window=900,
                             references_every=5.0)
    for name, ev in whole.sensors.items():
        assert ev.references is not None and ev.references["n_used"] > 0
        assert pieces.sensors[name].references == ev.references
        assert pieces.sensors[name].stats.rmse == pytest.approx(ev.stats.rmse, rel=1e-9)


def test_no_reference_or_a_bad_spacing_is_one_line_and_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t, r, _ = changed_run(60.0)
    with pytest.raises(InputError, match="s1 has no strain_reference"):
        evaluate_recordings({"s1": Recording("s1", t, r, None)}, line_calibration(),
                            references_every=10.0)
    bare = write(tmp_path / "bare.mcap", reference=False)
    cal = tmp_path / "cal.yaml"
    save_calibration(line_calibration(), cal)
    for argv in (["evaluate", str(bare), "--calibration", str(cal), "--references-every",
                  "10"],
                 ["replay", str(bare), "--calibration", str(cal), "--out",
                  str(tmp_path / "out.mcap"), "--references-every", "10"],
                 ["evaluate", str(write(tmp_path / "ok.mcap")), "--calibration", str(cal),
                  "--references-every", "-5"]):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("strain-comp: error: ")
        assert "--references-every" in err[0]
    assert not (tmp_path / "out.mcap").exists()  # nothing half written


def test_replay_writes_the_fused_strain_that_evaluate_scores(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = write(tmp_path / "run.mcap")
    cal = tmp_path / "cal.yaml"
    save_calibration(line_calibration(), cal)
    out = tmp_path / "out.mcap"
    summary = replay_bag(bag, line_calibration(), out, window=700, references_every=30.0)
    assert summary.references["s1"]["n_used"] == 9
    written = read_bag(out).series["/s1/strain"]
    ev = evaluate_recordings(load_recordings(bag)[0], line_calibration(), references_every=30.0)
    assert np.allclose(written.values, ev.sensors["s1"].estimate, rtol=0, atol=1e-9)
    # /diagnostics carries the fusion state as of each tick, as the node's does
    used = [(t, int(values["fusion_n_used"])) for t, statuses in read_bag(out).diagnostics
            for name, _, _, values in statuses if name == "strain_comp: s1"]
    assert len(used) > 250
    for t, n in used:  # a reference at each multiple of 30 s (ticks at one aside)
        if abs(t - 30.0 * round(t / 30.0)) > 0.1:
            assert n == min(9, int(t // 30.0)), t
    assert main(["replay", str(bag), "--calibration", str(cal), "--out",
                 str(tmp_path / "cli.mcap"), "--references-every", "30"]) == 0
    assert "a reference every 30 s: 9 used, 0 refused" in capsys.readouterr().err


def test_fusion_composes_with_the_tare_and_a_session_start() -> None:
    """The fusion is a stage after the engine's output: with ``--tare auto`` and a
    calibration recalibrated on the run's first cycle it still recovers the changed
    sensitivity."""
    from strain_comp.offline.session_start import recalibrate_recordings

    t, r, s = changed_run()
    rec = {"s1": Recording("s1", t, r, s)}
    cal = replace(line_calibration().sensors["s1"], rest_resistance=100.0)
    started = recalibrate_recordings(Calibration({"s1": cal}), rec, form="input",
                                     first=12.0)[0]
    assert started.sensors["s1"].input.zero_span is not None
    runs = {}
    for key, calib, tare in (("tared", Calibration({"s1": cal}), "auto"),
                             ("started", started, "calibration")):
        plain = evaluate_recordings(rec, calib, tare=tare).sensors["s1"]
        fused = evaluate_recordings(rec, calib, tare=tare,
                                    references_every=30.0).sensors["s1"]
        assert fused.references is not None and fused.references["n_used"] == 9
        runs[key] = (plain.stats.rmse, fused.stats.rmse, fused.references["gain"])
    plain, fused, gain = runs["tared"]  # the tare does not see a sensitivity: fusion does
    assert fused < 0.35 * plain and gain == pytest.approx(1.0 / CHANGED_SENSITIVITY, rel=0.05)
    plain, fused, gain = runs["started"]  # the input span corrected it: fusion keeps it
    assert plain < 0.3 and fused <= 1.05 * plain and gain == pytest.approx(1.0, abs=0.05)
