"""Shared set-up of the bench scripts: calibrations built from parameters, inputs, timing.

The APL parameters are the paper's ([Electrolycra] Table I:
sigma = 2.15e-2 /s, p = 0.73, w) with a mildly nonlinear f (M = 9), as in
``bench/bench_kernels.py``; each sensor gets a seeded perturbation of sigma, p and w so
that an array is not 256 copies of one sensor. The normalisation maps R in about
[11.5, 25.9] ohm and S in [0, 50] % onto [-1, 1].
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

import strain_comp.models  # noqa: F401  (registers the families the calibrations name)
from strain_comp.base.compensator import Normalisation
from strain_comp.base.direction import DirectionSettings
from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.core.uncertainty import Uncertainty

NORM = Normalisation(r0=7.16, alpha=-2.61, s0=25.0, beta=-1.0)
R_LO, R_HI = (-1.0 - NORM.alpha) * NORM.r0, (1.0 - NORM.alpha) * NORM.r0
RANGE = ValidRange(R_LO, R_HI, 0.0, 50.0)
DIRECTION = DirectionSettings(deadzone=2.0, tau=0.02)
W_PAPER = [2.523, 0.843, 1.522, 0.522, 0.513, 0.002, 0.022, 0.041, 0.106, 0.276, 0.457, 0.695,
           0.0]
MU = [1.0, 0.05, -0.03, 0.08, 0.02, 0.1, -0.05, 0.04, 0.06]
CUBIC = [-69.5, 7.816, -0.2112, 0.003512]


def apl_params(rng: np.random.Generator | None = None) -> dict[str, object]:
    """``APL.to_params()`` format (N, M, sigma, p, w, mu); perturbed when ``rng`` is given."""
    sigma, p, w = 2.15e-2, 0.73, np.array(W_PAPER)
    if rng is not None:
        sigma *= rng.uniform(0.5, 2.0)
        p *= rng.uniform(0.8, 1.3)
        w = w * rng.uniform(0.9, 1.1, w.size)
    return {"N": 11, "M": 9, "sigma": float(sigma), "p": float(p),
            "w": [float(v) for v in w], "mu": list(MU)}


def creep_params(rng: np.random.Generator | None = None) -> dict[str, object]:
    """``CreepPI.to_params()`` format: default time constants and 8 play operators, weights
    of a loop that lags with creep (perturbed when ``rng`` is given)."""
    from strain_comp.models.creep_pi import DIRECTION_WIDTH, TAUS, play_thresholds

    w = np.array([1.0, 0.05, 0.02, *[-0.05] * 8, 0.1, 0.05, 0.03, 0.02, 0.5, 0.1])
    if rng is not None:
        w = w * rng.uniform(0.9, 1.1, w.size)
    return {"taus": list(TAUS), "thresholds": [float(v) for v in play_thresholds(8)],
            "direction_width": DIRECTION_WIDTH, "mean": [0.0] * w.size,
            "scale": [1.0] * w.size, "weights": [float(v) for v in w], "intercept": 0.0,
            "penalty": 0.0}


def sensor(name: str, model: str, rng: np.random.Generator | None = None) -> SensorCalibration:
    """A calibration of one sensor (``apl``, ``creep_pi`` or ``cubic``) built from
    parameters."""
    params = (apl_params(rng) if model == "apl" else creep_params(rng) if model == "creep_pi"
              else {"c": list(CUBIC)})
    return SensorCalibration(name=name, model=model, params=params, normalisation=NORM,
                             valid_range=RANGE, direction=DIRECTION)


BAND = Uncertainty.from_weights({"bias": -3.0, "loading": 0.4, "unloading": 0.7,
                                 "hold": -0.2, "outside": 2.0, "elapsed": 0.3, "level": 1.1})
"""An uncertainty for ``calibration(..., band=True)`` (every feature weighed)."""


def calibration(names: Sequence[str], models: Sequence[str], *, seed: int = 0,
                band: bool = False) -> Calibration:
    """One calibration for ``names``, sensor i using ``models[i % len(models)]``; with
    ``band``, each with the uncertainty ``BAND`` (the engine computes every estimate's
    standard deviation)."""
    rng = np.random.default_rng(seed)
    return Calibration({name: replace(sensor(name, models[i % len(models)], rng),
                                      uncertainty=BAND if band else None)
                        for i, name in enumerate(names)})


def resistance(t: np.ndarray, k: int, *, seed: int = 0) -> np.ndarray:
    """(n, k) resistance [ohm] inside the valid range: triangles of 2-20 s periods with a
    per-sensor phase, plus 0.02 ohm noise."""
    rng = np.random.default_rng(seed)
    period = rng.uniform(2.0, 20.0, k)
    phase = rng.uniform(0.0, 1.0, k)
    tri = 1.0 - np.abs(1.0 - 2.0 * ((t[:, None] / period + phase) % 1.0))
    r = R_LO + 0.05 * (R_HI - R_LO) + 0.9 * (R_HI - R_LO) * tri
    return r + rng.normal(0.0, 0.02, r.shape)


def best_time(fn: Callable[[], object], repeat: int = 3) -> float:
    """Smallest wall time [s] of ``repeat`` calls."""
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def peak_rss_mb() -> float:
    """This process's peak resident memory so far [MB]."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def row(what: str, figure: str, baseline: str, ratio: str, *,
        memory_mb: float | None = None) -> None:
    """Print one row of docs/results.md's table (``bench/perf_table.py`` collects the
    ``ROW`` lines of ``bench/run_all.sh``); memory: the peak RSS of this process unless
    given."""
    memory = peak_rss_mb() if memory_mb is None else memory_mb
    print(f"ROW | {what} | {figure} | {baseline} | {ratio} | {memory:.0f} MB |", flush=True)
