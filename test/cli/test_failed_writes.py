"""No failed write of any command leaves a temporary file: under a file-size limit each
command that writes ends in one line naming its target, exit 2, and its folder holds what
it held before."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from strain_comp.cli import main

ROOT = Path(__file__).resolve().parents[2]
BAG = ROOT / "bags" / "steps.mcap"
CAL = ROOT / "config" / "demo_calibration.yaml"


def cli(args: list[str], fsize: int, cwd: Path) -> subprocess.CompletedProcess[str]:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return subprocess.run([sys.executable, "-m", "strain_comp.cli", *args], text=True,
                          capture_output=True, timeout=300, preexec_fn=limit, cwd=cwd,
                          env={**os.environ, "PYTHONPATH": str(ROOT),
                               "PYTHONDONTWRITEBYTECODE": "1"})


COMMANDS = {
    "simulate array": (["simulate", "--scenario", "array", "--out", "out2.mcap"], "out2.mcap"),
    "replay": (["replay", str(BAG), "--calibration", str(CAL), "--out", "out.mcap"],
               "out.mcap"),
    "evaluate csv": (["evaluate", str(BAG), "--calibration", str(CAL), "--csv", "out.csv"],
                     "out.csv"),
    "evaluate json": (["evaluate", str(BAG), "--calibration", str(CAL), "--json",
                       "out.json"], "out.json"),
    "fit": (["fit", str(BAG), "--model", "cubic", "--sensor", "s1", "--out", "c.yaml"],
            "c.yaml"),
}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_failed_write_leaves_no_temporary_file_and_names_its_target(
        tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Under ``ulimit -f`` of 1 byte (``simulate --scenario array`` left its temporary bag
    behind: the bag writer's close did not discard it on a failed write)."""
    args, target = COMMANDS[name]
    warm = tmp_path / "warm"  # the kernels compiled and cached first, without the limit
    warm.mkdir()
    monkeypatch.chdir(warm)  # in this process: one interpreter start fewer
    assert main(args) == 0
    work = tmp_path / "work"
    work.mkdir()
    (work / "keep.txt").write_text("kept")
    done = cli(args, 1, work)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith("strain-comp: error: ") and target in lines[0], lines[0]
    assert sorted(p.name for p in work.iterdir()) == ["keep.txt"]


def test_csv_writes_nan_and_inf_one_way(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A NaN and an infinite resistance are written ``nan`` and ``inf`` (as float() reads
    them back); the one empty cell is a reference the bag does not have."""
    import csv
    import math

    import numpy as np

    from strain_comp.io.bag import BagWriter

    bag = tmp_path / "in.mcap"
    t = np.arange(40) * 0.05
    r = np.linspace(12.0, 20.0, t.size)
    r[10], r[20], r[30] = np.nan, np.inf, -np.inf
    with BagWriter(bag) as writer:
        writer.write_float64("/s1/resistance", t, r)
        writer.write_float64("/s1/strain_reference", t[:30], np.linspace(0, 10, 30))
    monkeypatch.chdir(tmp_path)
    assert main(["replay", str(bag), "--calibration", str(CAL), "--out", "out.mcap", "--csv",
                 "out.csv"]) == 0
    with (tmp_path / "out.csv").open() as f:
        rows = list(csv.DictReader(f))
    cells = [row["resistance_ohm"] for row in rows]
    assert (cells[10], cells[20], cells[30]) == ("nan", "inf", "-inf")
    assert all(math.isfinite(float(c)) for i, c in enumerate(cells) if i not in (10, 20, 30))
    assert [float(c) for c in cells[:10]] == r[:10].tolist()
    refs = [row["reference"] for row in rows]
    assert all(c != "" for c in refs[:29]) and all(c == "" for c in refs[30:])
