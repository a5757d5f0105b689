"""Spike-and-decay model of viscoelastic nanocomposite gauges ([Nanocomposite] eq. (3), (4));
the forward model, the online inversion, its known limit and the fit: docs/models.md."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import (
    Compensator,
    Normalisation,
    Segment,
    as_float_arrays,
    require_float,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.registry import register
from strain_comp.errors import FitError, ParameterError
from strain_comp.models.spike_decay_fit import (
    analyse_holds,
    default_hold_rate,
    fit_f,
    movements,
    settled_points,
    tabulate,
)
from strain_comp.models.spike_decay_kernels import (
    STATE_LEN,
    f_eval,
    spike_decay_kernel,
    table_lookup,
)


@register
class SpikeDecay(Compensator):
    """Spike-and-decay inverse model, eq. (3)/(4)."""

    name = "spike_decay"

    def __init__(self, knots: npt.ArrayLike, c: npt.ArrayLike,
                 eps_range: Sequence[float] | np.ndarray, rates: npt.ArrayLike,
                 strains: npt.ArrayLike, s_table: npt.ArrayLike, lam_table: npt.ArrayLike,
                 min_step: float, normalisation: Normalisation,
                 direction: DirectionSettings) -> None:
        super().__init__(normalisation)
        self.direction = direction
        self.knots = np.ascontiguousarray(knots, dtype=np.float64)
        self.c = np.ascontiguousarray(c, dtype=np.float64).reshape(self.knots.size, 4)
        self.lo, self.hi = float(eps_range[0]), float(eps_range[1])
        self.rates = np.ascontiguousarray(rates, dtype=np.float64)
        self.strains = np.ascontiguousarray(strains, dtype=np.float64)
        shape = (2, self.rates.size, self.strains.size)
        self.s_table = np.ascontiguousarray(s_table, dtype=np.float64).reshape(shape)
        self.lam_table = np.ascontiguousarray(lam_table, dtype=np.float64).reshape(shape)
        self.min_step = float(min_step)
        self.state = np.zeros(STATE_LEN)

    def reset(self) -> None:
        """No spike, no movement; the detector restarts."""
        self.state[:] = 0.0

    def f(self, eps: npt.ArrayLike) -> np.ndarray:
        """Quasi-static resistance f(eps) [ohm], eq. (4), for strain eps [%]."""
        eps = np.asarray(eps, dtype=np.float64)
        return np.asarray(np.vectorize(lambda e: f_eval(self.knots, self.c, float(e)))(eps))

    def spike(self, rate: float, eps: float, *, loading: bool = True) -> tuple[float, float]:
        """(S, lambda) from the tables for a movement at ``rate`` [%/s] ending at ``eps`` [%]."""
        k = 0 if loading else 1
        args = (np.log10(self.rates), self.strains, float(rate), float(eps))
        return (float(table_lookup(self.s_table[k], *args)),
                float(table_lookup(self.lam_table[k], *args)))

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        out[:] = spike_decay_kernel(self.state, t, r, self.knots, self.c, self.lo, self.hi,
                                    np.log10(self.rates), self.strains, self.s_table,
                                    self.lam_table, self.min_step, self.direction.deadzone,
                                    self.direction.tau)

    def predict_resistance(self, t: npt.ArrayLike, s: npt.ArrayLike) -> np.ndarray:
        """Forward eq. (3) for a known strain history s [%] (the paper's output prediction)."""
        t, s = as_float_arrays(t, s)
        factor = np.ones(t.size)
        for start, end in movements(t, s, default_hold_rate(s)):
            change = s[end] - s[start]
            rate = abs(change) / (t[end] - t[start])
            spike, lam = self.spike(rate, s[end], loading=change >= 0)
            after = t >= t[end]
            factor[after] = 1.0 + spike * np.exp(-lam * (t[after] - t[end]))
        return self.f(s) * factor

    def to_params(self) -> dict[str, Any]:
        return {"knots": self.knots.tolist(), "c": self.c.tolist(), "range": [self.lo, self.hi],
                "rates": self.rates.tolist(), "strains": self.strains.tolist(),
                "S_loading": self.s_table[0].tolist(), "lambda_loading": self.lam_table[0].tolist(),
                "S_unloading": self.s_table[1].tolist(),
                "lambda_unloading": self.lam_table[1].tolist(), "min_step": self.min_step}

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> SpikeDecay:
        knots = require_vector(params, "knots")
        if np.any(np.diff(knots) <= 0.0):
            raise ParameterError("knots", "must be strictly increasing")
        c = _require_matrix(params, "c", (knots.size, 4))
        eps_range = require_vector(params, "range", length=2)
        if not (knots[0] <= eps_range[0] < eps_range[1]):
            raise ParameterError("range", f"must be [lo, hi] with {knots[0]} <= lo < hi, "
                                 f"got {eps_range.tolist()}")
        grid = np.linspace(eps_range[0], eps_range[1], 401)
        values = np.array([f_eval(knots, c, float(e)) for e in grid])
        steps = np.diff(values)
        if not (np.all(steps > 0.0) or np.all(steps < 0.0)):
            raise ParameterError("c", "f is not strictly monotone on range")
        rates = require_vector(params, "rates", lo=0.0, strict=True)
        if np.any(np.diff(rates) <= 0.0):
            raise ParameterError("rates", "must be strictly increasing")
        strains = require_vector(params, "strains")
        if np.any(np.diff(strains) <= 0.0):
            raise ParameterError("strains", "must be strictly increasing")
        shape = (rates.size, strains.size)
        # every S > -1 (a positive resistance), every lambda > 0
        tables = {key: _require_matrix(params, key, shape, lo=-1.0 if key[0] == "S" else 0.0)
                  for key in ("S_loading", "lambda_loading", "S_unloading", "lambda_unloading")}
        min_step = require_float(params, "min_step", lo=0.0)
        return cls(knots, c, eps_range, rates, strains,
                   [tables["S_loading"], tables["S_unloading"]],
                   [tables["lambda_loading"], tables["lambda_unloading"]], min_step,
                   normalisation, direction)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, hold_rate: float | None = None,
            min_hold: float = 1.0, **options: Any) -> SpikeDecay:
        """Fit from step-and-hold data; ``hold_rate`` [%/s], ``min_hold`` [s]."""
        s_all = np.concatenate([seg.s for seg in segments])
        if s_all.size < 10:
            raise FitError(f"spike_decay: needs at least 10 samples, got {s_all.size}")
        span = float(np.ptp(s_all))
        hold_rate = default_hold_rate(s_all) if hold_rate is None else float(hold_rate)
        settled, steps = analyse_holds(segments, hold_rate, min_hold)
        tol = 0.01 * span
        eps_pts, r_pts, steps = settled_points(segments, settled, steps, tol)
        knots, c, eps_range = fit_f(eps_pts, r_pts)
        rates, strains, s_table, lam_table = tabulate(steps, eps_pts, tol)
        sizes = [st[5] for st in steps]
        min_step = 0.25 * float(np.median(sizes)) if sizes else 0.0
        return cls(knots, c, eps_range, rates, strains, s_table, lam_table, min_step,
                   normalisation, direction)


def _require_matrix(params: Mapping[str, Any], key: str, shape: tuple[int, int], *,
                    lo: float | None = None) -> np.ndarray:
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != shape[0]:
        raise ParameterError(key, f"must be a list of {shape[0]} rows")
    rows = [require_vector({f"{key}.{i}": row}, f"{key}.{i}", length=shape[1], lo=lo,
                           strict=True)
            for i, row in enumerate(value)]
    return np.array(rows, dtype=np.float64).reshape(shape)
