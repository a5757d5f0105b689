"""Known strains in the live node's logic (no ROS): the reference topic, the array
reference and ``~/reference`` fused into the output; refusals counted, never raised past
the node."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import cubic_cal, one_message

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration
from strain_comp.errors import InputError, ParameterError
from strain_comp.io.multiarray import array_values
from strain_comp.ros.live import LiveCompensator
from strain_comp.ros.params import parse_values

GAIN, OFFSET = 1.25, 0.5
"""The truth: the sensor's strain is GAIN x what the calibration reads + OFFSET."""


def live(tmp_path: Path, fuse: str = "on", *, array: bool = False) -> LiveCompensator:
    cals = {n: replace(cubic_cal(n), rest_resistance=100.0) for n in ("a", "b")}
    save_calibration(Calibration(cals if array else {"s1": cals["a"]}), tmp_path / "c.yaml")
    flat = ({"arrays": ["arr"], "arr.sensors": ["a", "b"], "arr.calibration": "c.yaml"}
            if array else {"sensors": ["s1"], "s1.calibration": "c.yaml"})
    return LiveCompensator(parse_values({**flat, "fuse_references": fuse == "on",
                                         "baseline_tracking": "off"}, base_dir=tmp_path))


def resistance(t: np.ndarray) -> np.ndarray:
    """A slow cycle over the calibrated range (100..200 ohm) and back."""
    return 150.0 - 40.0 * np.cos(2 * np.pi * t / 20.0)


def test_references_on_the_topic_move_the_output_to_the_truth_and_only_after(
        tmp_path: Path) -> None:
    fused, plain = live(tmp_path), live(tmp_path, "off")
    t = np.arange(0.0, 120.0, 0.05)
    raw, out = [], []
    for k, (tk, rk) in enumerate(zip(t, resistance(t), strict=True)):
        ref = one_message(plain, "s1", tk, rk)
        got = one_message(fused, "s1", tk, rk)
        assert ref is not None and got is not None
        raw.append(ref.strain)
        out.append(got.strain)
        if k % 100 == 37:  # a reference every 5 s, at whatever strain the cycle is at
            assert fused.on_reference("s1", tk + 0.01, GAIN * ref.strain + OFFSET) is None
    raw_a, out_a = np.array(raw), np.array(out)
    first = t <= 37 * 0.05 + 1e-9  # up to the first reference: the engine's own output
    assert np.array_equal(out_a[first], raw_a[first])
    truth = GAIN * raw_a + OFFSET
    late = t > 60.0
    assert np.sqrt(np.mean((out_a - truth)[late] ** 2)) < 0.05 * np.sqrt(
        np.mean((raw_a - truth)[late] ** 2))
    values = fused.diagnostics(120.0)[0][3]
    assert int(values["fusion_n_used"]) == 24 and values["fusion_n_refused"] == "0"
    assert float(values["fusion_gain"]) == pytest.approx(GAIN, abs=0.02)
    assert "fusion_gain" not in plain.diagnostics(120.0)[0][3]


def test_known_strain_service_fuses_every_sensor_or_says_why_not(tmp_path: Path) -> None:
    node = live(tmp_path)
    with pytest.raises(ParameterError, match="known_strain"):
        node.reference_now(1.0)  # no estimate yet: refused, counted
    assert node.fusion["s1"].refused["no estimate yet"] == 1
    out = one_message(node, "s1", 1.0, 180.0)
    assert out is not None
    node.set_tunable("known_strain", out.strain + 3.0)
    summary = node.reference_now(1.0)
    assert summary.startswith(f"known strain {out.strain + 3.0:g} fused: s1: gain")
    after = one_message(node, "s1", 1.1, 180.0)
    assert after is not None and after.strain > out.strain + 1.0  # moved toward the known one
    with pytest.raises(ParameterError, match="fuse_references"):
        live(tmp_path, "off").reference_now(1.0)


def test_bad_references_are_refused_and_counted(tmp_path: Path) -> None:
    node = live(tmp_path)
    for k in range(40):
        one_message(node, "s1", 0.1 * k, 150.0)
    state = (node.fusion["s1"].gain, node.fusion["s1"].offset)
    assert node.on_reference("s1", 4.0, math.nan) == "non-finite reference"
    assert node.on_reference("s1", 4.0, math.inf) == "non-finite reference"
    assert node.on_reference("s1", 4.0, "ten") == "not a number"
    reason = node.on_reference("s1", 4.0, 1e6)
    assert reason is not None and reason.startswith("beyond the gate")
    assert node.on_reference("s1", 60.0, 20.0) == "no recent estimate"
    one_message(node, "s1", 60.0, 400.0)  # out of the calibrated range
    assert node.on_reference("s1", 60.01, 20.0) == "estimate out of the calibrated range"
    assert (node.fusion["s1"].gain, node.fusion["s1"].offset) == state
    values = node.diagnostics(61.0)[0][3]
    assert values["fusion_n_refused"] == "6" and values["fusion_n_used"] == "0"
    assert values["fusion_refused[non-finite reference]"] == "2"
    assert values["fusion_refused[beyond the gate]"] == "1"


def test_array_references_nan_for_none_and_the_label_honoured(tmp_path: Path) -> None:
    node = live(tmp_path, array=True)

    def references(t: float, data: list[float], label: str = "") -> dict[str, str | None]:
        values = array_values(data, 0, [], 2, label, ("a", "b"))  # NaN: none, as the node
        return {s: node.on_reference(s, t, float(v))
                for s, v in zip(("a", "b"), values, strict=True) if not math.isnan(v)}

    out = one_message(node, "arr", 1.0, [150.0, 170.0])
    assert out is not None
    raw = out.strain.copy()
    got = references(1.01, [math.nan, GAIN * raw[1] + OFFSET])
    assert got == {"b": None}
    assert node.fusion["a"].n_used == 0 and node.fusion["b"].n_used == 1
    again = one_message(node, "arr", 1.02, [150.0, 170.0])
    assert again is not None and again.strain[0] == raw[0] and again.strain[1] > raw[1]
    got = references(1.03, [GAIN * raw[0] + OFFSET, math.nan], label="a,b")
    assert got == {"a": None}
    with pytest.raises(InputError, match="label does not name the sensors"):
        references(1.04, [1.0, 2.0], label="a,c")
    with pytest.raises(InputError, match="expected 2 values"):
        references(1.05, [1.0])
    fresh = node.hand_over(node.successor(node.params))  # the estimate restarts, counts go on
    assert fresh.fusion["a"].gain == 1.0 and fresh.fusion["a"].n_used == 1


def test_fuse_references_is_a_bool_parameter(tmp_path: Path) -> None:
    save_calibration(Calibration({"s1": cubic_cal("s1")}), tmp_path / "c.yaml")
    flat = {"sensors": ["s1"], "s1.calibration": "c.yaml"}
    assert parse_values(flat, base_dir=tmp_path).fuse_references is False
    assert parse_values({**flat, "fuse_references": True}, base_dir=tmp_path).fuse_references
    for bad in ("on", 1, None):
        with pytest.raises(ParameterError, match="fuse_references: must be true or false"):
            parse_values({**flat, "fuse_references": bad}, base_dir=tmp_path)
