"""Spike-and-decay model of viscoelastic nanocomposite gauges ([Nanocomposite] eq. (3), (4)).

Forward model, eq. (3): R = f(eps) [1 + S exp(-lambda (t - ts))], with

* f the quasi-static curve, a piecewise cubic in the form of eq. (4) / Table 2: on
  knots[i] <= eps < knots[i+1], f = c0 + c1 d + c2 d^2 + c3 d^3 with d = eps - knots[i].
  Units here: eps in % strain (Table 2 uses a strain fraction), R in ohm.
* S [ohm/ohm] and lambda [1/s] tabulated over (movement rate [%/s] x strain [%]) as in
  Tables 4 and 5, one pair of tables for movements that raise the strain (``loading``) and
  one for movements that lower it (``unloading``); looked up by bilinear interpolation in
  (log10 rate, strain), clamped at the table edges. S may be negative (an undershoot).
* ts the end of the last movement; while a new movement is under way the previous spike
  keeps decaying.

Online inversion (``step``/``run``, one numba kernel):

1. The dead-zone direction detector ([EGaIn] section V.E, ``strain_comp.core.direction``)
   runs on the spike-compensated resistance R_c = R / (1 + S exp(-lambda (t - ts))) of the
   active spike, so the decay of a spike already accounted for is not taken for movement.
2. A movement starts when the detector leaves 0; its start time and start strain are
   those of the last hold sample. Along the movement the model tracks its furthest point
   (the extreme of R_c in the movement's direction: the peak of a spike). The movement
   ends at the first sample where the detector leaves the movement's sign (to hold or to
   the opposite sign); ts is then the time of the furthest point, so the detector's lag
   (filter, dead zone) does not delay the decay.
3. At the end: (S, lambda) from the tables at (rate, eps_end), eps_end solving
   R_peak = f(eps_end)(1 + S) (three fixed-point passes, as the paper divides the spiked
   reading by 1 + S), rate = |eps_end - eps_start| / (ts - start) from the model's own
   strain estimates, the table (loading / unloading) from the sign of the strain change.
   Movements smaller than ``min_step`` [%] (noise, a mis-modelled decay) start no new
   spike. The detector then restarts from R_c.
4. Every sample: eps = f^-1(R_c) on the monotone branch of f. f is only inverted on the
   stored ``range`` [lo, hi] where it is strictly monotone (carbon-black sensors have a
   non-monotone shoulder); readings beyond f(lo) or f(hi) give lo or hi (clamped; the
   calibration's valid range flags them).

Known limit: when a spike decays in the direction of the movement that caused it (S > 0
after a movement that lowered R: R keeps falling while the spike decays), the detector
takes the decay for a continuing movement; ts then comes late and the spike is
overestimated until it has decayed.

Fit (from step-and-hold data with a reference strain): holds are runs where the reference
moves slower than ``hold_rate`` [%/s] (default 0.2 % of the strain span per second) for at
least ``min_hold`` s (default 1 s). Each hold after a movement is fitted with
R = R_inf (1 + S exp(-lambda (t - t_end))) by least squares (t_end = end of the reference
movement); R_inf at the hold's strain gives the settled points of f (points at one strain
level, within 1 % of the span, are averaged; f = the monotone piecewise cubic Hermite
(PCHIP) interpolant through them, ``range`` = the longest strictly monotone run of
points). S, lambda go into the cell of the table nearest to the movement's (rate, strain);
table axes are the rates (clustered within a factor 1.5) and strain levels present; a cell
without data is filled from the mean of its filled neighbours, repeatedly; a direction
without any step copies the other's table; lambda is kept only from holds whose spike
stands clear of the noise; ``min_step`` = a quarter of the median training step. Without
usable holds (fewer than two settled levels) f is
fitted to all samples (PCHIP through the mean (strain, R) of 40 strain bins; the range
ends at the outer bins' mean strain) and S = 0: a plain quasi-static inverse.

``recalibrate_two_point`` scales and shifts f (f_new = a f + b) through two known points,
as the paper calibrates a new sensor of the same make at 0 % and 15 % strain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.interpolate import PchipInterpolator
from scipy.optimize import least_squares

from strain_comp._numba import njit
from strain_comp.core.direction import (
    STATE_SIZE,
    DirectionSettings,
    _check_settings,
    direction_update,
)
from strain_comp.errors import FitError, ParameterError
from strain_comp.models.base import (
    Compensator,
    Normalisation,
    Segment,
    as_float_arrays,
    require_float,
    require_vector,
)

# kernel state layout after the detector's STATE_SIZE entries
(_STARTED, _MOVING, _T_MOVE, _EPS_MOVE, _TS, _S, _LAM, _EPS, _T_LAST, _T_EXT, _R_EXT,
 _RC_EXT) = range(STATE_SIZE, STATE_SIZE + 12)
_STATE_LEN = STATE_SIZE + 12
_BISECT = 60
_N_BINS = 40  # strain bins of the quasi-static fit without holds


@njit
def f_eval(knots: np.ndarray, c: np.ndarray, eps: float) -> float:
    """Quasi-static curve eq. (4): the piece whose knot is the last one <= eps."""
    i = 0
    while i + 1 < knots.size and eps >= knots[i + 1]:
        i += 1
    d = eps - knots[i]
    return ((c[i, 3] * d + c[i, 2]) * d + c[i, 1]) * d + c[i, 0]


@njit
def f_invert(knots: np.ndarray, c: np.ndarray, lo: float, hi: float, r: float) -> float:
    """eps in [lo, hi] with f(eps) = r on the monotone branch, clamped at the ends."""
    f_lo = f_eval(knots, c, lo)
    f_hi = f_eval(knots, c, hi)
    rising = f_hi > f_lo
    if (r <= f_lo) == rising:
        return lo
    if (r >= f_hi) == rising:
        return hi
    a, b = lo, hi
    for _ in range(_BISECT):
        m = 0.5 * (a + b)
        if (f_eval(knots, c, m) < r) == rising:
            a = m
        else:
            b = m
        if b - a <= 1e-13 * (1.0 + abs(m)):
            break
    return 0.5 * (a + b)


@njit
def _axis(grid: np.ndarray, x: float) -> tuple[int, float]:
    """Cell index and weight for linear interpolation on ``grid``, clamped at the edges."""
    if grid.size == 1 or x <= grid[0]:
        return 0, 0.0
    if x >= grid[-1]:
        return grid.size - 2, 1.0
    i = 0
    while x >= grid[i + 1]:
        i += 1
    return i, (x - grid[i]) / (grid[i + 1] - grid[i])


@njit
def table_lookup(table: np.ndarray, log_rates: np.ndarray, strains: np.ndarray, rate: float,
                 eps: float) -> float:
    """Bilinear interpolation in (log10 rate, strain), clamped; rate <= 0 -> lowest rate."""
    x = math.log10(rate) if rate > 0.0 else -1e300
    i, u = _axis(log_rates, x)
    j, v = _axis(strains, eps)
    i1 = min(i + 1, log_rates.size - 1)
    j1 = min(j + 1, strains.size - 1)
    return ((1 - u) * (1 - v) * table[i, j] + u * (1 - v) * table[i1, j]
            + (1 - u) * v * table[i, j1] + u * v * table[i1, j1])


@njit
def spike_decay_kernel(state: np.ndarray, t: np.ndarray, r: np.ndarray, knots: np.ndarray,
                       c: np.ndarray, lo: float, hi: float, log_rates: np.ndarray,
                       strains: np.ndarray, s_tab: np.ndarray, lam_tab: np.ndarray,
                       min_step: float, deadzone: float, tau: float) -> np.ndarray:
    """Online inversion of eq. (3); see the module docstring for the steps."""
    out = np.empty(t.size)
    for n in range(t.size):
        tn = t[n]
        rn = r[n]
        if state[_STARTED] == 0.0:
            state[_STARTED] = 1.0
            direction_update(state, tn, rn, deadzone, tau)
            eps = f_invert(knots, c, lo, hi, rn)
        else:
            factor = 1.0
            if state[_S] != 0.0:
                factor = 1.0 + state[_S] * math.exp(-state[_LAM] * max(tn - state[_TS], 0.0))
            r_c = rn / factor
            d = direction_update(state, tn, r_c, deadzone, tau)
            moving = int(state[_MOVING])
            if moving == 0 and d != 0:  # a movement starts
                moving = d
                state[_MOVING] = float(d)
                state[_T_MOVE] = state[_T_LAST]
                state[_EPS_MOVE] = state[_EPS]
                state[_T_EXT] = tn
                state[_R_EXT] = rn
                state[_RC_EXT] = r_c
            elif moving != 0 and (r_c - state[_RC_EXT]) * moving > 0.0:
                state[_T_EXT] = tn  # furthest point of the movement so far
                state[_R_EXT] = rn
                state[_RC_EXT] = r_c
            eps = f_invert(knots, c, lo, hi, r_c)
            if moving != 0 and d != moving:  # the movement ended: ts = its furthest point
                t_end = state[_T_EXT]
                duration = max(t_end - state[_T_MOVE], 1e-9)
                eps_end = f_invert(knots, c, lo, hi, state[_RC_EXT])
                if abs(eps_end - state[_EPS_MOVE]) >= min_step:
                    s_new = 0.0
                    lam = 1.0
                    for _ in range(3):
                        change = eps_end - state[_EPS_MOVE]
                        k = 0 if change >= 0.0 else 1
                        rate = abs(change) / duration
                        s_new = table_lookup(s_tab[k], log_rates, strains, rate, eps_end)
                        lam = table_lookup(lam_tab[k], log_rates, strains, rate, eps_end)
                        eps_end = f_invert(knots, c, lo, hi, state[_R_EXT] / (1.0 + s_new))
                    state[_TS] = t_end
                    state[_S] = s_new
                    state[_LAM] = lam
                    r_c = rn / (1.0 + s_new * math.exp(-lam * (tn - t_end)))
                    eps = f_invert(knots, c, lo, hi, r_c)
                state[_MOVING] = 0.0
                # the detector restarts on the compensated resistance
                state[1] = tn
                state[2] = r_c
                state[3] = 0.0
                state[4] = 0.0
        state[_EPS] = eps
        state[_T_LAST] = tn
        out[n] = eps
    return out


@dataclass(frozen=True)
class _Movement:
    """One movement of the reference strain: sample indices of its start and end."""

    start: int
    end: int


def _movements(t: np.ndarray, s: np.ndarray, hold_rate: float) -> list[_Movement]:
    """Maximal runs of sample intervals where |ds/dt| > hold_rate."""
    if t.size < 2:
        return []
    moving = np.abs(np.diff(s) / np.diff(t)) > hold_rate
    edges = np.diff(np.concatenate([[0], moving.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return [_Movement(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


class SpikeDecay(Compensator):
    """Spike-and-decay inverse model, eq. (3)/(4); see the module docstring."""

    name = "spike_decay"

    def __init__(self, knots: npt.ArrayLike, c: npt.ArrayLike,
                 eps_range: Sequence[float] | np.ndarray, rates: npt.ArrayLike,
                 strains: npt.ArrayLike, s_table: npt.ArrayLike, lam_table: npt.ArrayLike,
                 min_step: float, normalisation: Normalisation,
                 direction: DirectionSettings) -> None:
        super().__init__(normalisation)
        _check_settings(direction)
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
        self.state = np.zeros(_STATE_LEN)

    def reset(self) -> None:
        """No spike, no movement; the detector restarts."""
        self.state[:] = 0.0

    def f(self, eps: npt.ArrayLike) -> np.ndarray:
        """Quasi-static resistance f(eps) [ohm], eq. (4), for strain eps [%]."""
        eps = np.asarray(eps, dtype=np.float64)
        return np.vectorize(lambda e: f_eval(self.knots, self.c, float(e)))(eps)

    def spike(self, rate: float, eps: float, *, loading: bool = True) -> tuple[float, float]:
        """(S, lambda) from the tables for a movement at ``rate`` [%/s] ending at ``eps`` [%]."""
        k = 0 if loading else 1
        args = (np.log10(self.rates), self.strains, float(rate), float(eps))
        return (float(table_lookup(self.s_table[k], *args)),
                float(table_lookup(self.lam_table[k], *args)))

    def _kernel(self, t: np.ndarray, r: np.ndarray) -> np.ndarray:
        return spike_decay_kernel(self.state, t, r, self.knots, self.c, self.lo, self.hi,
                                  np.log10(self.rates), self.strains, self.s_table,
                                  self.lam_table, self.min_step, self.direction.deadzone,
                                  self.direction.tau)

    def step(self, t: float, r: float) -> float:
        return float(self._kernel(np.array([float(t)]), np.array([float(r)]))[0])

    def run(self, t: npt.ArrayLike, r: npt.ArrayLike) -> np.ndarray:
        t, r = as_float_arrays(t, r)
        return self._kernel(t, r)

    def predict_resistance(self, t: npt.ArrayLike, s: npt.ArrayLike, *,
                           hold_rate: float | None = None) -> np.ndarray:
        """Forward eq. (3) for a known strain history s [%] (the paper's output prediction).

        Movements are found in s as in ``fit``; each one's end is ts, its rate and end strain
        pick (S, lambda); while a new movement is under way the previous spike decays on.
        """
        t, s = as_float_arrays(t, s)
        hold_rate = _default_hold_rate(s) if hold_rate is None else hold_rate
        factor = np.ones(t.size)
        for mv in _movements(t, s, hold_rate):
            change = s[mv.end] - s[mv.start]
            rate = abs(change) / (t[mv.end] - t[mv.start])
            spike, lam = self.spike(rate, s[mv.end], loading=change >= 0)
            after = t >= t[mv.end]
            factor[after] = 1.0 + spike * np.exp(-lam * (t[after] - t[mv.end]))
        return self.f(s) * factor

    def to_params(self) -> dict[str, Any]:
        def rows(a: np.ndarray) -> list[list[float]]:
            return [[float(v) for v in row] for row in a]

        return {"knots": [float(v) for v in self.knots], "c": rows(self.c),
                "range": [self.lo, self.hi], "rates": [float(v) for v in self.rates],
                "strains": [float(v) for v in self.strains],
                "S_loading": rows(self.s_table[0]), "lambda_loading": rows(self.lam_table[0]),
                "S_unloading": rows(self.s_table[1]),
                "lambda_unloading": rows(self.lam_table[1]), "min_step": self.min_step}

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
        rates = require_vector(params, "rates")
        if np.any(rates <= 0.0) or np.any(np.diff(rates) <= 0.0):
            raise ParameterError("rates", "must be > 0 and strictly increasing")
        strains = require_vector(params, "strains")
        if np.any(np.diff(strains) <= 0.0):
            raise ParameterError("strains", "must be strictly increasing")
        shape = (rates.size, strains.size)
        tables = {key: _require_matrix(params, key, shape) for key in
                  ("S_loading", "lambda_loading", "S_unloading", "lambda_unloading")}
        for key in ("S_loading", "S_unloading"):
            if np.any(tables[key] <= -1.0):
                raise ParameterError(key, "every S must be > -1")
        for key in ("lambda_loading", "lambda_unloading"):
            if np.any(tables[key] <= 0.0):
                raise ParameterError(key, "every lambda must be > 0")
        min_step = require_float(params, "min_step", lo=0.0)
        return cls(knots, c, eps_range, rates, strains,
                   [tables["S_loading"], tables["S_unloading"]],
                   [tables["lambda_loading"], tables["lambda_unloading"]], min_step,
                   normalisation, direction)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, **options: Any) -> SpikeDecay:
        """Fit from step-and-hold data; options ``hold_rate`` [%/s], ``min_hold`` [s]."""
        s_all = np.concatenate([seg.s for seg in segments])
        if s_all.size < 10:
            raise FitError(f"spike_decay: needs at least 10 samples, got {s_all.size}")
        span = float(np.ptp(s_all))
        if span <= 0.0:
            raise FitError("spike_decay: the reference strain does not vary")
        hold_rate = float(options.pop("hold_rate", _default_hold_rate(s_all)))
        min_hold = float(options.pop("min_hold", 1.0))
        if options:
            raise ParameterError(next(iter(options)), "unknown spike_decay fit option")
        settled, steps = _analyse_holds(segments, hold_rate, min_hold)
        tol = 0.01 * span
        levels = _cluster(np.array([p[0] for p in settled]), tol) if settled else []
        if len(levels) >= 2:
            eps_pts = np.array([np.mean([settled[i][0] for i in g]) for g in levels])
            r_pts = np.array([np.mean([settled[i][1] for i in g]) for g in levels])
        else:  # no usable holds: quasi-static f from all samples, no spike
            r_all = np.concatenate([seg.r for seg in segments])
            edges = np.linspace(s_all.min(), s_all.max(), _N_BINS + 1)
            idx = np.clip(np.digitize(s_all, edges) - 1, 0, _N_BINS - 1)
            keep = [b for b in range(_N_BINS) if np.sum(idx == b) >= 5]
            if len(keep) < 2:
                raise FitError("spike_decay: too few samples spread over strain to fit f")
            eps_pts = np.array([s_all[idx == b].mean() for b in keep])
            r_pts = np.array([r_all[idx == b].mean() for b in keep])
            steps = []
        knots, c, eps_range = _fit_f(eps_pts, r_pts)
        rates, strains, s_table, lam_table = _tabulate(steps, eps_pts, tol)
        sizes = [st[5] for st in steps]
        min_step = 0.25 * float(np.median(sizes)) if sizes else 0.0
        return cls(knots, c, eps_range, rates, strains, s_table, lam_table, min_step,
                   normalisation, direction)


def _default_hold_rate(s: np.ndarray) -> float:
    return 0.002 * max(float(np.ptp(s)), 1e-12)


def _require_matrix(params: Mapping[str, Any], key: str, shape: tuple[int, int]) -> np.ndarray:
    if key not in params:
        raise ParameterError(key, "missing")
    value = params[key]
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != shape[0]:
        raise ParameterError(key, f"must be a list of {shape[0]} rows")
    rows = [require_vector({f"{key}.{i}": row}, f"{key}.{i}", length=shape[1])
            for i, row in enumerate(value)]
    return np.array(rows, dtype=np.float64).reshape(shape)


def _cluster(values: np.ndarray, tol: float) -> list[list[int]]:
    """Indices grouped so that sorted neighbours closer than ``tol`` share a group."""
    order = np.argsort(values)
    groups: list[list[int]] = []
    for i in order:
        if groups and values[i] - values[groups[-1][-1]] <= tol:
            groups[-1].append(int(i))
        else:
            groups.append([int(i)])
    return groups


def _analyse_holds(segments: Sequence[Segment], hold_rate: float, min_hold: float
                   ) -> tuple[list[tuple[float, float]], list[tuple[float, ...]]]:
    """Settled (strain, R_inf) per hold; (rate, strain, direction, S, lambda, |step|) per step."""
    settled: list[tuple[float, float]] = []
    steps: list[tuple[float, ...]] = []
    for seg in segments:
        t, r, s = seg.t, seg.r, seg.s
        moves = _movements(t, s, hold_rate)
        bounds: list[tuple[int, int, _Movement | None]] = [
            (0, moves[0].start if moves else t.size - 1, None)]
        for k, mv in enumerate(moves):
            nxt = moves[k + 1].start if k + 1 < len(moves) else t.size - 1
            bounds.append((mv.end, nxt, mv))
        for a, b, mv in bounds:
            if b - a < 10 or t[b] - t[a] < min_hold:
                continue
            th, rh = t[a:b + 1] - t[a], r[a:b + 1]
            level = float(np.mean(s[a:b + 1]))
            tail = rh[th >= 0.8 * th[-1]]
            r_inf = float(np.median(tail))
            if mv is not None:
                fitted = _fit_decay(th, rh, r_inf)
                if fitted is not None:
                    r_inf, spike, lam, clear = fitted
                    change = s[mv.end] - s[mv.start]
                    rate = abs(change) / (t[mv.end] - t[mv.start])
                    steps.append((rate, level, 0 if change >= 0 else 1, spike,
                                  lam if clear else math.nan, abs(change)))
            settled.append((level, r_inf))
    return settled, steps


def _fit_decay(th: np.ndarray, rh: np.ndarray, r_inf: float
               ) -> tuple[float, float, float, bool] | None:
    """Least squares R = R_inf (1 + S exp(-lambda t)) on one hold; None if it fails."""
    duration = float(th[-1])
    dt = float(np.median(np.diff(th)))
    lam_lo, lam_hi = 0.2 / duration, 1.0 / dt
    s0 = float(rh[0] / r_inf - 1.0)

    def res(z: np.ndarray) -> np.ndarray:
        return z[0] * (1.0 + z[1] * np.exp(-np.exp(z[2]) * th)) - rh

    z0 = np.array([r_inf, s0, math.log(min(max(5.0 / duration, lam_lo * 1.01), lam_hi * 0.99))])
    try:
        sol = least_squares(res, z0, x_scale=np.array([abs(r_inf) + 1e-12, 0.1, 1.0]),
                            bounds=([-np.inf, -0.99, math.log(lam_lo)],
                                    [np.inf, 100.0, math.log(lam_hi)]))
    except ValueError:
        return None
    if not (sol.success and np.all(np.isfinite(sol.x))):
        return None
    noise = float(np.std(sol.fun))
    clear = abs(sol.x[0] * sol.x[1]) > 5.0 * noise
    return float(sol.x[0]), float(sol.x[1]), float(np.exp(sol.x[2])), bool(clear)


def _fit_f(eps_pts: np.ndarray, r_pts: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """PCHIP through the settled points in Table 2 form, and its longest monotone run."""
    order = np.argsort(eps_pts)
    x, y = eps_pts[order], r_pts[order]
    pchip = PchipInterpolator(x, y)
    knots = pchip.x[:-1]
    c = pchip.c[::-1].T.copy()  # rows [c0, c1, c2, c3] on (eps - knot)
    sign = np.sign(np.diff(y))
    best: tuple[int, int] | None = None
    start = 0
    for i in range(1, sign.size + 1):
        if i == sign.size or sign[i] != sign[start]:
            if sign[start] != 0 and (best is None
                                     or x[i] - x[start] > x[best[1]] - x[best[0]]):
                best = (start, i)
            start = i
    if best is None:
        raise FitError("spike_decay: the settled resistance does not change with strain")
    return knots, c, (float(x[best[0]]), float(x[best[1]]))


def _tabulate(steps: list[tuple[float, ...]], levels: np.ndarray,
              tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """S and lambda tables over (rate x strain) from the fitted steps; gaps filled.

    Steps whose measured rate is not > 0 (a step too small or too fast to time) have no
    place on the log-rate axis and are left out.
    """
    steps = [st for st in steps if st[0] > 0.0]
    if not steps:
        return (np.array([1.0]), np.array([float(np.mean(levels))]), np.zeros((2, 1, 1)),
                np.ones((2, 1, 1)))
    rate = np.array([st[0] for st in steps])
    level = np.array([st[1] for st in steps])
    rate_groups = _cluster(np.log10(rate), math.log10(1.5))
    rates = np.array([10 ** np.mean(np.log10(rate[g])) for g in rate_groups])
    strain_groups = _cluster(level, tol)
    strains = np.array([np.mean(level[g]) for g in strain_groups])
    rate_index = np.empty(rate.size, int)
    for gi, g in enumerate(rate_groups):
        rate_index[g] = gi
    strain_index = np.empty(rate.size, int)
    for gi, g in enumerate(strain_groups):
        strain_index[g] = gi
    tables = []
    for column in (3, 4):
        value = np.array([st[column] for st in steps])
        table = np.full((2, rates.size, strains.size), np.nan)
        for k in range(2):
            for i in range(rates.size):
                for j in range(strains.size):
                    cell = ((rate_index == i) & (strain_index == j) & np.isfinite(value)
                            & (np.array([st[2] for st in steps]) == k))
                    if cell.any():
                        table[k, i, j] = value[cell].mean()
        tables.append(table)
    s_table, lam_table = tables
    for table, default in ((s_table, 0.0), (lam_table, 1.0)):
        for k in range(2):
            if np.isnan(table[k]).all():
                table[k] = table[1 - k]
        if np.isnan(table).all():
            table[:] = default
        for k in range(2):
            _fill(table[k])
    return rates, strains, s_table, lam_table


def _fill(table: np.ndarray) -> None:
    """Fill NaN cells in place with the mean of their filled 4-neighbours, repeatedly."""
    while np.isnan(table).any():
        filled = table.copy()
        for i, j in zip(*np.nonzero(np.isnan(table)), strict=True):
            near = [table[a, b] for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))
                    if 0 <= a < table.shape[0] and 0 <= b < table.shape[1]
                    and not np.isnan(table[a, b])]
            if near:
                filled[i, j] = float(np.mean(near))
        table[:] = filled


def recalibrate_two_point(model: SpikeDecay, point_a: tuple[float, float],
                          point_b: tuple[float, float]) -> SpikeDecay:
    """A copy of ``model`` with f scaled and shifted (a f + b) through two (strain %, R ohm).

    The paper's calibration of a new sensor of the same make: S and lambda tables and the
    monotone range are kept. Give settled resistances (a reading taken during a spike
    should first be divided by 1 + S, as the paper does).
    """
    (eps_a, r_a), (eps_b, r_b) = point_a, point_b
    f_a, f_b = (f_eval(model.knots, model.c, float(e)) for e in (eps_a, eps_b))
    if f_a == f_b:
        raise ParameterError("point_b", "the two strains give one resistance on f; use two "
                             "different strains in the monotone range")
    a = (r_b - r_a) / (f_b - f_a)
    b = r_a - a * f_a
    if not (np.isfinite(a) and a != 0.0):
        raise ParameterError("point_b", "the two resistances must differ")
    c = model.c * a
    c[:, 0] += b
    return SpikeDecay(model.knots, c, (model.lo, model.hi), model.rates, model.strains,
                      model.s_table, model.lam_table, model.min_step, model.normalisation,
                      model.direction)
