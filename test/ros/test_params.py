"""Node parameter files: parsing, path resolution, validation messages, bundled examples."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import cubic_cal

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration
from strain_comp.errors import InputError, ParameterError, StrainCompError
from strain_comp.ros.params import (
    TUNABLES,
    load_params,
    parse_values,
    resolve_path,
    validate_tunable,
)

CONFIG = Path(__file__).resolve().parents[2] / "config"


def setup_files(tmp_path: Path, body: str) -> Path:
    save_calibration(Calibration({"s1": cubic_cal("s1")}), tmp_path / "one.yaml")
    save_calibration(Calibration({n: cubic_cal(n) for n in "abc"}), tmp_path / "arr.yaml")
    path = tmp_path / "params.yaml"
    path.write_text(body)
    return path


def test_sensors_and_arrays_parse(tmp_path: Path) -> None:
    path = setup_files(tmp_path, """
compensator:
  ros__parameters:
    use_sim_time: true
    sensors: [left, right]
    left: {calibration: one.yaml}
    right: {topic: /r/ohm, calibration: one.yaml}
    arrays: [hand]
    hand: {topic: /hand/resistance, sensors: [c, a], calibration: arr.yaml}
    deadzone_scale: 2
""")
    params = load_params(path)
    assert [(i.name, i.topic, i.sensors, i.is_array) for i in params.inputs] == [
        ("left", "left/resistance", ("left",), False), ("right", "/r/ohm", ("right",), False),
        ("hand", "/hand/resistance", ("c", "a"), True)]
    assert list(params.calibration.sensors) == ["left", "right", "c", "a"]
    assert params.calibration.sensors["left"].name == "left"  # one-sensor file takes the name
    assert params.tunables["deadzone_scale"] == 2.0
    assert params.tunables["stale_after_s"] == 1.0
    engine = params.build_engine()
    assert engine.arrays == {"hand": ["c", "a"]} and engine.deadzone_scale == 2.0


@pytest.mark.parametrize(("body", "match"), [
    ("sensors: [s1]\n    s1: {calibration: missing.yaml}", "missing.yaml"),
    ("sensors: [s1]", "s1.calibration: missing"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    deadzone_scale: 0.0",
     r"deadzone_scale: must be in \[0.01, 100.0\]"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    dead_zone: 1.0",
     "dead_zone: unknown parameter"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    stale_afer_s: 1.0",
     "stale_afer_s: unknown parameter; did you mean 'stale_after_s'"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    s2: {calibration: one.yaml}",
     "'s2' is not listed in 'sensors' or 'arrays'"),
    ("sensors: s1", "sensors: must be a list of names"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    stale_after_s: soon",
     "stale_after_s: must be a number"),
    ("sensors: [s1]\n    s1: {calibration: one.yaml}\n    tare: later",
     "tare: must be one of calibration, auto"),
    ("arrays: [h]\n    h: {sensors: [a, x], calibration: arr.yaml}",
     "sensor 'x' is not in the calibration"),
    ("sensors: []", "nothing to compensate"),
    ("sensors: [s1, s1]", "names repeat"),
])
def test_bad_params_give_one_clear_error(tmp_path: Path, body: str, match: str) -> None:
    path = setup_files(tmp_path, f"compensator:\n  ros__parameters:\n    {body}\n")
    with pytest.raises(StrainCompError, match=match) as info:
        load_params(path)
    assert str(path) in str(info.value) or "missing.yaml" in str(info.value)


def test_integers_accepted_for_floats_and_paths_beside_the_file(tmp_path: Path,
                                                                monkeypatch: Any) -> None:
    path = setup_files(tmp_path, "compensator:\n  ros__parameters:\n    sensors: [s1]\n"
                                 "    s1: {calibration: one.yaml}\n    stale_after_s: 2\n")
    monkeypatch.chdir(Path(__file__).parent)
    params = load_params(path)
    assert params.tunables["stale_after_s"] == 2.0
    assert params.inputs[0].calibration_path == tmp_path / "one.yaml"


def test_a_relative_calibration_falls_back_to_the_source_checkout(tmp_path: Path,
                                                                  monkeypatch: Any) -> None:
    # an editable install has no share dir and no ament index: config/ of the checkout serves
    monkeypatch.setitem(sys.modules, "ament_index_python.packages", None)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert resolve_path("demo_calibration.yaml", tmp_path) == CONFIG / "demo_calibration.yaml"
    assert resolve_path("config/demo_calibration.yaml", None) == CONFIG / "demo_calibration.yaml"
    assert resolve_path("missing.yaml", tmp_path) == tmp_path / "missing.yaml"


def test_a_hostile_params_file_is_refused_in_one_line(tmp_path: Path) -> None:
    laughs = "a: &a [x,x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n"
        for p, c in zip("abcdefgh", "bcdefghi", strict=True))
    path = tmp_path / "p.yaml"
    path.write_text(laughs)
    with pytest.raises(InputError, match="params file refused: more than"):
        load_params(path)
    path.write_bytes(b"#" * (9 * 2**20))
    with pytest.raises(InputError, match="params file refused: larger than"):
        load_params(path)


def test_file_structure_errors(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text("a: {ros__parameters: {}}\nb: {ros__parameters: {}}\n")
    with pytest.raises(InputError, match="no parameters for node '/compensator'"):
        load_params(path)
    path.write_text("compensator: {sensors: [s1]}\n")
    with pytest.raises(InputError, match="ros__parameters"):
        load_params(path)
    path.write_text(": : :")
    with pytest.raises(InputError, match="not a YAML params file"):
        load_params(path)


def test_tunable_table() -> None:
    assert {s.name for s in TUNABLES} >= {"deadzone_scale", "publish_rate_limit_hz",
                                          "stale_after_s", "diagnostics_period_s"}
    for spec in TUNABLES:
        assert spec.description and spec.range is not None
        assert validate_tunable(spec.name, spec.default) == spec.default
    with pytest.raises(ParameterError, match="must be a number"):
        validate_tunable("deadzone_scale", "big")
    with pytest.raises(ParameterError, match="unknown"):
        parse_values({"sensors": ["s1"], "s1.calibration": "x", "s1.typo": 1})


@pytest.mark.parametrize("name", ["compensator_params.yaml", "array_params.yaml"])
def test_bundled_params_files_are_valid(name: str) -> None:
    """The bundled example files parse, and the calibrations they name load."""
    params = load_params(CONFIG / name)
    assert params.inputs


def test_a_null_list_reads_as_empty(tmp_path: Path) -> None:
    """``arrays: null`` (an empty list in an older ``ros2 param dump`` file) is no arrays."""
    path = setup_files(tmp_path, "/compensator:\n  ros__parameters:\n    arrays: null\n"
                                 "    sensors: [s1]\n    s1: {calibration: one.yaml}\n")
    params = load_params(path)
    assert [(i.name, i.is_array) for i in params.inputs] == [("s1", False)]


def test_tunables_are_checked_before_any_calibration_loads(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A tunable out of range is refused before a calibration is read (loading one runs its
    probe, which compiles kernels: seconds on a colcon install's first start)."""
    import strain_comp.ros.params as params

    def never(path: Path) -> Calibration:
        raise AssertionError(f"{path} loaded before the tunables were checked")

    monkeypatch.setattr(params, "load_calibration", never)
    with pytest.raises(ParameterError, match=r"deadzone_scale: must be in \[0.01, 100.0\], "
                                             r"got -5.0"):
        parse_values({"sensors": ["s1"], "s1.calibration": str(tmp_path / "c.yaml"),
                      "deadzone_scale": -5.0})
