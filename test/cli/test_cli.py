"""The command line end to end on a tiny simulated bag, and exit code 2 for bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main

ERROR_PREFIX = "strain-comp: error: "


def scenario() -> str:
    """A single-sensor triangle scenario of the virtual rig."""
    from strain_comp.offline.rig import SCENARIOS

    return next((n for n in SCENARIOS if "triangle" in n), next(iter(SCENARIOS)))


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """simulate -> fit cubic, once for the module."""
    work = tmp_path_factory.mktemp("cli")
    assert main(["simulate", "--scenario", scenario(), "--out", str(work / "sim.mcap"),
                 "--seed", "1", "--duration", "60"]) == 0
    assert main(["fit", str(work / "sim.mcap"), "--model", "cubic", "--sensor", "all",
                 "--out", str(work / "cal.yaml")]) == 0
    return work


def run_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``argv``, check exit code 2 and exactly one stderr line; return that line."""
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(ERROR_PREFIX)
    assert "Traceback" not in err
    return lines[0]


def test_fit_evaluate_replay(workdir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from strain_comp.core.calibration_file import load_calibration
    from strain_comp.io.bag import read_bag

    calibration = load_calibration(workdir / "cal.yaml")
    names = list(calibration.sensors)
    assert names and all(c.model == "cubic" for c in calibration.sensors.values())
    capsys.readouterr()
    out_json = workdir / "eval.json"
    assert main(["evaluate", str(workdir / "sim.mcap"), "--calibration",
                 str(workdir / "cal.yaml"), "--json", str(out_json)]) == 0
    table = capsys.readouterr().out
    document = json.loads(out_json.read_text())
    assert list(document) == ["sensors"] and list(document["sensors"]) == names
    for name, record in document["sensors"].items():
        assert {"rmse", "mae", "max_abs", "r2", "n"} <= set(record)
        assert isinstance(record["n"], int) and record["n"] > 100
        assert 0 <= record["mae"] <= record["rmse"] <= record["max_abs"]
        # docs/design.md's key, kept after baseline tracking went: it never acts
        assert record["baseline_tracking"] == {"seconds": 0.0, "correction": 0.0}
        row = next(line for line in table.splitlines() if line.startswith(f"{name} "))
        assert row.split()[2:4] == [str(record["n"]), f"{record['rmse']:.4f}"]
    assert main(["replay", str(workdir / "sim.mcap"), "--calibration",
                 str(workdir / "cal.yaml"), "--out", str(workdir / "out.mcap")]) == 0
    topics = read_bag(workdir / "out.mcap").series
    for name in names:
        assert f"/{name}/strain" in topics and f"/{name}/direction" in topics


def test_console_script_runs_as_a_process(workdir: Path, tmp_path: Path) -> None:
    script = shutil.which("strain-comp")
    command = [script] if script else [sys.executable, "-m", "strain_comp.cli"]
    done = subprocess.run([*command, "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "evaluate" in done.stdout
    done = subprocess.run([*command, "evaluate", str(tmp_path / "missing.mcap"),
                           "--calibration", str(workdir / "cal.yaml")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [f"{ERROR_PREFIX}{tmp_path / 'missing.mcap'}: bag not "
                                        "found"]


def test_bad_input_exits_2_with_one_line(workdir: Path, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    bag, cal = str(workdir / "sim.mcap"), str(workdir / "cal.yaml")
    line = run_error(["evaluate", str(tmp_path / "missing.mcap"), "--calibration", cal], capsys)
    assert "missing.mcap" in line
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("this is not an MCAP file\n" * 20)
    line = run_error(["evaluate", str(not_mcap), "--calibration", cal], capsys)
    assert "notes.mcap" in line
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("format: strain_comp/calibration/v1\nsensors: {s1: [unclosed\n")
    line = run_error(["evaluate", bag, "--calibration", str(bad_yaml)], capsys)
    assert "bad.yaml" in line and "YAML" in line
    line = run_error(["fit", bag, "--model", "quintic", "--sensor", "all", "--out",
                      str(tmp_path / "x.yaml")], capsys)
    assert "quintic" in line
    line = run_error(["fit", bag, "--model", "cubic", "--sensor", "no_such_sensor", "--out",
                      str(tmp_path / "x.yaml")], capsys)
    assert "no_such_sensor" in line
    assert not (tmp_path / "x.yaml").exists()
    line = run_error(["fit", bag, "--model", "cubic", "--sensor", "all", "--option", "N",
                      "--out", str(tmp_path / "x.yaml")], capsys)
    assert "key=value" in line
    for command in (["evaluate", bag], ["replay", bag, "--out", str(tmp_path / "o.mcap")]):
        line = run_error([*command, "--calibration", cal, "--baseline-tracking", "on"], capsys)
        assert "baseline tracking was removed" in line and "only off" in line
    assert not (tmp_path / "o.mcap").exists()


def test_import_csv_then_fit(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from strain_comp.io.recording import load_recordings

    t = np.arange(0.0, 600.0, 1.0)
    extension = 10.0 * np.abs((t / 60.0) % 2.0 - 1.0)  # mm
    resistance = 70.0 + 0.5 * extension
    csv = tmp_path / "fiber.csv"
    np.savetxt(csv, np.column_stack([t, extension, 0.1 * extension, resistance]),
               delimiter=",")
    bag = tmp_path / "bags" / "fiber.mcap"
    assert main(["import-csv", str(csv), "--out", str(bag), "--sensor", "fib", "--format",
                 "fiber", "--gauge-length-mm", "50"]) == 0
    assert "600 rows" in capsys.readouterr().out
    rec = load_recordings(bag)[0]["fib"]
    assert np.allclose(rec.s, 100.0 * extension / 50.0)
    assert main(["fit", str(bag), "--model", "cubic", "--sensor", "fib", "--out",
                 str(tmp_path / "fib.yaml")]) == 0
    line = run_error(["import-csv", str(tmp_path / "none.csv"), "--out", str(bag),
                      "--sensor", "fib", "--format", "fiber"], capsys)
    assert "none.csv" in line
    line = run_error(["simulate", "--scenario", "no_such_scenario", "--out", str(bag)], capsys)
    assert "no_such_scenario" in line


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert main(["evaluate", "x.mcap"]) == 2  # --calibration missing
    assert main(["fit", "x.mcap", "--model", "cubic", "--out", "c.yaml"]) == 2  # no --sensor
    assert main(["--help"]) == 0
    assert "simulate" in capsys.readouterr().out
