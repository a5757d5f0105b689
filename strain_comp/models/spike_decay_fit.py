"""The fit of the spike-and-decay model ([Nanocomposite] eq. (3), (4), Tables 2, 4, 5) from
step-and-hold data: each hold's decay, the quasi-static curve through the settled points and
the (rate x strain) tables; docs/models.md gives the method."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import least_squares

from strain_comp.base.compensator import Segment
from strain_comp.errors import FitError

_N_BINS = 40  # strain bins of the quasi-static fit without holds


def movements(t: np.ndarray, s: np.ndarray, hold_rate: float) -> list[tuple[int, int]]:
    """(start, end) sample indices of the maximal runs of intervals where |ds/dt| > hold_rate."""
    if t.size < 2:
        return []
    moving = np.abs(np.diff(s) / np.diff(t)) > hold_rate
    edges = np.diff(np.concatenate([[0], moving.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def default_hold_rate(s: np.ndarray) -> float:
    """The default ``hold_rate`` for the reference ``s``: 0.2 % of its span per second."""
    return 0.002 * max(float(np.ptp(s)), 1e-12)


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


def analyse_holds(segments: Sequence[Segment], hold_rate: float, min_hold: float
                   ) -> tuple[list[tuple[float, float]], list[tuple[float, ...]]]:
    """The holds between movements and the steps into them."""
    settled: list[tuple[float, float]] = []
    steps: list[tuple[float, ...]] = []
    for seg in segments:
        t, r, s = seg.t, seg.r, seg.s
        moves = movements(t, s, hold_rate)
        bounds: list[tuple[int, int, tuple[int, int] | None]] = [
            (0, moves[0][0] if moves else t.size - 1, None)]
        for k, mv in enumerate(moves):
            nxt = moves[k + 1][0] if k + 1 < len(moves) else t.size - 1
            bounds.append((mv[1], nxt, mv))
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
                    change = s[mv[1]] - s[mv[0]]
                    rate = abs(change) / (t[mv[1]] - t[mv[0]])
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
        return np.asarray(z[0] * (1.0 + z[1] * np.exp(-np.exp(z[2]) * th)) - rh)

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


def fit_f(eps_pts: np.ndarray, r_pts: np.ndarray
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


def tabulate(steps: list[tuple[float, ...]], levels: np.ndarray,
              tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """S and lambda tables over (rate x strain) from the fitted steps; gaps filled."""
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
    kind = np.array([st[2] for st in steps])
    tables = []
    for column in (3, 4):
        value = np.array([st[column] for st in steps])
        table = np.full((2, rates.size, strains.size), np.nan)
        for k, i, j in np.ndindex(table.shape):
            cell = (rate_index == i) & (strain_index == j) & np.isfinite(value) & (kind == k)
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


def settled_points(segments: Sequence[Segment], settled: list[tuple[float, float]],
                   steps: list[tuple[float, ...]], tol: float
                   ) -> tuple[np.ndarray, np.ndarray, list[tuple[float, ...]]]:
    """Points f passes through, steps of the tables (docs/models.md, "spike_decay")."""
    levels = _cluster(np.array([p[0] for p in settled]), tol) if settled else []
    if len(levels) >= 2:
        eps_pts = np.array([np.mean([settled[i][0] for i in g]) for g in levels])
        r_pts = np.array([np.mean([settled[i][1] for i in g]) for g in levels])
        return eps_pts, r_pts, steps
    s_all = np.concatenate([seg.s for seg in segments])
    r_all = np.concatenate([seg.r for seg in segments])
    edges = np.linspace(s_all.min(), s_all.max(), _N_BINS + 1)
    idx = np.clip(np.digitize(s_all, edges) - 1, 0, _N_BINS - 1)
    keep = [b for b in range(_N_BINS) if np.sum(idx == b) >= 5]
    if len(keep) < 2:
        raise FitError("spike_decay: too few samples spread over strain to fit f")
    eps_pts = np.array([s_all[idx == b].mean() for b in keep])
    r_pts = np.array([r_all[idx == b].mean() for b in keep])
    return eps_pts, r_pts, []
