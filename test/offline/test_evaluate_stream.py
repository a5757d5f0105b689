"""Streamed evaluation: ``evaluate_bag`` over a bag read in small pieces equals
``evaluate_recordings`` over the whole recordings (``load_recordings``), the in-memory
reference; its pieces (running error sums, alignment across pieces) against their
whole-series counterparts."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import BAGS, CONFIG, cubic_cal

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.metrics import ErrorAccumulator, error_stats
from strain_comp.errors import InputError
from strain_comp.io.bag import BagWriter
from strain_comp.io.recording import PieceAlign, Recording, align, load_recordings
from strain_comp.offline.evaluate import _Kept, evaluate_bag, evaluate_recordings
from strain_comp.offline.evaluation import EvaluationResult, format_table


def assert_same(streamed: EvaluationResult, whole: EvaluationResult) -> None:
    assert list(streamed.sensors) == list(whole.sensors)
    assert streamed.notes == whole.notes
    for name, ev in whole.sensors.items():
        got = streamed.sensors[name]
        assert got.stats.n == ev.stats.n > 0
        for key in ("rmse", "mae", "max_abs", "r2"):
            assert math.isclose(getattr(got.stats, key), getattr(ev.stats, key),
                                rel_tol=1e-9), (name, key)
        assert (got.n_samples, got.n_bad, got.n_out_of_range, got.bad_by_status) == \
            (ev.n_samples, ev.n_bad, ev.n_out_of_range, ev.bad_by_status)


@pytest.mark.parametrize(("bag", "cal"), [("steps", "demo_calibration"),
                                          ("demo_rates", "demo_calibration"),
                                          ("array", "array_calibration")])
@pytest.mark.parametrize("tare", ["calibration", "auto"])
def test_streamed_evaluate_of_the_bundled_bags_equals_the_whole_series(
        bag: str, cal: str, tare: str) -> None:
    calibration = load_calibration(CONFIG / f"{cal}.yaml")
    recordings, problems = load_recordings(BAGS / f"{bag}.mcap")
    whole = evaluate_recordings(recordings, calibration, tare=tare)
    pieces, got_problems = evaluate_bag(BAGS / f"{bag}.mcap", calibration, tare=tare,
                                        window=1500)
    assert got_problems == problems
    assert_same(pieces, whole)
    one, _ = evaluate_bag(BAGS / f"{bag}.mcap", calibration, tare=tare)
    assert one.to_json() == whole.to_json()  # one piece: the same bits
    assert format_table(one) == format_table(whole)


def hostile_bag(path: Path) -> Calibration:
    """A single sensor with a temperature term (reference on other stamps, with NaNs and
    an outage, ending early; temperature starting late) and a three-sensor array with
    cross-talk (reference on the same stamps, with NaNs), every kind of bad sample."""
    rng = np.random.default_rng(5)
    t = 10.0 + np.arange(6000) * 0.01
    r = 150.0 + 45.0 * np.sin(2 * np.pi * 0.3 * t) + rng.normal(0, 0.3, t.size)
    r[rng.choice(t.size, 300, replace=False)] = np.nan
    r[rng.choice(t.size, 100, replace=False)] = 400.0  # out of range
    r[rng.choice(t.size, 50, replace=False)] = -1.0
    t_ref = 10.003 + np.arange(1500) * 0.037
    s_ref = 0.5 * (150.0 + 45.0 * np.sin(2 * np.pi * 0.3 * t_ref) - 100.0)
    s_ref[rng.choice(t_ref.size, 60, replace=False)] = np.nan
    keep = (t_ref < 25.0) | (t_ref > 31.0)  # a reference outage of 6 s
    t_temp = 20.0 + np.arange(200) * 0.2
    ta = 10.0 + np.arange(5000) * 0.012
    ra = np.stack([150 + 30 * np.sin(ta * (1 + k) + k) + rng.normal(0, 0.3, ta.size)
                   for k in range(3)], axis=1)
    ra[rng.random(ra.shape) < 0.03] = np.nan
    sa = 0.5 * (ra - 100.0) + rng.normal(0, 0.5, ra.shape)
    sa[rng.random(sa.shape) < 0.02] = np.nan
    labels = ["a", "b", "c"]
    with BagWriter(path, chunk_size=700) as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64("/s1/strain_reference", t_ref[keep], s_ref[keep])
        w.write_temperature("/s1/temperature", t_temp, 20.0 + 0.05 * np.arange(t_temp.size))
        w.write_float64_array("/arr/resistance", ta, ra, labels)
        w.write_float64_array("/arr/strain_reference", ta, sa, labels)
    temp = [{"name": "temp", "kind": "temperature", "params": {"form": "offset",
                                                             "t_ref": 20.0}, "coef": 0.3}]
    cals = [cubic_cal("s1", effects=temp)] + [
        cubic_cal(n, effects=[{"name": f"ct_{m}", "kind": "crosstalk",
                               "params": {"neighbour": m}, "coef": 0.2}
                              for m in labels if m != n]) for n in labels]
    return Calibration({c.name: c for c in cals})


@pytest.mark.parametrize("window", [300, 2000, 10**9])
def test_streamed_evaluate_with_interpolated_references_equals_the_whole_series(
        tmp_path: Path, window: int) -> None:
    calibration = hostile_bag(tmp_path / "h.mcap")
    recordings, problems = load_recordings(tmp_path / "h.mcap")
    whole = evaluate_recordings(recordings, calibration)
    got, got_problems = evaluate_bag(tmp_path / "h.mcap", calibration, window=window)
    assert got_problems == problems
    assert_same(got, whole)
    assert whole.sensors["s1"].n_bad > 0 and whole.sensors["s1"].n_out_of_range > 0


def test_nothing_to_score_names_both_sides(tmp_path: Path) -> None:
    hostile_bag(tmp_path / "h.mcap")
    with pytest.raises(InputError, match=r"calibration: x; data: a, b, c, s1\)"):
        evaluate_bag(tmp_path / "h.mcap", Calibration({"x": cubic_cal("x")}))


def test_error_accumulator_over_pieces_equals_error_stats_over_the_whole() -> None:
    rng = np.random.default_rng(8)
    s = rng.normal(10.0, 5.0, 100_000)
    est = s + rng.normal(0.0, 0.4, s.size)
    est[rng.random(s.size) < 0.01] = np.nan
    s[rng.random(s.size) < 0.01] = np.inf
    whole = error_stats(est, s)
    acc = ErrorAccumulator()
    cuts = np.sort(rng.choice(s.size, 40, replace=False))
    for a, b in zip([0, *cuts], [*cuts, s.size], strict=True):
        acc.add(est[a:b], s[a:b])
    got = acc.stats()
    assert got.n == whole.n
    for key in ("rmse", "mae", "max_abs", "r2"):
        assert math.isclose(getattr(got, key), getattr(whole, key), rel_tol=1e-9)
    one = ErrorAccumulator()
    one.add(est, s)
    assert one.stats() == whole


def test_piece_align_equals_align_over_the_whole_series() -> None:
    rng = np.random.default_rng(9)
    t = np.sort(rng.uniform(0.0, 100.0, 3000))
    t_src = np.sort(rng.uniform(5.0, 90.0, 700))
    t_src[100:110] = t_src[100]  # repeated stamps: the last wins
    v = rng.normal(size=t_src.size)
    v[rng.random(v.size) < 0.1] = np.nan
    v[(t_src > 40.0) & (t_src < 60.0)] = np.nan  # a long stretch without a finite value
    expect = align(t, t_src, v)
    piece = PieceAlign()
    got, waiting = [], np.empty(0)
    edges = np.sort(rng.uniform(0.0, 100.0, 25))
    for a, b in zip([-np.inf, *edges], [*edges, np.inf], strict=True):
        k, ks = (t >= a) & (t < b), (t_src >= a) & (t_src < b)
        piece.add(t[k], t_src[ks], v[ks])
        waiting = np.concatenate((waiting, t[k]))
        n = int(np.searchsorted(waiting, piece.horizon(), side="right"))
        got.append(piece.take(waiting[:n]))
        waiting = waiting[n:]
        assert piece.src_t.size <= 30  # only what the waiting samples need is held
    piece.finish()
    got.append(piece.take(waiting))
    np.testing.assert_array_equal(np.concatenate(got), expect)


def test_piece_align_copies_while_the_stamps_are_the_sources() -> None:
    t = np.arange(100) * 0.1
    v = np.sin(t)
    v[[3, 50]] = np.nan  # copied as NaN (align's exact case), not interpolated
    piece = PieceAlign()
    out = []
    for a in range(0, 100, 30):
        piece.add(t[a:a + 30], t[a:a + 30], v[a:a + 30])
        assert piece.horizon() == math.inf
        out.append(piece.take(t[a:a + 30]))
    np.testing.assert_array_equal(np.concatenate(out), align(t, t, v))


def test_plot_samples_are_bounded_and_evenly_spaced() -> None:
    kept = _Kept(1000)
    for a in range(0, 100_000, 7_000):
        idx = np.arange(a, min(a + 7_000, 100_000)).astype(np.float64)
        kept.add(t=idx, r=idx, reference=idx, estimate=idx, direction=idx,
                 scored=np.ones(idx.size, bool), out_of_range=np.zeros(idx.size, bool))
    t = kept.get("t")
    assert 500 < t.size <= 1000
    assert np.all(np.diff(t) == kept.stride) and t[0] == 0.0


def test_evaluate_command_json_and_plots_from_the_streamed_path(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from strain_comp.cli import main

    bag, cal = BAGS / "array.mcap", CONFIG / "array_calibration.yaml"
    out = tmp_path / "e.json"
    assert main(["evaluate", str(bag), "--calibration", str(cal), "--json", str(out),
                 "--plots", str(tmp_path / "plots")]) == 0
    whole = evaluate_recordings(load_recordings(bag)[0], load_calibration(cal))
    assert json.loads(out.read_text()) == json.loads(json.dumps(whole.to_json()))
    assert format_table(whole) in capsys.readouterr().out
    assert len(list((tmp_path / "plots").glob("*.png"))) == 4 * len(whole.sensors)


def test_streamed_evaluate_of_an_unchunked_bag_equals_the_whole_series(tmp_path: Path) -> None:
    from mcap.writer import Writer

    from strain_comp.io.bag import iter_bag, read_bag

    demo = read_bag(BAGS / "demo_rates.mcap")
    topics = ["/s1/resistance", "/s1/strain_reference"]
    rows = sorted((round(t * 1e9), k, v) for k, topic in enumerate(topics)
                  for t, v in zip(demo.series[topic].t, demo.series[topic].values,
                                  strict=True))
    path = tmp_path / "flat.mcap"
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start(profile="ros2")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n")
        cids = [w.register_channel(topic, "cdr", sid) for topic in topics]
        for ns, k, v in rows:
            w.add_message(cids[k], ns, b"\0\1\0\0" + np.array([v]).tobytes(), ns)
        w.finish()
    assert len(list(iter_bag(path, window=3000))) > 3
    calibration = load_calibration(CONFIG / "demo_calibration.yaml")
    whole = evaluate_recordings(load_recordings(path)[0], calibration)
    got, problems = evaluate_bag(path, calibration, window=3000)
    assert problems == []
    assert_same(got, whole)
    assert got.sensors["s1"].stats.n == whole.sensors["s1"].stats.n > 10_000


def test_an_array_sensor_reads_its_own_temperature_topic(tmp_path: Path) -> None:
    """Each sensor of an array reads ``/NAME/temperature`` (as replay and the node do), not
    ``/ARRAY/temperature``: the streamed scores equal the in-memory ones of recordings with
    each sensor's own temperature, and no sensor is noted as without temperature."""
    t = 10.0 + np.arange(2000) * 0.01
    r = np.stack([150 + 30 * np.sin(t), 150 + 30 * np.cos(t)], axis=1)
    t_temp = 10.0 + np.arange(100) * 0.2
    temps = {"a": 20.0 + 0.1 * np.arange(100), "b": 35.0 - 0.1 * np.arange(100)}
    term = [{"name": "temp", "kind": "temperature", "params": {"form": "offset",
                                                             "t_ref": 20.0}, "coef": 0.3}]
    calibration = Calibration({n: cubic_cal(n, effects=term) for n in temps})
    with BagWriter(tmp_path / "t.mcap") as w:
        w.write_float64_array("/arr/resistance", t, r, ["a", "b"])
        w.write_float64_array("/arr/strain_reference", t, 0.5 * (r - 100.0), ["a", "b"])
        for name, values in temps.items():
            w.write_temperature(f"/{name}/temperature", t_temp, values)
    recordings = {n: Recording(n, t, r[:, j], 0.5 * (r[:, j] - 100.0),
                               align(t, t_temp, temps[n]), "arr", j)
                  for j, n in enumerate(temps)}
    whole = evaluate_recordings(recordings, calibration)
    got, _ = evaluate_bag(tmp_path / "t.mcap", calibration, window=500)
    assert_same(got, whole)
    assert not any("temperature" in note for note in got.notes)
    assert got.sensors["a"].stats.rmse != got.sensors["b"].stats.rmse  # each its own
