"""The uncertainty learned from runs left out: the variance model of
``strain_comp.core.uncertainty`` by maximum likelihood, then a factor on sigma
(docs/design.md, "Uncertainty")."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.metrics import Z_95
from strain_comp.core.uncertainty import (
    WEIGHT_MAX,
    Uncertainty,
    features_run,
    new_state,
)
from strain_comp.io.recording import Recording

RIDGE = 1e-3
"""Weight of a penalty ||w - w_0||^2 / 2 per unit of run weight on the weights but the bias."""
# a feature that never varies in the runs left out keeps weight 0, not an arbitrary one


def left_out_samples(started: Calibration, recordings: Mapping[str, Recording]
                     ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every referenced sensor's features and residuals, the engine run as ``evaluate``'s."""
    engine = Engine(replace(started, sensors={
        n: replace(c, uncertainty=None) for n, c in started.sensors.items()}))
    out = {}
    for name in started.sensors:
        rec = recordings.get(name)
        if rec is None or rec.s is None:
            continue
        batch = engine.run(name, rec.t, rec.r, rec.temperature)
        used = used_mask(batch.status)
        x = features_run(rec.t[used], batch.direction[used].astype(np.float64),
                         np.ascontiguousarray(batch.resistance[used]),
                         np.ascontiguousarray(batch.strain[used]),
                         new_state(), engine.limits_row(name))
        e = batch.strain[used] - rec.s[used]
        keep = np.isfinite(e) & np.isfinite(x).all(axis=1)
        out[name] = (x[keep], e[keep])
    return out


def likelihood_weights(runs: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The weights by maximum likelihood over ``runs`` (module docstring), unscaled."""
    x = np.concatenate([f for f, _ in runs])
    e2 = np.concatenate([e for _, e in runs]) ** 2
    weight = np.concatenate([np.full(e.size, 1.0 / max(e.size, 1)) for _, e in runs])
    w0 = np.zeros(x.shape[1])
    w0[0] = np.log(max(float(np.average(e2, weights=weight)), 1e-300))
    ridge = np.full(x.shape[1], RIDGE * weight.sum())
    ridge[0] = 0.0

    def nll(w: np.ndarray) -> tuple[float, np.ndarray]:
        z = np.clip(x @ w, -700.0, 700.0)
        q = e2 * np.exp(-z)
        d = w - w0
        value = 0.5 * float(weight @ (z + q)) + 0.5 * float(ridge @ (d * d))
        return value, 0.5 * (x.T @ (weight * (1.0 - q))) + ridge * d

    def hess(w: np.ndarray) -> np.ndarray:
        q = e2 * np.exp(-np.clip(x @ w, -700.0, 700.0))
        out: np.ndarray = 0.5 * (x.T * (weight * q)) @ x + np.diag(ridge)
        return out

    found: np.ndarray = minimize(nll, w0, jac=True, hess=hess, method="trust-exact").x
    return found


def fit_weights(runs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float]:
    """The weights over every run times the factor on sigma a new run needs (design.md)."""
    factors = []
    for j, (x, e) in enumerate(runs):
        others = [r for k, r in enumerate(runs) if k != j] or runs
        w = likelihood_weights(others)
        ratio = np.abs(e) / np.exp(0.5 * np.clip(x @ w, -700.0, 700.0))
        factors.append(float(np.quantile(ratio, 0.95)) / Z_95 if ratio.size else np.nan)
    factor = float(np.exp(np.nanmean(np.log(np.maximum(factors, 1e-150)))))
    w = likelihood_weights(runs)
    w[0] += 2.0 * np.log(max(factor, 1e-150))
    return np.clip(w, -WEIGHT_MAX, WEIGHT_MAX), factor


def learn(pairs: Iterable[tuple[Calibration, Mapping[str, Recording]]]
          ) -> dict[str, Uncertainty]:
    """Each sensor's uncertainty from runs left out (module docstring)."""
    by_sensor: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for started, recordings in pairs:
        for name, samples in left_out_samples(started, recordings).items():
            if samples[1].size:
                by_sensor.setdefault(name, []).append(samples)
    out = {}
    for name, runs in by_sensor.items():
        if len(runs) < 2:
            continue
        w, _ = fit_weights(runs)
        out[name] = Uncertainty(tuple(float(v) for v in w), runs=len(runs),
                                samples=sum(e.size for _, e in runs))
    return out
