"""Calibration files: exact round trip, atomic writes, one clear error naming file and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import make_calibration

from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.errors import CalibrationError


def test_round_trip_is_exact(tmp_path: Path) -> None:
    calibration = make_calibration()
    path = tmp_path / "cal.yaml"
    save_calibration(calibration, path)
    loaded = load_calibration(path)
    assert loaded == calibration
    save_calibration(loaded, tmp_path / "again.yaml")
    assert (tmp_path / "again.yaml").read_text() == path.read_text()


def test_the_input_unit_is_optional_and_kept(tmp_path: Path) -> None:
    """A file without ``input.unit`` (every file before it) reads ohm, and its text is as
    before; a unit written is read back, and the dead zone is in it per second."""
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    assert "unit:" not in path.read_text().replace("strain_unit", "")
    old = load_calibration(path).sensors["left"]
    assert old.input.unit == "ohm" and old.input.rate_unit == "ohm/s"
    data = yaml.safe_load(path.read_text())
    data["sensors"]["left"]["input"]["unit"] = "R/R0"
    path.write_text(yaml.safe_dump(data))
    loaded = load_calibration(path)
    assert loaded.sensors["left"].input.unit == "R/R0"
    assert loaded.sensors["left"].input.rate_unit == "R/R0/s"
    assert loaded.sensors["right"].input.unit == "ohm"
    save_calibration(loaded, tmp_path / "again.yaml")
    assert load_calibration(tmp_path / "again.yaml") == loaded


def test_a_stretch_line_is_optional_and_kept(tmp_path: Path) -> None:
    """A calibration pooled with the stretch session start keeps its stretches' line; a
    file without one (every other) reads None and its text has no such key."""
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    assert "stretch_line" not in path.read_text()
    assert load_calibration(path).sensors["left"].input.stretch_line is None
    data = yaml.safe_load(path.read_text())
    data["sensors"]["left"]["input"]["stretch_line"] = {"rest": 1003.5, "slope": -2.25}
    path.write_text(yaml.safe_dump(data))
    loaded = load_calibration(path)
    assert loaded.sensors["left"].input.stretch_line == (1003.5, -2.25)
    save_calibration(loaded, tmp_path / "again.yaml")
    assert load_calibration(tmp_path / "again.yaml") == loaded


def test_loaded_model_computes_eq4(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    model = load_calibration(path).sensors["left"].build_model()
    c0, c1, c2, c3 = model.c
    r = np.array([12.0, 20.0, 29.5])
    assert np.allclose(model.run(np.arange(3.0), r), c3 * r**3 + c2 * r**2 + c1 * r + c0)


def test_numpy_values_are_written_as_plain_yaml(tmp_path: Path) -> None:
    calibration = make_calibration()
    calibration.sensors["left"].params["c"] = np.array([1.0, 2.0, 3.0, 4.0])
    path = tmp_path / "cal.yaml"
    save_calibration(calibration, path)
    assert "!!python" not in path.read_text()
    assert load_calibration(path).sensors["left"].params["c"] == [1.0, 2.0, 3.0, 4.0]


def test_failed_write_leaves_old_file_intact(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    before = path.read_text()
    broken = make_calibration()
    broken.sensors["left"].params["c"] = [object()]  # not representable in safe YAML
    with pytest.raises(yaml.YAMLError):
        save_calibration(broken, path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cal.yaml"]


def _edit(tmp_path: Path, change) -> Path:
    path = tmp_path / "cal.yaml"
    save_calibration(make_calibration(), path)
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("change", "field", "words"), [
    (lambda d: d.pop("format"), "format", "missing"),
    (lambda d: d.update(format="v0"), "format", "must be"),
    (lambda d: d.update(sensors={}), "sensors", "at least one"),
    (lambda d: d["sensors"]["left"].pop("model"), "sensors.left.model", "missing"),
    (lambda d: d["sensors"]["left"]["model"].update(name="quintic"),
     "sensors.left.model.name", "unknown model"),
    (lambda d: d["sensors"]["left"]["model"]["params"].update(c=[1, 2]),
     "sensors.left.model.params.c", "4 entries"),
    (lambda d: d["sensors"]["left"]["model"]["params"].update(c=[1, "x", 2, 3]),
     "sensors.left.model.params.c.1", "number"),
    (lambda d: d["sensors"]["left"]["normalisation"].update(r0=-1.0),
     "sensors.left.normalisation.r0", "> 0"),
    (lambda d: d["sensors"]["left"]["normalisation"].update(s0="25 %"),
     "sensors.left.normalisation.s0", "number"),
    (lambda d: d["sensors"]["left"]["valid_range"].update(resistance=[30.0, 10.0]),
     "sensors.left.valid_range.resistance", "hi must be > lo"),
    (lambda d: d["sensors"]["left"]["valid_range"].update(resistance=[-1.0, 10.0]),
     "sensors.left.valid_range.resistance", "> 0 ohm"),
    (lambda d: d["sensors"]["left"]["direction"].update(deadzone=0.0),
     "sensors.left.direction.deadzone", "> 0"),
    (lambda d: d["sensors"]["right"]["input"].update(kind="current"),
     "sensors.right.input.kind", "divider"),
    (lambda d: d["sensors"]["right"]["input"].pop("r1"), "sensors.right.input.r1", "missing"),
    (lambda d: d["sensors"]["left"]["input"].update(unit="ohm per day!"),
     "sensors.left.input.unit", "must be a unit"),
    (lambda d: d["sensors"]["right"]["input"].update(unit="R/R0"),
     "sensors.right.input.unit", "in ohm"),
    (lambda d: d["sensors"]["right"].update(effects={"name": "x"}),
     "sensors.right.effects", "list"),
    (lambda d: d["sensors"]["left"]["input"].update(stretch_line={"rest": 1000.0, "slope": 0}),
     "sensors.left.input.stretch_line.slope", "must not be 0"),
    (lambda d: d["sensors"]["left"]["input"].update(stretch_line={"rest": -5.0, "slope": 2.0}),
     "sensors.left.input.stretch_line.rest", "> 0"),
    (lambda d: d["sensors"]["left"]["input"].update(
        stretch_line={"rest": 1e3, "slope": float("nan")}),
     "sensors.left.input.stretch_line.slope", "must be finite"),
    (lambda d: d["sensors"]["left"]["input"].update(stretch_line=[1000.0, 2.0]),
     "sensors.left.input.stretch_line", "mapping"),
    (lambda d: d["sensors"]["left"].update(provenance={"options": "abc"}),
     "sensors.left.provenance.options", "mapping"),
])
def test_malformed_field_is_named(tmp_path: Path, change, field: str, words: str) -> None:
    path = _edit(tmp_path, change)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {field}: "), message
    assert words in message
    assert "\n" not in message


def test_invalid_yaml_names_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("format: strain_comp/calibration/v1\nsensors:\n  a: [1, 2\n")
    with pytest.raises(CalibrationError, match=r"bad\.yaml: line \d+: not valid YAML"):
        load_calibration(path)


def test_missing_and_binary_files(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match=r"nope\.yaml: file: cannot read"):
        load_calibration(tmp_path / "nope.yaml")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CalibrationError, match=r"bin\.yaml: "):
        load_calibration(binary)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n")
    with pytest.raises(CalibrationError, match=r"\(top level\): must be a mapping"):
        load_calibration(scalar)


def test_new_file_gets_umask_mode_and_rewrite_keeps_mode(tmp_path: Path) -> None:
    import os

    path = tmp_path / "cal.yaml"
    umask = os.umask(0o022)
    try:
        save_calibration(make_calibration(), path)
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644
    path.chmod(0o640)
    save_calibration(make_calibration(), path)
    assert path.stat().st_mode & 0o777 == 0o640
