"""The node's per-message logic without ROS: clock gate, array layout, tare, diagnostics."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import S_HI, S_LO, cubic_cal, one_message

from strain_comp.core.calibration import Calibration
from strain_comp.core.tare import REST_WINDOW, rest_resistance_at_start, tare_engine
from strain_comp.errors import InputError, ParameterError
from strain_comp.io.multiarray import array_values
from strain_comp.ros.live import ClockGate, LiveCompensator
from strain_comp.ros.params import parse_values


def live(tmp_path: Path, *, tare: str = "calibration", rest: float | None = 150.0
         ) -> LiveCompensator:
    from strain_comp.core.calibration_file import save_calibration

    save_calibration(Calibration({"s1": replace(cubic_cal("s1"), rest_resistance=rest)}),
                     tmp_path / "c.yaml")
    return LiveCompensator(parse_values({"sensors": ["s1"], "s1.calibration": "c.yaml",
                                         "tare": tare},
                                        base_dir=tmp_path))


def test_clock_gate_gives_each_input_its_own_tick() -> None:
    gate = ClockGate()
    assert gate.arrive("a", 10, "x") == [("a", 10, "x")]
    assert gate.arrive("a", 10, "y") == []            # arrived before its tick: held
    assert gate.tick(20) == [("a", 20, "y")]           # its tick releases it
    assert gate.arrive("a", 30, "z") == [("a", 30, "z")]  # tick first: processed at once
    assert gate.arrive("a", 30, "u") == []
    assert gate.arrive("a", 30, "v") == [("a", 30, "u"), ("a", 30, "v")]  # as if no gate
    assert gate.arrive("b", 30, "w") == [("b", 30, "w")]  # topics are independent


def test_array_layout() -> None:
    np.testing.assert_array_equal(array_values([9, 1, 2, 3], 1, [3], 3), [1, 2, 3])
    np.testing.assert_array_equal(array_values([1, 2, 3], 0, [], 3), [1, 2, 3])
    for data, offset, sizes, match in (([1, 2], 0, [], "expected 3 values, got 2"),
                                       ([1, 2, 3], 0, [2], r"dim\[0\].size 2 != 3"),
                                       ([1, 2, 3], 1, [3], "exceeds the 3 values")):
        with pytest.raises(InputError, match=match):
            array_values(data, offset, sizes, 3)


def test_array_values_follow_the_label() -> None:
    """Values are matched to the sensors by ``dim[0].label``, whatever order (and spacing)
    a peer labels them in, the same when the label's order is looked up again (cached);
    a label naming other sensors is refused."""
    rng = np.random.default_rng(5)
    sensors = [f"s{i}" for i in range(40)]
    value_of = {s: float(i) for i, s in enumerate(sensors)}
    for _ in range(3):
        for order in (sensors, list(rng.permutation(sensors))):
            label = " , ".join(order) if rng.random() < 0.5 else ",".join(order)
            got = array_values([value_of[s] for s in order], 0, [40], 40, label, sensors)
            assert got.tolist() == [value_of[s] for s in sensors]
    assert array_values([1.0, 2.0], 0, [2], 2, "", ["a", "b"]).tolist() == [1.0, 2.0]
    for label in ("a,c", "a,a", "a,"):
        with pytest.raises(InputError, match="label does not name the sensors"):
            array_values([1.0, 2.0], 0, [2], 2, label, ["a", "b"])


def test_tare_takes_the_recent_median_all_or_nothing(tmp_path: Path) -> None:
    node = live(tmp_path)
    with pytest.raises(ParameterError, match="no good sample"):
        node.taring.tare()
    for i, r in enumerate([100.0, 160.0, 161.0, math.nan, 159.0]):
        one_message(node, "s1", 10.0 + 0.2 * i, r)
    node.taring.tare()  # the good samples of the last 0.5 s: 161, 159
    assert node.engine.input_gain("s1") == pytest.approx(150.0 / 160.0)
    values = node.diagnostics(10.5)[0][3]
    assert float(values["rest_resistance"]) == pytest.approx(160.0)
    assert live(tmp_path, rest=None).engine.input_gain("s1") == 1.0
    bare = live(tmp_path, rest=None)
    one_message(bare, "s1", 1.0, 150.0)
    with pytest.raises(ParameterError, match="stores no rest_resistance"):
        bare.taring.tare()


def test_auto_tare_uses_the_first_seconds_at_rest(tmp_path: Path) -> None:
    node = live(tmp_path, tare="auto")
    t = np.arange(0.0, REST_WINDOW + 0.5, 0.01)
    for ti in t:
        one_message(node, "s1", float(ti), 140.0)
    assert node.engine.input_gain("s1") == pytest.approx(150.0 / 140.0)
    assert node.taring.log and "auto tare" in node.taring.log[0]
    with pytest.raises(ParameterError, match="auto needs 'rest_resistance'"):
        live(tmp_path, tare="auto", rest=None)


def test_auto_tare_at_1_khz_reads_the_whole_window_as_offline(tmp_path: Path) -> None:
    """At 1 kHz the ``REST_WINDOW`` holds 5000 samples, more than the ``~/tare`` ring: the
    node still takes the rest level from the whole window, exactly as ``--tare auto``."""
    node = live(tmp_path, tare="auto")
    t = np.arange(0.0, REST_WINDOW + 0.2, 0.001)
    r = np.where(t < 2.5, 140.0, 140.3) + 0.1 * np.random.default_rng(1).standard_normal(t.size)
    for ti, ri in zip(t, r, strict=True):
        one_message(node, "s1", float(ti), float(ri))
    assert node.taring.log and "auto tare: rest resistance" in node.taring.log[0]
    expected = rest_resistance_at_start(t, r, node.params.calibration.sensors["s1"].direction)
    assert node.engine.input_gain("s1") == pytest.approx(150.0 / expected, rel=1e-12)
    assert not node.taring.pending  # the start log is dropped once decided


def test_auto_tare_is_the_offline_rule_when_the_run_starts_moving(tmp_path: Path) -> None:
    """An alternating rest, then a ramp: the node tares once the detector leaves hold, with
    exactly the rest resistance ``--tare auto`` computes offline from the same samples."""
    node = live(tmp_path, tare="auto")
    t = np.arange(0.0, 3.0, 0.01)
    r = 140.0 + 2.0 * (-1.0) ** np.arange(t.size) + np.where(t > 1.0, 60.0 * (t - 1.0), 0.0)
    for ti, ri in zip(t, r, strict=True):
        one_message(node, "s1", float(ti), float(ri))
    assert node.taring.log, "no auto tare although the run started at rest"
    direction = node.params.calibration.sensors["s1"].direction
    expected = rest_resistance_at_start(t, r, direction)
    assert expected == pytest.approx(140.0, abs=0.5)
    assert node.engine.input_gain("s1") == pytest.approx(150.0 / expected, rel=1e-12)


def test_auto_tare_declines_a_run_that_starts_moving_and_never_tares_later(
        tmp_path: Path) -> None:
    """A ramp from the first sample, then a long hold under load: no zero is taken (the
    offline rule declines the same samples), and the log says why."""
    node = live(tmp_path, tare="auto")
    t = np.arange(0.0, 3.0 * REST_WINDOW, 0.01)
    r = 140.0 + 60.0 * np.minimum(t, 1.0)
    for ti, ri in zip(t, r, strict=True):
        one_message(node, "s1", float(ti), float(ri))
    direction = node.params.calibration.sensors["s1"].direction
    with pytest.raises(InputError):
        rest_resistance_at_start(t, r, direction)
    assert node.engine.input_gain("s1") == 1.0
    assert len(node.taring.log) == 1 and "auto tare declined" in node.taring.log[0]


def test_diagnostics_error_stale_and_transport_recovery(tmp_path: Path) -> None:
    node = live(tmp_path)
    one_message(node, "s1", 1.0, 150.0)
    one_message(node, "s1", 1.1, math.nan)
    status = node.diagnostics(1.2)
    assert status[0][1:3] == (2, "non-finite input: estimate held")
    assert node.diagnostics(5.0)[0][1] == 3  # no input at all for longer than stale_after_s
    node.refuse("s1", "bad")
    assert node.diagnostics(5.0)[-1][1] == 1
    assert node.diagnostics(5.1)[-1][1:3] == (0, "ok")


def test_auto_tare_of_a_rest_outside_the_calibrated_range_is_the_offline_one(
        tmp_path: Path) -> None:
    """A rest at 60 ohm below a 100-200 ohm range (every sample flagged out of range, still
    fed to the model): the node tares it as ``--tare auto`` does offline, and ``~/tare``
    takes it too."""
    t = np.arange(0.0, REST_WINDOW + 0.5, 0.01)
    r = 60.0 + 0.05 * np.random.default_rng(2).standard_normal(t.size)
    node = live(tmp_path, tare="auto")
    for ti, ri in zip(t, r, strict=True):
        one_message(node, "s1", float(ti), float(ri))
    engine = node.params.build_engine()
    tare_engine(engine, {"s1": (t, r)}, "auto")
    assert engine.input_gain("s1") != 1.0
    assert node.engine.input_gain("s1") == pytest.approx(engine.input_gain("s1"), rel=1e-12)
    service = live(tmp_path)
    for ti, ri in zip(t, r, strict=True):
        one_message(service, "s1", float(ti), float(ri))
    service.taring.tare()
    assert service.engine.input_gain("s1") == pytest.approx(150.0 / 60.0, rel=1e-3)


def test_auto_tare_log_stays_bounded_while_a_sensor_never_reads(tmp_path: Path) -> None:
    """An array whose second sensor never gives a usable sample: the first is tared after
    ``REST_WINDOW``, the second stays pending, and the start log keeps no more than a few
    hundred samples however long the input runs."""
    from strain_comp.core.calibration_file import save_calibration

    save_calibration(Calibration({n: replace(cubic_cal(n), rest_resistance=150.0)
                                  for n in ("a", "b")}), tmp_path / "c.yaml")
    node = LiveCompensator(parse_values({"arrays": ["m"], "m.sensors": ["a", "b"],
                                         "m.calibration": "c.yaml", "tare": "auto"},
                                        base_dir=tmp_path))
    for ti in np.arange(0.0, 60.0, 0.01):
        one_message(node, "m", float(ti), [140.0, math.nan])
    assert node.engine.input_gain("a") == pytest.approx(150.0 / 140.0)
    assert node.engine.input_gain("b") == 1.0
    assert node.taring.recent["m"].n <= 512


def test_tare_service_ends_a_pending_auto_tare(tmp_path: Path) -> None:
    """``~/tare`` within the first seconds of ``tare: auto``: its zero stays, no automatic
    tare follows, and nothing more is logged for one."""
    node = live(tmp_path, tare="auto")
    for ti in np.arange(0.0, 1.0, 0.01):
        one_message(node, "s1", float(ti), 140.0)
    node.taring.tare()
    assert not node.taring.pending
    for ti in np.arange(1.0, 2.0 * REST_WINDOW, 0.01):
        one_message(node, "s1", float(ti), 120.0)
    assert node.engine.input_gain("s1") == pytest.approx(150.0 / 140.0)
    assert not node.taring.log and not node.taring.pending


def test_span_at_a_known_strain_reads_a_more_sensitive_sensor(tmp_path: Path) -> None:
    from strain_comp.offline.session_start import calibrated_resistance

    cal = cubic_cal("s1")
    rest_strain = S_LO + 0.05 * (S_HI - S_LO) / 1.1  # the fitted minimum of the range
    r0, r10 = calibrated_resistance(cal, rest_strain), calibrated_resistance(cal, 10.0)
    node = live(tmp_path, rest=r0)
    moved = 155.0 + 1.5 * (r10 - r0)  # rest moved to 155 ohm, 50 % more sensitive
    with pytest.raises(ParameterError, match="span_strain"):
        node.span()
    one_message(node, "s1", 1.0, 155.0)
    node.taring.tare()  # the zero of the moved sensor
    node.set_tunable("span_strain", 10.0)
    for i in range(5):
        one_message(node, "s1", 2.0 + 0.1 * i, moved)
    fresh, message = node.span()
    assert "span gain" in message
    assert fresh.params.calibration.sensors["s1"].input.zero_span == pytest.approx(
        (155.0, r0, 1.0 / 1.5), rel=1e-6)
    assert fresh.tunables["span_strain"] == 10.0
    out = [one_message(fresh, "s1", 5.0 + 0.1 * i, moved) for i in range(100)][-1]
    assert out is not None and out.strain == pytest.approx(10.0, abs=0.05)
    out = [one_message(fresh, "s1", 20.0 + 0.1 * i, 155.0) for i in range(100)][-1]
    assert out is not None and out.strain == pytest.approx(rest_strain, abs=0.05)


def test_baseline_tracking_parameter_accepts_off_only(tmp_path: Path) -> None:
    """Baseline tracking was removed: ``off`` is the node's behaviour, anything else is
    refused in one line naming the parameter."""
    from strain_comp.core.calibration_file import save_calibration

    save_calibration(Calibration({"s1": cubic_cal("s1")}), tmp_path / "c.yaml")
    flat = {"sensors": ["s1"], "s1.calibration": "c.yaml", "baseline_tracking": "off"}
    parse_values(flat, base_dir=tmp_path)
    for value in ("on", "yes"):
        with pytest.raises(ParameterError, match=r"baseline_tracking.*only off") as refused:
            parse_values({**flat, "baseline_tracking": value}, base_dir=tmp_path)
        assert "\n" not in str(refused.value)


def test_an_arrays_sensors_take_their_temperature_as_replay_does(tmp_path: Path) -> None:
    """An array whose calibrations hold a temperature term, its sensors' SENSOR/temperature
    fed in log-time order: the node's strains are replay's of the same bag (the node once
    ignored an array's temperature), and the temperature moves them."""
    import copy

    import yaml

    from strain_comp.core.calibration_file import load_calibration
    from strain_comp.io.bag import BagWriter, read_bag
    from strain_comp.offline.replay import replay_bag
    from strain_comp.ros.params import TUNABLES, InputTopic, NodeParams

    config = Path(__file__).resolve().parents[2] / "config"
    demo = yaml.safe_load((config / "demo_calibration.yaml").read_text())["sensors"]["s1"]
    sensors = {}
    for name, coef in (("a", 0.05), ("b", -0.03)):
        sensors[name] = copy.deepcopy(demo)
        sensors[name]["effects"] = [{"name": "temp", "kind": "temperature",
                                     "params": {"form": "offset", "t_ref": 20.0}, "coef": coef}]
    (tmp_path / "cal.yaml").write_text(yaml.safe_dump(
        {"format": "strain_comp/calibration/v1", "sensors": sensors}))
    cal = load_calibration(tmp_path / "cal.yaml")
    t = 100.0 + np.arange(400) * 0.02
    r = np.stack([13.0 + 2.0 * np.sin(t), 13.0 + 2.0 * np.cos(t)], axis=1)
    t_temp = 100.005 + np.arange(40) * 0.2
    temps = {"a": 20.0 + 0.5 * np.arange(40), "b": 40.0 - 0.4 * np.arange(40)}
    with BagWriter(tmp_path / "in.mcap") as writer:
        writer.write_float64_array("/arr/resistance", t, r, ["a", "b"])
        for name, values in temps.items():
            writer.write_temperature(f"/{name}/temperature", t_temp, values)
    replay_bag(tmp_path / "in.mcap", cal, tmp_path / "out.mcap")
    replayed = read_bag(tmp_path / "out.mcap").series["/arr/strain"].values

    def node(with_temperature: bool) -> np.ndarray:
        live = LiveCompensator(NodeParams([InputTopic("arr", "/arr/resistance", ("a", "b"),
                                                      tmp_path / "cal.yaml", True)],
                                          cal, {s.name: s.default for s in TUNABLES}))
        events = [(ti, "arr", row) for ti, row in zip(t, r, strict=True)]
        if with_temperature:
            events += [(ti, name, v) for name, values in temps.items()
                       for ti, v in zip(t_temp, values, strict=True)]
        out = []
        for ti, name, value in sorted(events, key=lambda e: e[0]):
            if name == "arr":
                out.append(one_message(live, name, ti, value).strain)
            else:
                live.on_temperature(name, value)
        return np.array(out)

    np.testing.assert_allclose(node(True), replayed, rtol=1e-12, atol=1e-12)
    assert np.abs(node(False) - replayed).max() > 0.1


def test_row_decoder_reads_one_layout_in_bulk_and_learns_only_what_reads_back() -> None:
    """The intake's bulk read: the rows of the messages of the layout learnt, in the sensors'
    columns; another label is not that layout; a message whose values are not its last
    bytes (padding after them) is not learnt."""
    from strain_comp.io.cdr import RowEncoder
    from strain_comp.ros.cdr import RowDecoder

    rows = np.arange(12.0).reshape(4, 3)
    raws = RowEncoder.vector(["a", "b", "c"]).encode(rows)
    decoder = RowDecoder()
    assert not decoder.fits(raws[0])
    decoder.learn(raws[0], 3, np.array([2, 0, 1]), rows[0][[2, 0, 1]])
    assert all(decoder.fits(raw) for raw in raws)
    np.testing.assert_array_equal(decoder.rows(raws), rows[:, [2, 0, 1]])
    assert not decoder.fits(RowEncoder.vector(["a", "b", "x"]).encode(rows)[0])
    padded = RowDecoder()
    padded.learn(raws[0] + bytes(8), 3, np.arange(3), rows[0])
    assert not padded.fits(raws[0] + bytes(8))
