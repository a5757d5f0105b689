"""Reduced power-law model with sinh resistors ([ReducedPL] eq. (1)-(3)), inverted exactly
through the linearly implicit forward step (Newton per sample); docs/models.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from strain_comp._numba import njit
from strain_comp.base.compensator import (
    Compensator,
    Normalisation,
    Segment,
    require_float,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.registry import register
from strain_comp.errors import FitError, ParameterError

_MAX_NEWTON = 30
_LOG_LO, _LOG_HI = -20.0, 10.0  # bounds of log I_S and log V_T in the fit
_START_NFEV = 15  # evaluations per start before the best start is refined
_START_SAMPLES = 5000  # starts see at most about this many samples


@njit
def _cell_step(u: float, e: float, dt: float, i_s: float, v_t: float) -> tuple[float, float]:
    """One linearly implicit step of u' = f(e - u); returns (u_new, d u_new / d e)."""
    x = (e - u) / v_t
    if x > 700.0:
        x = 700.0
    elif x < -700.0:
        x = -700.0
    q = math.exp(-abs(x))
    sign = 1.0 if x >= 0.0 else -1.0
    c = 2.0 * i_s / v_t
    d = q + 0.5 * dt * c * (1.0 + q * q)  # (1 + dt g') / m
    du = dt * i_s * sign * (1.0 - q * q) / d  # dt g / (1 + dt g')
    slope = dt * (0.5 * c * (1.0 + q * q) * q + dt * c * c * q * q) / (d * d)
    return u + du, slope


@njit
def sinh_pl_inverse_kernel(state: np.ndarray, t: np.ndarray, xi: np.ndarray, w0: float,
                           vb: float, w: np.ndarray, i_s: np.ndarray, v_t: np.ndarray
                           ) -> np.ndarray:
    """Compensator eq. (3), exact inverse of the discrete forward model: xi -> psi."""
    n_cells = w.size
    out = np.empty(t.size)
    gain = w0
    for k in range(n_cells):
        gain += w[k]
    if gain == 0.0:  # no static map to start from: start from the explicit eq. (3)
        gain = w0
    for n in range(t.size):
        target = xi[n] + vb
        if state[0] == 0.0:
            state[0] = 1.0
            e = target / gain
            for k in range(n_cells):
                state[2 + k] = e
        else:
            dt = t[n] - state[1]
            acc = target
            for k in range(n_cells):
                acc -= w[k] * state[2 + k]
            e = acc / w0  # explicit eq. (3) with the old states
            if dt > 0.0:
                for _ in range(_MAX_NEWTON):
                    h = w0 * e - target
                    dh = w0
                    for k in range(n_cells):
                        u_new, slope = _cell_step(state[2 + k], e, dt, i_s[k], v_t[k])
                        h += w[k] * u_new
                        dh += w[k] * slope
                    if dh == 0.0 or not math.isfinite(dh):
                        dh = w0
                    delta = h / dh
                    e -= delta
                    if abs(delta) <= 1e-14 * (1.0 + abs(e)):
                        break
                for k in range(n_cells):
                    state[2 + k] = _cell_step(state[2 + k], e, dt, i_s[k], v_t[k])[0]
        state[1] = t[n]
        out[n] = e
    return out


@register
class SinhPL(Compensator):
    """Reduced power-law compensator with N sinh cells, eq. (1)-(3)."""

    name = "sinh_pl"
    param_names = ("w0", "vb", "w", "i_s", "v_t")

    def __init__(self, w0: float, vb: float, w: npt.ArrayLike, i_s: npt.ArrayLike,
                 v_t: npt.ArrayLike, normalisation: Normalisation) -> None:
        super().__init__(normalisation)
        self.w0 = float(w0)
        self.vb = float(vb)
        self.w = np.ascontiguousarray(w, dtype=np.float64)
        self.i_s = np.ascontiguousarray(i_s, dtype=np.float64)
        self.v_t = np.ascontiguousarray(v_t, dtype=np.float64)
        self.state = np.zeros(2 + self.w.size)

    def reset(self) -> None:
        """Cells back to 'not started': the next sample puts them at rest."""
        self.state[:] = 0.0

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        out[:] = self.normalisation.strain(sinh_pl_inverse_kernel(
            self.state, t, self.normalisation.xi(r), self.w0, self.vb, self.w, self.i_s,
            self.v_t))

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> SinhPL:
        w0 = require_float(params, "w0")
        if w0 == 0.0:
            raise ParameterError("w0", "must be non-zero (the compensator divides by it)")
        vb = require_float(params, "vb")
        w = require_vector(params, "w")
        i_s = require_vector(params, "i_s", length=w.size, lo=0.0, strict=True)
        v_t = require_vector(params, "v_t", length=w.size, lo=0.0, strict=True)
        return cls(w0, vb, w, i_s, v_t, normalisation)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, n_cells: int = 1, max_nfev: int = 100,
            **options: Any) -> SinhPL:
        """Nonlinear least squares on the inverse output error; ``n_cells`` 1 to 3."""
        data = [(seg.t, normalisation.xi(seg.r), normalisation.psi(seg.s)) for seg in segments]
        n_samples = sum(d[0].size for d in data)
        if n_samples < 10 * (3 * n_cells + 2):
            raise FitError(f"sinh_pl: needs at least {10 * (3 * n_cells + 2)} samples, "
                           f"got {n_samples}")
        xi_all = np.concatenate([d[1] for d in data])
        psi_all = np.concatenate([d[2] for d in data])
        slope, offset = np.polyfit(psi_all, xi_all, 1)  # static map xi = gain psi - Vb
        if slope == 0.0 or not np.isfinite(slope):
            raise FitError("sinh_pl: resistance does not change with strain")
        dts = np.concatenate([np.diff(d[0]) for d in data if d[0].size > 1])
        duration = sum(float(d[0][-1] - d[0][0]) for d in data)
        tau_lo = max(10.0 * float(np.median(dts)), 1e-3)
        tau_hi = max(duration / 20.0, 2.0 * tau_lo)

        def unpack(x: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
            return (x[0], x[1], x[2:2 + n_cells], np.exp(x[2 + n_cells:2 + 2 * n_cells]),
                    np.exp(x[2 + 2 * n_cells:]))

        def residual(x: np.ndarray,
                     data: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = data
                     ) -> np.ndarray:
            w0, vb, w, i_s, v_t = unpack(x)
            parts = []
            for t, xi, psi in data:
                state = np.zeros(2 + n_cells)
                parts.append(sinh_pl_inverse_kernel(state, t, xi, w0, vb, w, i_s, v_t) - psi)
            res = np.concatenate(parts)
            return np.where(np.isfinite(res), res, 1e3)

        taus = np.geomspace(tau_lo, tau_hi, n_cells + 2)[1:-1]  # cell time constants
        # starts run on every k-th sample (the integrator is stable for any dt)
        k = max(1, n_samples // _START_SAMPLES)
        coarse = [(t[::k], xi[::k], psi[::k]) for t, xi, psi in data]
        # w0 keeps the sign of the static gain and stays away from 0; log I_S, log V_T bounded
        # and |w_k| <= 10 |gain| (the paper bounds the weights likewise)
        w0_lo, w0_hi = (0.05 * slope, np.inf) if slope > 0 else (-np.inf, 0.05 * slope)
        w_max = 10.0 * abs(slope)
        lower = np.concatenate([[w0_lo, -np.inf], np.full(n_cells, -w_max),
                                np.full(2 * n_cells, _LOG_LO)])
        upper = np.concatenate([[w0_hi, np.inf], np.full(n_cells, w_max),
                                np.full(2 * n_cells, _LOG_HI)])
        starts = []
        for share in (0.8, 0.5):
            for v_t0 in (0.1, 1.0):
                w_cells = np.full(n_cells, (1.0 - share) * slope / n_cells)
                x0 = np.concatenate([[share * slope, -offset], w_cells,
                                     np.log(v_t0 / (2.0 * taus)), np.full(n_cells,
                                                                          np.log(v_t0))])
                starts.append(least_squares(
                    residual, np.clip(x0, lower + 1e-9, upper - 1e-9), bounds=(lower, upper),
                    method="trf", x_scale="jac", max_nfev=_START_NFEV, kwargs={"data": coarse}))
        best = least_squares(residual, min(starts, key=lambda sol: sol.cost).x,
                             bounds=(lower, upper), method="trf", x_scale="jac",
                             max_nfev=max_nfev)
        return cls(*unpack(best.x), normalisation)  # w0 bounded away from 0
