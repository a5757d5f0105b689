# Study: Does every model survive rig runs unlike the bundled ones? (docs/architecture.md)
"""Every model through the command line on rig recordings unlike the bundled ones.

Each case turns two runs of the virtual rig (``strain_comp.offline.rig``, scenario ``random``
unless said, seeds 1 and 2) into bags of a sensor the bundled files do not show: resistance
falling with strain, in the Mohm or sub-ohm range, sampled at 1 Hz, 0.1 Hz or 1 kHz, stamped
in bursts (arrival times), with a long pause, with NaN references, or only 300 samples
long. For every model, ``strain-comp fit`` on the first run and ``strain-comp evaluate
--json`` on the second (read as strict JSON: a NaN literal fails), and the table gives the
held-out RMSE [% strain] against the reference's own standard deviation (an RMSE near that
means the output carries no information).

    python studies/unseen.py [--models cubic,apl] [--cases negative,slow] [--out DIR]

The ``base`` case is the rig as it is; a model that does well there and badly in another
case has a problem with what that case changes. Bags and calibrations go to ``--out``
(default: a temporary directory).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from strain_comp.cli import main
from strain_comp.io.bag import BagWriter
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.rig import RigEffects, simulate

Run = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(t [s], R [ohm], S [%]) of one sensor."""


def _resample(run: Run, fs: float) -> Run:
    t, r, s = run
    grid = np.arange(t[0], t[-1], 1.0 / fs)
    return grid, np.interp(grid, t, r), np.interp(grid, t, s)


def _bursts(run: Run, seed: int) -> Run:
    t, r, s = run
    late = np.maximum.accumulate(t + np.random.default_rng(seed).uniform(0.0, 0.035, t.size))
    return late + 1e-6 * np.arange(t.size), r, s


def _pause(run: Run) -> Run:
    t, r, s = run
    keep = (t < 100.0) | (t > 160.0)
    return t[keep], r[keep], s[keep]


def _nan_reference(run: Run, seed: int) -> Run:
    t, r, s = run
    s = s.copy()
    s[np.random.default_rng(seed).random(s.size) < 0.05] = np.nan
    return t, r, s


CASES: dict[str, tuple[str, Callable[[Run, int], Run]]] = {
    "base": ("random", lambda run, seed: run),
    "negative": ("random", lambda run, seed: (run[0], 34.5 - run[1], run[2])),
    "megaohm": ("random", lambda run, seed: (run[0], 2e5 * run[1], run[2])),
    "sub_ohm": ("random", lambda run, seed: (run[0], 0.02 * run[1], run[2])),
    "1hz": ("random", lambda run, seed: _resample(run, 1.0)),
    "1khz": ("random", lambda run, seed: _resample(run, 1000.0)),
    "bursts": ("random", _bursts),
    "pause": ("random", lambda run, seed: _pause(run)),
    "nan_reference": ("random", _nan_reference),
    "short": ("random", lambda run, seed: tuple(a[:300] for a in run)),  # type: ignore[misc]
    "slow_0.1hz": ("long", lambda run, seed: tuple(a[::50] for a in run)),  # type: ignore[misc]
}


def write_bag(path: Path, scenario: str, seed: int, change: Callable[[Run, int], Run]) -> float:
    """The case's bag of one rig run; returns the reference's standard deviation."""
    sensor = simulate(scenario, seed=seed, effects=RigEffects())["s1"]
    t, r, s = change((sensor.t, sensor.r, sensor.s), seed)
    with BagWriter(path) as writer:
        writer.write_float64("/s1/resistance", t, r)
        writer.write_float64("/s1/strain_reference", t, s)
    return float(np.nanstd(s))


def strict_json(path: Path) -> dict:
    def refuse(constant: str) -> None:
        raise ValueError(f"{path}: {constant} is not JSON")
    with path.open() as f:
        return json.load(f, parse_constant=refuse)


def cli(*args: str) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(list(args))
    return code, err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else ""


def run_case(out: Path, case: str, models: list[str]) -> list[str]:
    scenario, change = CASES[case]
    train, test = out / f"{case}_1.mcap", out / f"{case}_2.mcap"
    write_bag(train, scenario, 1, change)
    spread = write_bag(test, scenario, 2, change)
    rows = []
    for model in models:
        cal, js = out / f"{case}_{model}.yaml", out / f"{case}_{model}.json"
        start = time.perf_counter()
        code, line = cli("fit", str(train), "--model", model, "--sensor", "s1", "--out", str(cal))
        seconds = time.perf_counter() - start
        if code:
            rows.append(f"| {case} | {model} | fit exit {code}: {line} | | | |")
            continue
        code, line = cli("evaluate", str(test), "--calibration", str(cal), "--json", str(js))
        if code:
            rows.append(f"| {case} | {model} | evaluate exit {code}: {line} | | | |")
            continue
        stats = strict_json(js)["sensors"]["s1"]
        rmse = stats["rmse"]
        rows.append(f"| {case} | {model} | {rmse:.4g} | {spread:.4g} | {rmse / spread:.2f} | "
                    f"{seconds:.1f} |")
    return rows


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", default=",".join(MODEL_NAMES))
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--out", type=Path)
    return p.parse_args()


def main_script() -> None:
    args = parse_args()
    models = args.models.split(",")
    cases = args.cases.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        print("| case | model | held-out RMSE [%] | reference std [%] | RMSE / std | fit [s] |")
        print("|---|---|---:|---:|---:|---:|")
        for case in cases:
            for row in run_case(out, case, models):
                print(row, flush=True)


if __name__ == "__main__":
    main_script()
