"""Progress bars (strain_comp.progress): drawn for fit (an APL grid), diagnose, many-bag
evaluate and scripts/generalisation.py when stderr is a terminal, absent from a log (not a
terminal) and with --quiet. The terminal is a pseudo-terminal the command's stderr is
attached to."""

from __future__ import annotations

import fcntl
import os
import pty
import struct
import subprocess
import sys
import termios
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CAL = str(ROOT / "config" / "demo_calibration.yaml")
STEPS = str(ROOT / "bags" / "steps.mcap")
RATES = str(ROOT / "bags" / "demo_rates.mcap")


def commands(out: Path) -> dict[str, list[str]]:
    return {
        "apl fit": ["fit", STEPS, "--model", "apl", "--sensor", "s1", "--out",
                    str(out / "apl.yaml"), "--option", "N=5", "--option", "M=3"],
        "evaluate": ["evaluate", STEPS, RATES, "--calibration", CAL],
        "diagnose": ["diagnose", STEPS, "--calibration", CAL, "--out", str(out / "v2.yaml")],
        "benchmark": [str(ROOT / "scripts" / "generalisation.py"), "--sensors", "rig",
                      "--quick", "--models", "cubic", "--out", str(out / "generalisation")],
    }


def stderr_of(argv: list[str], *, terminal: bool) -> str:
    """What ``strain-comp argv`` writes to stderr: a pseudo-terminal's or a pipe's."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "100"}
    script = argv[0].endswith(".py")
    command = [sys.executable, *([] if script else ["-m", "strain_comp.cli"]), *argv]
    if not terminal:
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600,
                              check=True)
        return done.stderr
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 100 columns
    chunks: list[bytes] = []

    def drain() -> None:
        while True:
            try:
                data = os.read(main, 4096)
            except OSError:  # the child closed its end
                return
            if not data:
                return
            chunks.append(data)
    reader = threading.Thread(target=drain)
    reader.start()
    try:
        done = subprocess.run(command, env=env, stdout=subprocess.DEVNULL, stderr=child,
                              timeout=600)
    finally:
        os.close(child)
        reader.join(timeout=10)
        os.close(main)
    assert done.returncode == 0
    return b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.parametrize("what", ["apl fit", "evaluate", "diagnose", "benchmark"])
def test_a_bar_on_a_terminal_none_in_a_log_none_when_quiet(what: str, tmp_path: Path) -> None:
    """The three runs (a terminal, a log, a terminal with --quiet) are independent
    processes, each writing to a folder of its own: they run side by side."""
    runs = {"shown": (True, []), "logged": (False, []), "quiet": (True, ["--quiet"])}
    for name in runs:
        (tmp_path / name).mkdir()
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = {name: pool.submit(stderr_of, [*commands(tmp_path / name)[what], *extra],
                                     terminal=terminal)
                   for name, (terminal, extra) in runs.items()}
    shown, logged, quiet = (futures[name].result() for name in runs)
    assert f"\r{what}:" in shown  # tqdm's bar, redrawn in place
    assert f"{what}:" not in logged and "\r" not in logged
    assert "grid row" not in logged  # the APL grid's own lines gave way too
    assert quiet == ""
