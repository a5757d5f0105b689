"""Streaming: the bag read in pieces equals the whole bag, and replay in small pieces equals
the engine's batch path over each whole series (the in-memory reference)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.io.bag import BagContents, BagWriter, iter_bag, read_bag
from strain_comp.offline.replay import replay_bag

ROOT = Path(__file__).resolve().parents[2]


def _concat(pieces: list, topic: str) -> tuple[np.ndarray, np.ndarray]:
    parts = [p.series[topic] for p in pieces if topic in p.series]
    return np.concatenate([s.t for s in parts]), np.concatenate([s.values for s in parts])


def assert_same_messages_in_time_order(whole: BagContents, pieces: list[BagContents]) -> None:
    """The pieces hold every message of ``whole``, and no piece starts before the one
    before it ended."""
    for topic, series in whole.series.items():
        t, v = _concat(pieces, topic)
        np.testing.assert_array_equal(t, series.t)
        np.testing.assert_array_equal(v, series.values)
    end = -np.inf
    for p in pieces:
        times = np.concatenate([s.t for s in p.series.values()])
        assert times.min() >= end
        end = times.max()


def test_iter_bag_pieces_are_time_ordered_and_make_the_whole_bag(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t1 = np.sort(rng.uniform(0.0, 50.0, 4000))
    t2 = np.arange(2500) * 0.02
    path = tmp_path / "b.mcap"
    with BagWriter(path, chunk_size=3000) as w:
        w.write_float64("/a", t1, rng.normal(size=t1.size))
        w.write_float64_array("/b", t2, rng.normal(size=(t2.size, 3)), ["x", "y", "z"])
        w.write_temperature("/c", t2[::10], rng.normal(size=250))
    whole = read_bag(path)
    pieces = list(iter_bag(path, window=500))
    assert len(pieces) > 5
    assert not any(p.problems for p in pieces)
    assert_same_messages_in_time_order(whole, pieces)


def test_writer_flushes_give_the_same_messages_as_one_write(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    t = np.arange(3000) * 0.01
    v = rng.normal(size=(t.size, 2))
    with BagWriter(tmp_path / "one.mcap", chunk_size=2000) as w:
        w.write_float64("/x", t, v[:, 0])
        w.write_float64_array("/y", t, v, ["p", "q"])
    with BagWriter(tmp_path / "many.mcap", chunk_size=2000) as w:
        for a in range(0, t.size, 700):
            w.write_float64("/x", t[a:a + 700], v[a:a + 700, 0])
            w.write_float64_array("/y", t[a:a + 700], v[a:a + 700], ["p", "q"])
            w.flush(before=float(t[min(a + 700, t.size - 1)]))
    one, many = read_bag(tmp_path / "one.mcap"), read_bag(tmp_path / "many.mcap")
    assert not many.problems
    for topic in ("/x", "/y"):
        np.testing.assert_array_equal(many.series[topic].t, one.series[topic].t)
        np.testing.assert_array_equal(many.series[topic].values, one.series[topic].values)


@pytest.mark.parametrize(("bag", "cal", "array"), [
    ("steps", "demo_calibration", None),
    ("demo_rates", "demo_calibration", None),
    ("array", "array_calibration", "array"),
])
def test_streaming_replay_equals_the_batch_path_over_the_whole_series(
        tmp_path: Path, bag: str, cal: str, array: str | None) -> None:
    calibration = load_calibration(ROOT / "config" / f"{cal}.yaml")
    out = tmp_path / "out.mcap"
    big = tmp_path / "big.mcap"
    replay_bag(ROOT / "bags" / f"{bag}.mcap", calibration, out, window=1500)
    replay_bag(ROOT / "bags" / f"{bag}.mcap", calibration, big, window=10**9)
    contents = read_bag(ROOT / "bags" / f"{bag}.mcap")
    got = read_bag(out)
    engine = Engine(calibration)
    if array is None:
        series = contents.series["/s1/resistance"]
        ref = engine.run("s1", series.t, series.values)
        for what in ("strain", "direction", "status"):
            np.testing.assert_array_equal(got.series[f"/s1/{what}"].t, series.t)
            np.testing.assert_array_equal(got.series[f"/s1/{what}"].values,
                                          getattr(ref, what).astype(np.float64))
    else:
        series = contents.series[f"/{array}/resistance"]
        names = contents.labels[f"/{array}/resistance"]
        refs = engine.run_array(names, series.t, series.values)
        for what in ("strain", "direction", "status"):
            expect = np.stack([getattr(refs[n], what) for n in names], axis=1)
            np.testing.assert_array_equal(got.series[f"/{array}/{what}"].values,
                                          expect.astype(np.float64))
    whole = read_bag(big)
    assert got.diagnostics == whole.diagnostics
    assert len(got.diagnostics) > 3


def test_chunks_out_of_time_order_are_all_delivered_with_a_problem_line(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    t = np.arange(2000) * 0.01
    with BagWriter(path, chunk_size=2000) as w:  # /a fully, then /b over the same times
        w.write_float64("/a", t, np.ones(t.size))
        w.flush()
        w.write_float64("/b", t, np.zeros(t.size))
    whole = read_bag(path)
    pieces = list(iter_bag(path, window=300))
    for topic in ("/a", "/b"):
        got, _ = _concat(pieces, topic)
        np.testing.assert_array_equal(np.sort(got), whole.series[topic].t)
    assert any("delivered late" in line for p in pieces for line in p.problems)


def test_an_exception_inside_the_writer_leaves_no_output(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    with pytest.raises(RuntimeError), BagWriter(path, chunk_size=500) as w:
        w.write_float64("/a", np.arange(500) * 0.01, np.ones(500))
        w.flush()
        raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def test_fit_segments_cut_at_a_long_step_back_in_time() -> None:
    from strain_comp.offline.fit import split_segments

    t = np.concatenate([np.arange(100) * 0.1, np.arange(100) * 0.1])  # a looped recording
    r = 100.0 + np.sin(t)
    segments = split_segments(t, r, np.sin(t))
    assert [seg.t.size for seg in segments] == [100, 100]
    assert all(np.all(np.diff(seg.t) > 0) for seg in segments)


def test_replay_diagnostics_equal_the_engine_stepped_up_to_each_tick(tmp_path: Path) -> None:
    from strain_comp.core.health import diagnostics

    calibration = load_calibration(ROOT / "config" / "demo_calibration.yaml")
    bag = ROOT / "bags" / "steps.mcap"
    out = tmp_path / "out.mcap"
    replay_bag(bag, calibration, out, diagnostics_period=0.7, window=2000)
    series = read_bag(bag).series["/s1/resistance"]
    written = read_bag(out).diagnostics
    assert len(written) > 20
    engine = Engine(calibration)
    i = 0
    t0 = series.t[0]
    for stored, statuses in written:
        tick = t0 + 0.7 * round((stored - t0) / 0.7)  # the tick before its ns rounding
        while i < series.t.size and series.t[i] <= tick:
            engine.step("s1", series.t[i], series.values[i])
            i += 1
        expect = [(name, level, message, values) for name, level, message, values
                  in diagnostics(engine.health(now=tick))]
        assert statuses == expect
    assert i == series.t.size


def _unchunked(path: Path, n: int) -> tuple[np.ndarray, np.ndarray]:
    """An MCAP written without chunks (as some tools do): two Float64 topics, in time
    order, every message a top-level record."""
    from mcap.writer import Writer

    t = np.arange(n) * 1000
    v = np.sin(np.arange(n) * 0.01)
    with path.open("wb") as f:
        w = Writer(f, use_chunking=False)
        w.start(profile="ros2")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n")
        cids = [w.register_channel(f"/s{k}/resistance", "cdr", sid) for k in range(2)]
        for i in range(n):
            w.add_message(cids[i % 2], int(t[i]), b"\0\1\0\0" + np.array([v[i]]).tobytes(),
                          int(t[i]))
        w.finish()
    return t, v


def test_unchunked_bag_comes_in_bounded_time_ordered_pieces(tmp_path: Path) -> None:
    from strain_comp.io.bag.walk import LOOSE_BLOCK

    path = tmp_path / "flat.mcap"
    _unchunked(path, 30_000)
    whole = read_bag(path)
    pieces = list(iter_bag(path, window=2000))
    sizes = [sum(s.t.size for s in p.series.values()) for p in pieces]
    assert len(pieces) > 5 and max(sizes) <= 2000 + LOOSE_BLOCK
    assert not any(p.problems for p in pieces) and not whole.problems
    assert_same_messages_in_time_order(whole, pieces)


def test_truncated_unchunked_bag_keeps_what_is_readable_in_pieces(tmp_path: Path) -> None:
    path = tmp_path / "flat.mcap"
    _unchunked(path, 20_000)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:len(data) // 2 + 7])
    whole = read_bag(cut)
    pieces = list(iter_bag(cut, window=1000))
    assert len(pieces) >= 3
    n = sum(s.t.size for s in whole.series.values())
    assert 9000 < n < 11_000
    for topic, series in whole.series.items():
        t, _ = _concat(pieces, topic)
        np.testing.assert_array_equal(t, series.t)
    lines = [line for p in pieces for line in p.problems]
    assert any("truncated" in line for line in lines)
    assert lines == whole.problems
