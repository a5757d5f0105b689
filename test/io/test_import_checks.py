"""import-csv's checks of the reference: a signed position, a time that runs backwards and
a span that does not look like % each give one warning line saying what to pass; the
measured lab files, read as their README says, give none."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main
from strain_comp.io.csv_import import import_csv

T = np.arange(0.0, 40.0, 0.1)
S = 20.0 * (1.0 - np.abs((T / 10.0) % 2.0 - 1.0))  # 0 -> 20 % triangles


def write(path: Path, strain: np.ndarray, t_ref: np.ndarray = T) -> Path:
    r = 1000.0 * (1.0 + 0.02 * np.abs(strain))
    rows = ["t,r,s,ts"] + [f"{a},{b},{c},{d}" for a, b, c, d in
                          zip(T, r, strain, t_ref, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def warnings_of(path: Path, *, scales: dict | None = None, strain_time: bool = False
                ) -> list[str]:
    columns = {"time": "t", "resistance": "r", "strain": "s"}
    if strain_time:
        columns["strain_time"] = "ts"
    return import_csv(path, fmt="generic", sensor="s1", columns=columns,
                      scales=scales)[1].warnings


@pytest.mark.parametrize(("strain", "words"), [
    (-S, "--scales strain=-1"),  # a signed stage position: 0 to -20
    (S / 100.0, "--scales strain=100"),  # a fraction: span 0.2
    (S * 1e4 / 100.0 * 1.5, "--scales strain=1e-4"),  # microstrain: span 3000
])
def test_a_suspicious_reference_gets_one_line_saying_what_to_pass(
        tmp_path: Path, strain: np.ndarray, words: str) -> None:
    lines = warnings_of(write(tmp_path / "x.csv", strain))
    assert len(lines) == 1 and words in lines[0]


def test_plain_percent_and_a_chosen_scale_give_no_warning(tmp_path: Path) -> None:
    assert warnings_of(write(tmp_path / "x.csv", S)) == []
    # the user chose a scale: the span is theirs to judge
    assert warnings_of(write(tmp_path / "x.csv", S / 100.0), scales={"strain": 100.0}) == []


def test_a_reference_time_running_backwards_is_named(tmp_path: Path) -> None:
    t_ref = T.copy()
    t_ref[50:60] = t_ref[50:60][::-1]
    lines = warnings_of(write(tmp_path / "x.csv", S, t_ref), strain_time=True)
    assert len(lines) == 1 and "runs backwards at 9 rows" in lines[0]


def test_the_command_prints_the_warning_on_stderr(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path / "x.csv", -S)
    capsys.readouterr()
    assert main(["import-csv", str(path), "--out", str(tmp_path / "x.mcap"), "--sensor", "s1",
                 "--format", "generic", "--columns", "time=t,resistance=r,strain=s"]) == 0
    out, err = capsys.readouterr()
    assert "strain-comp: warning: " in err and "warning" not in out


def test_the_measured_files_give_no_warning(measured_data: Path) -> None:
    for path in sorted((measured_data / "cb_pdms_7p5wt").glob("*.csv")):
        assert import_csv(path, fmt="cb_pdms", sensor="s")[1].warnings == [], path
    for path in sorted((measured_data / "conductive_fiber").glob("*.csv")):
        assert import_csv(path, fmt="fiber", sensor="s")[1].warnings == [], path
    nylon = measured_data / "nylon_silver" / "session1_100Hz" / "sin_20.csv"
    columns = {"time": "time_s", "resistance": "r_over_r0", "strain": "position"}
    assert import_csv(nylon, fmt="generic", sensor="s", columns=columns,
                      scales={"strain": 100.0})[1].warnings == []
