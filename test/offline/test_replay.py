"""Replay equals the node logic fed message by message, and its output bag reads back."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import cubic_cal, lag_cal, noisy_stream, one_message

from strain_comp.base.samples import Status
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tare import rest_resistance_at_start
from strain_comp.errors import BagError, InputError
from strain_comp.io.bag import SCHEMAS, BagWriter, read_bag
from strain_comp.offline.evaluate import evaluate_bag
from strain_comp.offline.replay import replay_bag
from strain_comp.ros.live import LiveCompensator
from strain_comp.ros.params import TUNABLES, InputTopic, NodeParams


def make_bag(path: object) -> None:
    t, r = noisy_stream(np.random.default_rng(7), n=500)
    t = np.sort(t) - t.min() + 100.0  # a bag's log times are in order and >= 0
    t2 = np.arange(300) * 0.02 + 100.0
    arr = np.stack([150 + 30 * np.sin(t2), 150 + 30 * np.cos(t2)], axis=1)
    arr[50, 0] = np.nan
    arr[60, 1] = -5.0
    with BagWriter(path) as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64("/s1/strain_reference", t, np.zeros_like(t))
        w.write_float64_array("/arr/resistance", t2, arr, ["a", "b"])
        w.write_float64("/unrelated/resistance", t2, np.ones_like(t2))


def calibration() -> Calibration:
    return Calibration({"s1": lag_cal("s1"), "a": cubic_cal("a"), "b": lag_cal("b")})


def node_logic(contents: object) -> dict[str, list]:
    """What a live node publishes, messages fed one by one in log-time order."""
    params = NodeParams([InputTopic("s1", "/s1/resistance", ("s1",), None, False),
                         InputTopic("arr", "/arr/resistance", ("a", "b"), None, True)],
                        calibration(), {s.name: s.default for s in TUNABLES})
    live = LiveCompensator(params)
    events = [(t, "s1", v) for t, v in zip(contents.series["/s1/resistance"].t,
                                           contents.series["/s1/resistance"].values, strict=True)]
    events += [(t, "arr", v) for t, v in zip(contents.series["/arr/resistance"].t,
                                            contents.series["/arr/resistance"].values,
                                            strict=True)]
    events.sort(key=lambda e: e[0])
    out: dict[str, list] = {"s1": [], "arr": []}
    for t, name, value in events:
        out[name].append(one_message(live, name, t, value))
    return out


def test_replay_equals_node_logic_and_reads_back(tmp_path: object) -> None:
    bag_in, bag_out = tmp_path / "in.mcap", tmp_path / "out.mcap"
    make_bag(bag_in)
    summary = replay_bag(bag_in, calibration(), bag_out)
    assert summary.arrays == {"arr": ["a", "b"]}
    contents_in = read_bag(bag_in)
    live = node_logic(contents_in)
    out = read_bag(bag_out)
    s1 = out.series["/s1/strain"]
    np.testing.assert_array_equal(s1.t, contents_in.series["/s1/resistance"].t)
    np.testing.assert_allclose(s1.values, [o.strain for o in live["s1"]], rtol=1e-12)
    np.testing.assert_array_equal(out.series["/s1/direction"].values,
                                  [o.direction for o in live["s1"]])
    status = out.series["/s1/status"].values
    np.testing.assert_array_equal(status, [int(o.status) for o in live["s1"]])
    assert (status != Status.GOOD).sum() > 20  # bad samples kept and marked
    arr = out.series["/arr/strain"]
    assert out.labels["/arr/strain"] == ["a", "b"]
    np.testing.assert_allclose(arr.values, [o.strain for o in live["arr"]], rtol=1e-12)
    np.testing.assert_array_equal(out.series["/arr/status"].values[[50, 60]],
                                  [[Status.NOT_FINITE, 0], [0, Status.NON_POSITIVE]])
    for topic in ("/s1/resistance", "/s1/strain_reference", "/arr/resistance",
                  "/unrelated/resistance"):
        np.testing.assert_array_equal(out.series[topic].values, contents_in.series[topic].values)
    assert len(out.diagnostics) == summary.n_output_messages - summary.n_input_messages - (
        4 * 500 + 4 * 300)
    stamped = _joint_states(bag_out)
    for topic, names, strain in (("/s1/strain_stamped", ["s1"], s1), ("/arr/strain_stamped",
                                                                      ["a", "b"], arr)):
        log_ns, msgs = stamped[topic]
        np.testing.assert_array_equal(log_ns, np.round(strain.t * 1e9))
        np.testing.assert_array_equal([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                                       for m in msgs], log_ns)  # the input's time
        assert all(m.name == names and m.header.frame_id == "" and m.velocity.size == 0
                   and m.effort.size == 0 for m in msgs)
        np.testing.assert_array_equal(np.array([m.position for m in msgs]).reshape(
            strain.values.shape), strain.values)
    names = {s[0] for s in out.diagnostics[-1][1]}
    assert names == {"strain_comp: s1", "strain_comp: a", "strain_comp: b"}
    health = summary.sensors
    assert health["s1"].n_good + health["s1"].n_bad == 500
    assert health == live_health(contents_in)


def _joint_states(path: object) -> dict[str, tuple[list[int], list[object]]]:
    """Per JointState topic: log times [ns] and messages, decoded by rosbags."""
    from rosbags.highlevel import AnyReader

    found: dict[str, tuple[list[int], list[object]]] = {}
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/JointState"]
        for conn, t_ns, raw in reader.messages(connections=conns):
            log, msgs = found.setdefault(conn.topic, ([], []))
            log.append(t_ns)
            msgs.append(reader.deserialize(raw, conn.msgtype))
    return found


def live_health(contents: object) -> dict:
    params = NodeParams([InputTopic("s1", "/s1/resistance", ("s1",), None, False)],
                        Calibration({"s1": lag_cal("s1"), "a": cubic_cal("a"),
                                     "b": lag_cal("b")}),
                        {s.name: s.default for s in TUNABLES})
    live = LiveCompensator(params)
    for t, v in zip(contents.series["/s1/resistance"].t, contents.series["/s1/resistance"].values,
                    strict=True):
        one_message(live, "s1", t, v)
    arr = contents.series["/arr/resistance"]
    for k, name in enumerate(["a", "b"]):
        for t, v in zip(arr.t, arr.values[:, k], strict=True):
            live.engine.step(name, t, v)
    return live.engine.health()


def test_replay_without_calibrated_topics_is_a_bag_error(tmp_path: object) -> None:
    with BagWriter(tmp_path / "x.mcap") as w:
        w.write_float64("/other/resistance", [0.0, 1.0], [1.0, 2.0])
    with pytest.raises(BagError, match="no /NAME/resistance"):
        replay_bag(tmp_path / "x.mcap", calibration(), tmp_path / "y.mcap")


def test_a_sensor_on_two_topics_is_replayed_from_the_first_only(tmp_path: Path) -> None:
    """A sensor an array labels and another topic also names (the node refuses such
    parameters): its engine runs on the first topic alone, the other is copied and said."""
    t = np.arange(300) * 0.02 + 100.0
    arr = np.stack([150 + 30 * np.sin(t), 150 + 30 * np.cos(t)], axis=1)
    paths = [tmp_path / "twice.mcap", tmp_path / "once.mcap"]
    for path in paths:
        with BagWriter(path) as w:
            w.write_float64_array("/arr/resistance", t, arr, ["a", "b"])
            if path is paths[0]:
                w.write_float64("/b/resistance", t, arr[:, 1] + 20.0)
    twice, once = (replay_bag(p, calibration(), p.with_suffix(".out.mcap")) for p in paths)
    assert twice.problems[0] == (f"{paths[0]}: /b/resistance: sensor b appears twice; the "
                                 "topic copied, not replayed")
    assert len(twice.problems) == len(once.problems) + 1
    out, alone = (read_bag(p.with_suffix(".out.mcap")) for p in paths)
    assert "/b/strain" not in out.series
    np.testing.assert_array_equal(out.series["/b/resistance"].values, arr[:, 1] + 20.0)
    np.testing.assert_array_equal(out.series["/arr/strain"].values,
                                  alone.series["/arr/strain"].values)

def test_array_without_labels_replays_under_column_names(tmp_path) -> None:
    """An array topic written by another tool without labels: fit, evaluate and replay all
    name its sensors ARRAY_0 ... ARRAY_{k-1}."""
    from mcap_ros2.writer import Writer

    from strain_comp.offline.fit import fit_bags

    t = np.arange(0.0, 30.0, 0.02)
    strain = np.stack([10 + 10 * np.sin(t * k / 5) for k in (1, 2, 3)], axis=1)
    ohm = 100.0 + 2.0 * strain
    path = tmp_path / "unlabelled.mcap"
    with path.open("wb") as handle:
        writer = Writer(handle)
        kind = "std_msgs/msg/Float64MultiArray"
        schema = writer.register_msgdef(kind, SCHEMAS[kind])
        for i, ti in enumerate(t):
            ns = round(float(ti) * 1e9)
            for topic, values in (("/arr/resistance", ohm), ("/arr/strain_reference", strain)):
                writer.write_message(topic, schema,
                                     {"layout": {"dim": [], "data_offset": 0},
                                      "data": values[i].tolist()},
                                     log_time=ns, publish_time=ns)
        writer.finish()
    calibration = fit_bags([path], "cubic")
    assert list(calibration.sensors) == ["arr_0", "arr_1", "arr_2"]
    summary = replay_bag(path, calibration, tmp_path / "out.mcap")
    assert summary.arrays == {"arr": ["arr_0", "arr_1", "arr_2"]}
    out = read_bag(tmp_path / "out.mcap")
    assert out.labels["/arr/strain"] == ["arr_0", "arr_1", "arr_2"]
    assert np.allclose(out.series["/arr/strain"].values, strain, atol=1e-6)


def test_replay_with_auto_tare_equals_the_engine_tared_at_the_run_start(tmp_path: Path) -> None:
    """``tare="auto"``: the streamed replay tares each sensor from the start of its run,
    exactly as an engine tared by hand with ``rest_resistance_at_start``."""
    root = Path(__file__).resolve().parents[2]
    bag = root / "bags" / "demo_rates.mcap"
    demo = load_calibration(root / "config" / "demo_calibration.yaml")
    name, sensor = next(iter(demo.sensors.items()))
    series = read_bag(bag).series[f"/{name}/resistance"]
    rest = rest_resistance_at_start(series.t, series.values, sensor.direction)
    calibration = Calibration({name: replace(sensor, rest_resistance=0.9 * rest)})
    replay_bag(bag, calibration, tmp_path / "out.mcap", tare="auto", window=5000)
    engine = Engine(calibration)
    assert engine.tare(name, rest) == pytest.approx(0.9)
    expected = engine.run(name, series.t, series.values).strain
    got = read_bag(tmp_path / "out.mcap").series[f"/{name}/strain"].values
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def test_replay_refuses_an_array_reference_evaluate_refuses(tmp_path: Path) -> None:
    """One rule for an array's reference columns (``io.recording.reference_columns``): a
    reference without a column for sensor b is refused whole by replay as by evaluate,
    with the same problem, and replay's CSV then holds no reference for a either."""
    t = 100.0 + np.arange(200) * 0.02
    r = np.stack([150 + 30 * np.sin(t), 150 + 30 * np.cos(t)], axis=1)
    bag = tmp_path / "ref.mcap"
    with BagWriter(bag) as w:
        w.write_float64_array("/arr/resistance", t, r, ["a", "b"])
        w.write_float64_array("/arr/strain_reference", t, 0.5 * (r - 100.0), ["a", "x"])
    cal = Calibration({"a": cubic_cal("a"), "b": cubic_cal("b")})
    problem = "/arr/strain_reference: columns do not match /arr/resistance; ignored"
    summary = replay_bag(bag, cal, tmp_path / "out.mcap", csv=tmp_path / "out.csv")
    assert any(problem in line for line in summary.problems)
    with open(tmp_path / "out.csv", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 * t.size and all(row["reference"] == "" for row in rows)
    with pytest.raises(InputError, match=problem):
        evaluate_bag(bag, cal)
