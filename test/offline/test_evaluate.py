"""Evaluation: the table and JSON equal error_stats computed independently; plots are written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from strain_comp.base.direction import DirectionSettings
from strain_comp.base.samples import good_mask
from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.core.metrics import error_stats
from strain_comp.errors import InputError
from strain_comp.io.bag import BagWriter
from strain_comp.io.recording import Recording, load_recordings
from strain_comp.models import Normalisation
from strain_comp.offline.evaluate import evaluate_bag, evaluate_recordings
from strain_comp.offline.evaluation import format_notes, format_table

C = [-50.0, 0.5, 0.0, 0.0]  # S = 0.5 R - 50: R in [100, 150] ohm -> S in [0, 25] %


def calibration() -> Calibration:
    cal = SensorCalibration(
        name="s1", model="cubic", params={"c": C},
        normalisation=Normalisation.from_ranges(100.0, 150.0, 0.0, 25.0),
        valid_range=ValidRange(95.0, 155.0, -2.5, 27.5),
        direction=DirectionSettings(deadzone=0.5, tau=0.0, k_sigma=4.0))
    return Calibration({"s1": cal})


def data() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 60.0, 0.02)
    s = 12.5 + 12.0 * np.sin(2 * np.pi * t / 15.0)
    r = (s + 50.0) / 0.5 + 0.4 * rng.standard_normal(t.size) + 1.5 * np.sin(t)  # model error
    r[[100, 101, 2000]] = [np.nan, -3.0, np.inf]
    return t, r, s


def recording(name: str = "s1", *, with_reference: bool = True) -> Recording:
    t, r, s = data()
    return Recording(name=name, t=t, r=r, s=s if with_reference else None, temperature=None,
                     array=None, index=None)


def test_recordings_with_bad_time_stamps_score_each_sample_on_its_own_reference() -> None:
    """NaN stamps, a repeated one and a step back: screened by the engine as in a bag's
    replay, every other sample scored against the reference recorded with it."""
    t, r, s = data()
    t[[300, 600, 900, 1200, 1500, -1]] = [np.nan, np.nan, t[899], np.nan, t[1500] - 0.5,
                                          np.nan]
    rec = Recording(name="s1", t=t, r=r, s=s)
    got = evaluate_recordings({"s1": rec}, calibration()).sensors["s1"]
    good = good_mask(t, r)
    expected = error_stats(0.5 * r[good] - 50.0, s[good])
    assert got.stats.n == expected.n == t.size - 9
    assert got.stats.rmse == pytest.approx(expected.rmse, rel=1e-12)
    assert (got.n_samples, got.n_bad) == (t.size, 9)

def test_a_sensor_on_two_topics_is_scored_once_as_the_recordings_read_it(tmp_path: Path
                                                                          ) -> None:
    """An array's label that another topic also names: the bag is scored as
    ``load_recordings`` reads it, the first topic's samples, the other skipped and said."""
    t, r, s = data()
    path = tmp_path / "twice.mcap"
    with BagWriter(path) as writer:
        writer.write_float64_array("/arr/resistance", t, np.column_stack([r, r]), ["s1", "b"])
        writer.write_float64_array("/arr/strain_reference", t, np.column_stack([s, s]),
                                   ["s1", "b"])
        writer.write_float64("/s1/resistance", t, r + 20.0)
        writer.write_float64("/s1/strain_reference", t, s)
    recordings, read = load_recordings(path)
    streamed, problems = evaluate_bag(path, calibration())
    whole = evaluate_recordings(recordings, calibration()).sensors["s1"].stats
    assert streamed.sensors["s1"].stats == whole
    assert whole.n == t.size - 3
    assert problems == read == [f"{path}: /s1/resistance: sensor s1 appears twice; column 0 "
                                "skipped"]

def test_table_and_json_equal_independent_error_stats() -> None:
    result = evaluate_recordings({"s1": recording()}, calibration())
    t, r, s = data()
    good = np.isfinite(r) & (r > 0)
    expected = error_stats(0.5 * r[good] - 50.0, s[good])  # eq. (4) with c by hand
    got = result.sensors["s1"].stats
    for key in ("rmse", "mae", "max_abs", "r2"):
        assert getattr(got, key) == pytest.approx(getattr(expected, key), rel=1e-9)
    assert got.n == expected.n == t.size - 3
    table = format_table(result)
    row = next(line for line in table.splitlines() if line.startswith("s1 "))
    assert row.split() == ["s1", "cubic", str(expected.n), f"{expected.rmse:.4f}",
                           f"{expected.mae:.4f}", f"{expected.max_abs:.4f}",
                           f"{expected.r2:.5f}"]
    document = json.loads(json.dumps(result.to_json()))
    assert list(document) == ["sensors"] and list(document["sensors"]) == ["s1"]
    record = document["sensors"]["s1"]
    assert {"rmse", "mae", "max_abs", "r2", "n"} <= set(record)
    assert record["rmse"] == pytest.approx(expected.rmse, rel=1e-12)
    assert record["n"] == expected.n and record["n_bad"] == 3
    notes = format_notes(result)
    assert any("3 of" in line and "bad" in line for line in notes)


def test_unscorable_sensors_are_noted_and_nothing_scorable_is_an_error() -> None:
    cal = calibration()
    cal.sensors["s2"] = SensorCalibration(**{**cal.sensors["s1"].__dict__, "name": "s2"})
    result = evaluate_recordings({"s1": recording()}, cal)
    assert list(result.sensors) == ["s1"]
    assert any(note.startswith("s2:") for note in result.notes)
    with pytest.raises(InputError, match="no calibrated sensor"):
        evaluate_recordings({"s1": recording(with_reference=False)}, calibration())
    with pytest.raises(InputError, match="no calibrated sensor"):
        evaluate_recordings({"other": recording("other")}, calibration())


def test_plots_are_written(tmp_path: Path) -> None:
    from strain_comp.offline.plots import evaluation_figures, write_plots

    result = evaluate_recordings({"s1": recording()}, calibration())
    written = write_plots(evaluation_figures(result, calibration(), bag="runs/b.mcap",
                                             calibration_path="c/cal.yaml", tare="auto"),
                          tmp_path / "plots")
    assert sorted(p.name for p in written) == ["s1_error_hist.png", "s1_loop.png",
                                               "s1_raw.png", "s1_time.png"]
    for path in written:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


def test_plot_titles_name_bag_calibration_and_tare_and_axes_span_the_data() -> None:
    from strain_comp.offline.evaluation import SensorEvaluation
    from strain_comp.offline.plots import _limits, context_line

    result = evaluate_recordings({"s1": recording()}, calibration())
    result.notes.append("s1: not tared: the run does not start at rest")
    assert context_line(result, "s1", "runs/b.mcap", "c/cal.yaml", "auto") == (
        "bag b.mcap, calibration cal.yaml, rest level (tare) from the run's start (--tare "
        "auto) (not tared: the run does not start at rest)")
    values = np.array([np.nan, -2.0, 3.0, np.inf, 8.0])
    assert _limits(values) == (-2.5, 8.5)  # finite data plus 5 % of its span each side
    assert _limits(np.array([np.nan])) is None
    assert isinstance(result.sensors["s1"], SensorEvaluation)
    assert result.sensors["s1"].out_of_range.shape == result.sensors["s1"].t.shape


def test_a_temperature_term_without_temperature_in_the_data_is_noted(tmp_path: Path) -> None:
    """A calibration with a temperature term scored on a run without a temperature topic:
    the term reads nothing (g = 0), the estimate is the bare model's, and the notes say so,
    in memory and streamed alike; with temperature, no note and the term applies."""
    from dataclasses import replace

    from strain_comp.io.recording import write_recordings
    from strain_comp.offline.evaluate import evaluate_bag

    bare = calibration()
    term = {"name": "temperature_offset", "kind": "temperature",
            "params": {"form": "offset", "t_ref": 23.0}, "coef": 0.5}
    cal = Calibration({"s1": replace(bare.sensors["s1"], effects=[term])})
    rec = recording()
    note = "s1: no temperature in the data: the calibration's temperature term " \
           "temperature_offset is not applied"
    without = evaluate_recordings({"s1": rec}, cal)
    assert note in format_notes(without)
    assert without.sensors["s1"].stats.rmse == evaluate_recordings(
        {"s1": rec}, bare).sensors["s1"].stats.rmse
    path = tmp_path / "no_temperature.mcap"
    write_recordings({rec.name: rec}, path)
    streamed, _ = evaluate_bag(path, cal, window=500)
    assert note in format_notes(streamed)
    warm = replace(rec, temperature=np.full(rec.t.size, 25.0))
    with_t = evaluate_recordings({"s1": warm}, cal)
    assert not any("temperature" in line for line in format_notes(with_t))
    path = tmp_path / "temperature.mcap"
    write_recordings({warm.name: warm}, path)
    streamed, _ = evaluate_bag(path, cal, window=500)
    assert not any("temperature" in line for line in format_notes(streamed))
    assert streamed.sensors["s1"].stats.rmse != without.sensors["s1"].stats.rmse


def test_a_crosstalk_term_whose_neighbour_is_on_another_topic_is_noted(tmp_path: Path) -> None:
    """A cross-talk term (fitted on an array topic) scored on sensors recorded on separate
    topics reads its neighbour batch by batch, not tick by tick: the notes say so, in
    memory and streamed; on one array topic there is no such note."""
    from dataclasses import replace

    from strain_comp.io.bag import BagWriter
    from strain_comp.offline.evaluate import evaluate_bag

    bare = calibration().sensors["s1"]
    term = {"name": "crosstalk_s2", "kind": "crosstalk", "params": {"neighbour": "s2"},
            "coef": 0.05}
    cal = Calibration({"s1": replace(bare, effects=[term]), "s2": replace(bare, name="s2")})
    t, r, s = data()
    apart = {n: replace(recording(n), r=r) for n in ("s1", "s2")}
    note = "s1: cross-talk term crosstalk_s2 (s2) reads a sensor not recorded on its array"
    assert any(line.startswith(note) for line in format_notes(evaluate_recordings(apart, cal)))
    together = {n: replace(rec, array="arr", index=i) for i, (n, rec) in
                enumerate(apart.items())}
    assert not any("cross-talk" in line
                   for line in format_notes(evaluate_recordings(together, cal)))
    for path, arrayed in ((tmp_path / "apart.mcap", False), (tmp_path / "arr.mcap", True)):
        with BagWriter(path) as writer:
            if arrayed:
                writer.write_float64_array("/arr/resistance", t, np.column_stack([r, r]),
                                           ["s1", "s2"])
                writer.write_float64_array("/arr/strain_reference", t, np.column_stack([s, s]),
                                           ["s1", "s2"])
            else:
                for n in ("s1", "s2"):
                    writer.write_float64(f"/{n}/resistance", t, r)
                    writer.write_float64(f"/{n}/strain_reference", t, s)
        notes = format_notes(evaluate_bag(path, cal, window=500)[0])
        assert any(line.startswith(note) for line in notes) is not arrayed, notes
