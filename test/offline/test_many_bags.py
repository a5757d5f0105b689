"""``evaluate`` over many bags: outputs committed only when all of them were written, plot
folders confined under ``--plots`` and one per bag, SIGTERM ends every worker and removes
the temporaries (exit 143), pool workers' rows reach the table through files."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from strain_comp.cli import main
from strain_comp.offline.batch import plot_dirs

ROOT = Path(__file__).resolve().parents[2]
ERROR = "strain-comp: error: "


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four short rig bags (one named ``...mcap``) and a cubic calibration."""
    work = tmp_path_factory.mktemp("many")
    for seed, name in enumerate(("a.mcap", "b.mcap", "...mcap", "c.mcap")):
        assert main(["simulate", "--scenario", "triangle", "--out", str(work / name),
                     "--seed", str(seed + 1), "--duration", "60", "-q"]) == 0
    assert main(["fit", str(work / "a.mcap"), "--model", "cubic", "--sensor", "all",
                 "--out", str(work / "cal.yaml"), "-q"]) == 0
    return work


def cli(args: list[str], cwd: Path, fsize: int | None = None,
        env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    def limit() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return subprocess.Popen([sys.executable, "-m", "strain_comp.cli", *args], text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=cwd,
                            preexec_fn=limit, env={**os.environ, "PYTHONPATH": str(ROOT),
                                                   "PYTHONDONTWRITEBYTECODE": "1",
                                                   **(env or {})})


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_a_table_that_cannot_be_written_fails_the_command_and_keeps_the_old_one(
        work: Path, tmp_path: Path, jobs: str) -> None:
    """The failed CSV write was reported as a bag's error and the cut table committed over
    the old one ("wrote out.csv"); now the command fails naming the table, the old table
    and JSON stay, and nothing temporary is left."""
    (tmp_path / "out.csv").write_text("old table\n")
    (tmp_path / "out.json").write_text("{}\n")
    proc = cli(["evaluate", str(work / "a.mcap"), str(work / "b.mcap"), "--calibration",
                str(work / "cal.yaml"), "--csv", "out.csv", "--json", "out.json",
                "--jobs", jobs], tmp_path, fsize=64 * 1024)
    _, err = proc.communicate(timeout=300)
    lines = err.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, err
    assert lines[0].startswith(ERROR + "out.csv: cannot write"), lines[0]
    assert (tmp_path / "out.csv").read_text() == "old table\n"
    assert (tmp_path / "out.json").read_text() == "{}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv", "out.json"]


def test_plot_folders_stay_under_plots_and_are_one_per_bag(tmp_path: Path) -> None:
    plots = tmp_path / "plots"
    bags = ["x/...mcap", "rig/run/..", "a/x.mcap", "b/x.mcap", "c/x_2.mcap", "d/.mcap",
            "e/x.mcap"]
    dirs = [Path(str(d)) for d in plot_dirs(bags, str(plots))]
    assert len(set(dirs)) == len(bags)
    assert all(d.parent == plots and d.name not in ("", ".", "..") for d in dirs), dirs
    assert [d.name for d in dirs] == ["bag", "bag_2", "x", "x_2", "x_2_2", "bag_3", "x_3"]


def test_a_bag_named_dots_gets_its_plots_inside_plots(work: Path, tmp_path: Path) -> None:
    plots = tmp_path / "plots"
    assert main(["evaluate", str(work / "...mcap"), str(work / "a.mcap"), "--calibration",
                 str(work / "cal.yaml"), "--plots", str(plots), "-q"]) == 0
    written = [p for p in tmp_path.rglob("*.png")]
    assert written and all(plots in p.parents for p in written)
    assert sorted(p.name for p in plots.iterdir()) == ["a", "bag"]


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(x) for x in path.read_text().split()] if path.exists() else []


def test_sigterm_ends_every_worker_and_removes_the_temporaries(work: Path,
                                                               tmp_path: Path) -> None:
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    bags = [str(work / n) for n in ("a.mcap", "b.mcap", "c.mcap", "...mcap")]
    proc = cli(["evaluate", *bags, "--calibration", str(work / "cal.yaml"), "--csv",
                "out.csv", "--plots", "plots", "--jobs", "2", "--in-run-bound"], out,
               env={"TMPDIR": str(scratch)})
    deadline = time.monotonic() + 120
    workers: list[int] = []
    while time.monotonic() < deadline and len(workers) < 2:
        workers = _children(proc.pid)
        time.sleep(0.05)
    assert len(workers) >= 2, "the pool did not start"
    time.sleep(1.0)  # the workers are inside their bags
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode == 143
    time.sleep(0.5)
    assert not [w for w in workers if Path(f"/proc/{w}").exists()
                and "zombie" not in Path(f"/proc/{w}/status").read_text()]
    assert list(scratch.iterdir()) == []  # the CSV parts' folder
    left = [p for p in out.rglob("*") if p.name.endswith(".tmp") or p.name == "out.csv"]
    assert left == []
