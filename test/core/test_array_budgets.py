"""Calibration budgets per sensor and per term: a large array loads, a hostile file is
refused in one line, and every distinct sensor is still probed."""

from __future__ import annotations

import copy
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from strain_comp.core.calibration import MAX_SENSOR_BYTES, MAX_SENSOR_EFFECTS, MAX_SENSORS
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.errors import CalibrationError

ROOT = Path(__file__).resolve().parents[2]
DEMO = yaml.safe_load((ROOT / "config" / "demo_calibration.yaml").read_text())


def demo_sensor(n_effects: int = 2) -> dict[str, Any]:
    """config/demo_calibration.yaml's sensor with ``n_effects`` temperature terms."""
    sensor = copy.deepcopy(DEMO["sensors"]["s1"])
    sensor["effects"] = [{"name": f"t{j}", "kind": "temperature",
                          "params": {"form": "offset", "t_ref": 20.0}, "coef": 0.001}
                         for j in range(n_effects)]
    return sensor


def write_array(path: Path, sensors: dict[str, Any]) -> Path:
    """A calibration file of ``sensors`` in their order, each written as ``save_calibration``
    writes a sensor (block style, flow lists); a sensor alike its predecessor is dumped
    once."""
    texts: list[str] = []
    last: tuple[Any, str] = (None, "")
    for name, sensor in sensors.items():
        if sensor != last[0]:
            body = yaml.safe_dump(sensor, sort_keys=False, default_flow_style=None, width=100)
            last = (sensor, textwrap.indent(body, "    "))
        texts.append(f"  {name}:\n{last[1]}")
    path.write_text("format: strain_comp/calibration/v1\nsensors:\n" + "".join(texts))
    return path


def test_a_1024_sensor_array_with_two_terms_each_loads_and_runs(tmp_path: Path) -> None:
    sensors = {f"a{i}": demo_sensor() for i in range(1024)}
    path = write_array(tmp_path / "array.yaml", sensors)
    cal = load_calibration(path)
    assert list(cal.sensors) == list(sensors)
    single = load_calibration(ROOT / "config" / "demo_calibration.yaml").sensors["s1"]
    assert all(s.params == single.params and len(s.effects) == 2
               for s in cal.sensors.values())
    # the array's estimate equals the single sensor's (the bundled demo) on the same input
    t = np.linspace(0.0, 2.0, 200)
    r = np.linspace(11.0, 25.0, 200)
    temp = np.full(t.size, 30.0)
    one = Engine(load_calibration(write_array(tmp_path / "one.yaml", {"s1": demo_sensor()})))
    want = one.run("s1", t, r, temp).strain
    got = Engine(cal).run("a1023", t, r, temp).strain
    np.testing.assert_array_equal(got, want)


def test_every_distinct_sensor_of_an_array_is_probed(tmp_path: Path) -> None:
    """Sensors alike are probed once; one different sensor among 1000, a rational whose
    pole lies inside its valid range, is found and named."""
    sensors = {f"a{i}": demo_sensor() for i in range(1000)}
    odd = sensors["a977"]
    norm, (lo, hi) = odd["normalisation"], odd["valid_range"]["resistance"]
    xi_mid = 0.5 * (lo + hi) / norm["r0"] + norm["alpha"]
    odd["model"] = {"name": "rational", "params": {  # den = (xi - xi_mid) xi
        "mode": "combined", "combined": {"p": [0.0, 1.0, 0.0], "q": [-xi_mid, 0.0]}}}
    path = write_array(tmp_path / "array.yaml", sensors)
    with pytest.raises(CalibrationError, match=r"sensors\.a977\.model: .*\(a pole\)"):
        load_calibration(path)


def hostile(work: Path) -> dict[str, tuple[Path, str]]:
    one = demo_sensor()
    padded = {"s1": {**one, "provenance": {"note": "x" * (2 * MAX_SENSOR_BYTES)}}}
    many = {f"s{i}": 0 for i in range(MAX_SENSORS + 1)}
    terms = {"s1": demo_sensor(MAX_SENSOR_EFFECTS + 1)}
    return {"padded": (write_array(work / "padded.yaml", padded), "per sensor"),
            "sensors": (write_array(work / "many.yaml", many), f"at most {MAX_SENSORS}"),
            "terms": (write_array(work / "terms.yaml", terms),
                      f"sensors.s1.effects: refused: {MAX_SENSOR_EFFECTS + 1} effect terms")}


@pytest.mark.parametrize("name", ["padded", "sensors", "terms"])
def test_a_file_beyond_the_per_sensor_budgets_is_refused_in_one_line(tmp_path: Path,
                                                                       name: str) -> None:
    path, words = hostile(tmp_path)[name]
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and words in message and "\n" not in message
