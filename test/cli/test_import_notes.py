"""import-csv on stderr and stdout: notes on stderr, each on its own line, silenced by
``-q``; ``--columns`` takes ASCII digits or a header name; a scale that overflows is one
clear line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main
from strain_comp.io.recording import load_recordings

PROG = "strain-comp"


def fiber_csv(path: Path) -> Path:
    """A fiber-format file (time, extension [mm], force, resistance)."""
    t = np.arange(0.0, 120.0, 1.0)
    extension = 10.0 * np.abs((t / 60.0) % 2.0 - 1.0)
    np.savetxt(path, np.column_stack([t, extension, 0.1 * extension, 70.0 + 0.5 * extension]),
               delimiter=",")
    return path


@pytest.mark.parametrize("quiet", [False, True])
def test_notes_go_to_stderr_on_their_own_line_and_quiet_silences_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], quiet: bool) -> None:
    csv = fiber_csv(tmp_path / "f.csv")
    bag = tmp_path / "f.mcap"
    assert main(["import-csv", str(csv), "--out", str(bag), "--sensor", "s1", "--format",
                 "fiber", *(["-q"] if quiet else [])]) == 0  # no gauge length: a note
    out, err = capsys.readouterr()
    assert "note:" not in out and "120 rows" in out
    notes = [line for line in err.splitlines() if "note:" in line]
    if quiet:
        assert err == ""
    else:
        assert len(notes) == 1 and notes[0].startswith(f"{PROG}: note: no --gauge-length-mm")
        assert any(line.startswith("wrote ") for line in err.splitlines())
    assert load_recordings(bag)[0]["s1"].t.size == 120


@pytest.mark.parametrize("column", ["²", "١", "0x1", "-1"])
def test_columns_take_ascii_digits_or_a_header_name(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str) -> None:
    csv = fiber_csv(tmp_path / "f.csv")
    code = main(["import-csv", str(csv), "--out", str(tmp_path / "o.mcap"), "--sensor", "s1",
                 "--format", "generic", "--columns", f"time={column},resistance=3"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith(f"{PROG}: error: "), err
    assert "unexpected" not in err[0] and f"time={column!r}" in err[0], err[0]
    assert not (tmp_path / "o.mcap").exists()


def test_a_scale_that_overflows_is_one_clear_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = fiber_csv(tmp_path / "f.csv")
    code = main(["import-csv", str(csv), "--out", str(tmp_path / "o.mcap"), "--sensor", "s1",
                 "--format", "generic", "--columns", "time=0,resistance=3,strain=1",
                 "--scales", "strain=1e308"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "--scales strain=1e+308" in err[0] and "overflow" in err[0], err[0]
    assert "time span" not in err[0] and not (tmp_path / "o.mcap").exists()
