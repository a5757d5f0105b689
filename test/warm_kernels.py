"""Compile the package's numba kernels into numba's cache before the pytest-xdist workers
start: test/conftest.py runs ``python test/warm_kernels.py PART`` for parts 0 and 1 side by
side. On a cold cache (a fresh clone) both workers would otherwise compile the same kernels
at the same moment, each test's first call paying for it. Each part runs a share of what
the tests run (the fits of ``conftest.fitted``, left pickled in ``conftest.FITS`` for the
workers to load, the measurement chain's correction, an array's fused tick, a replay, a
diagnosis); a kernel missed here is compiled by the first test that needs it, as before."""

from __future__ import annotations

import os
import pickle
import sys
import tempfile
from pathlib import Path

import numpy as np
from conftest import FITS, PROJECT_ROOT, fitted, training_recording

import strain_comp as sc
from strain_comp.core.calibration import Calibration
from strain_comp.core.chain import correct
from strain_comp.core.engine import Engine

PARTS = (("cubic", "sinh_pl", "spike_decay", "rational", "mpi"), ("apl", "pl", "creep_pi"))
"""The models each part fits. Part 0 first corrects a run (the chain's kernels, the
longest to compile), part 1 steps an array, replays and last diagnoses, by then finding
the chain's kernels in the cache: about even CPU time on a cold cache."""


def array_ticks() -> None:
    """A few ticks of an array of the two families with a fused tick (APL and creep_pi)."""
    sensors = {f"{model}{i}": fitted(model) for model in ("apl", "creep_pi") for i in range(2)}
    calibration = Calibration({name: type(cal)(**{**vars(cal), "name": name})
                               for name, cal in sensors.items()})
    engine = Engine(calibration, arrays={"array": list(sensors)})
    for i in range(5):
        engine.step_array("array", 0.02 * i, np.full(len(sensors), 150.0))


def main(part: int) -> None:
    if part == 0:
        run = training_recording()
        correct(run.t, run.r, alternating=False)
    for model in PARTS[part]:
        (Path(os.environ[FITS]) / f"{model}.pickle").write_bytes(pickle.dumps(fitted(model)))
    if part == 1:
        array_ticks()
        with tempfile.TemporaryDirectory() as tmp:
            sc.replay(PROJECT_ROOT / "config" / "array_calibration.yaml",
                      PROJECT_ROOT / "bags" / "array.mcap", Path(tmp) / "replayed.mcap")
        sc.diagnose(PROJECT_ROOT / "config" / "demo_calibration.yaml",
                    PROJECT_ROOT / "bags" / "steps.mcap", stretch_history=True)


if __name__ == "__main__":
    main(int(sys.argv[1]))
