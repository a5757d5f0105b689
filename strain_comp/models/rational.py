"""Rational rat22 model ([EGaIn] eq. (10)) on xi = R / r0 + alpha, combined or split by
direction (section V.E); the fit and its pole guard: docs/models.md.
"""

from __future__ import annotations

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
    require_vector,
)
from strain_comp.base.direction import (
    STATE_SIZE,
    DirectionDetector,
    DirectionSettings,
    direction_update,
)
from strain_comp.base.registry import register
from strain_comp.errors import FitError, ParameterError

MODES = ("combined", "split")
_BRANCHES = ("combined", "loading", "unloading")
_GUARD_MARGIN = 0.05


@njit
def rational_kernel(state: np.ndarray, t: np.ndarray, xi: np.ndarray, coef: np.ndarray,
                    split: bool, deadzone: float, tau: float) -> np.ndarray:
    """S for each sample, through the combined or the direction's branch."""
    out = np.empty(t.size)
    active = STATE_SIZE
    for n in range(t.size):
        x = xi[n]
        row = 0
        if split:
            d = direction_update(state, t[n], x, deadzone, tau)
            if d > 0:
                state[active] = 1.0
            elif d < 0:
                state[active] = 2.0
            row = int(state[active])
        num = (coef[row, 0] * x + coef[row, 1]) * x + coef[row, 2]
        den = (x + coef[row, 3]) * x + coef[row, 4]
        out[n] = num / den if den != 0.0 else np.nan  # on a pole: no strain, screened
    return out


def _branches(states: np.ndarray) -> np.ndarray:
    """Coefficient row the split model uses per sample: last moving direction, 0 before any."""
    row = np.where(states > 0, 1, np.where(states < 0, 2, 0))
    index = np.maximum.accumulate(np.where(row > 0, np.arange(row.size), -1))
    return np.where(index >= 0, row[np.maximum(index, 0)], 0)


def _poles_in(q: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The real roots of x^2 + q[0] x + q[1] in [lo, hi], in ascending order."""
    disc = q[0] * q[0] - 4.0 * q[1]
    if disc < 0.0:
        return np.empty(0)
    root = np.sqrt(disc)
    poles = np.array([(-q[0] - root) / 2.0, (-q[0] + root) / 2.0])
    return poles[(poles >= lo) & (poles <= hi)]


def _eval(coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.asarray(((coef[0] * x + coef[1]) * x + coef[2]) / ((x + coef[3]) * x + coef[4]))


def _jac(coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    """d _eval / d [p1, p2, p3, q1, q2] (n, 5): x^2/D, x/D, 1/D, -N x/D^2, -N/D^2."""
    inv_d = 1.0 / ((x + coef[3]) * x + coef[4])
    f = ((coef[0] * x + coef[1]) * x + coef[2]) * inv_d
    jac = np.empty((x.size, 5))
    jac[:, 2] = inv_d
    jac[:, 1] = x * inv_d
    jac[:, 0] = x * jac[:, 1]
    jac[:, 4] = -f * inv_d
    jac[:, 3] = x * jac[:, 4]
    return jac


def _free(z: np.ndarray) -> np.ndarray:
    """[p1, p2, p3, q1, q2] of the pole-free form den = (xi - c)^2 + d^2, z = [p, c, log d]."""
    return np.array([z[0], z[1], z[2], -2.0 * z[3], z[3] * z[3] + np.exp(2.0 * z[4])])


def _jac_free(z: np.ndarray, x: np.ndarray) -> np.ndarray:
    """d _eval(_free(z)) / d z by the chain rule through ``_free``."""
    jac = _jac(_free(z), x)
    dq2 = jac[:, 4]
    out = np.empty_like(jac)
    out[:, :3] = jac[:, :3]
    out[:, 3] = -2.0 * jac[:, 3] + 2.0 * z[3] * dq2
    out[:, 4] = 2.0 * np.exp(2.0 * z[4]) * dq2
    return out


def fit_rat22(xi: np.ndarray, s: np.ndarray, *, guard: tuple[float, float],
              what: str = "rational") -> np.ndarray:
    """The best pole-free rat22 fit of s(xi) (docs/models.md)."""
    if np.ptp(xi) <= 0.0:
        raise FitError(f"{what}: the resistance does not vary")
    lo, hi = guard
    a = np.column_stack([xi * xi, xi, np.ones_like(xi), -s * xi, -s])
    lin, *_ = np.linalg.lstsq(a, s * xi * xi, rcond=None)
    candidates = []
    with np.errstate(all="ignore"):
        if not _poles_in(lin[3:], lo, hi).size:
            sol = least_squares(lambda c: _eval(c, xi) - s, lin, jac=lambda c: _jac(c, xi),
                                method="lm")
            for coef in (sol.x, lin):
                if not _poles_in(coef[3:], lo, hi).size and np.all(np.isfinite(coef)):
                    candidates.append(coef)
                    break
        # pole-free form: den = (xi - c)^2 + d^2, d = exp(log_d)
        c0 = -lin[3] / 2.0 if np.isfinite(lin[3]) else 0.0
        d2 = lin[4] - c0 * c0 if np.isfinite(lin[4]) else 1.0
        span = max(hi - lo, 1e-12)
        log_d0 = 0.5 * np.log(d2) if d2 > 1e-6 * span**2 else np.log(2.0 * span)
        c0 = float(np.clip(c0, lo - 10 * span, hi + 10 * span))

        den0 = (xi - c0) ** 2 + np.exp(2.0 * log_d0)
        pz, *_ = np.linalg.lstsq(np.column_stack([xi * xi, xi, np.ones_like(xi)]), s * den0,
                                 rcond=None)
        z0 = np.concatenate([pz, [c0, log_d0]])
        sol = least_squares(lambda z: _eval(_free(z), xi) - s, z0,
                            jac=lambda z: _jac_free(z, xi), method="trf")
        coef = _free(sol.x)
        if np.all(np.isfinite(coef)):
            candidates.append(coef)
    if not candidates:
        raise FitError(f"{what}: no pole-free rat22 fit found")
    costs = [float(np.sum((_eval(c, xi) - s) ** 2)) for c in candidates]
    return np.asarray(candidates[int(np.argmin(costs))], dtype=np.float64)


@register
class Rational(Compensator):
    """rat22 compensator, combined or split by direction."""

    name = "rational"

    def __init__(self, coef: Mapping[str, npt.ArrayLike], mode: str,
                 normalisation: Normalisation, direction: DirectionSettings) -> None:
        super().__init__(normalisation)
        self.mode = mode  # checked by the reader (from_params) and the fit's options
        self.direction = direction
        rows = [coef["combined"]] * 3 if mode == "combined" else [coef[b] for b in _BRANCHES]
        self.coef = np.ascontiguousarray(np.array(rows, dtype=np.float64).reshape(3, 5))
        self.state = np.zeros(STATE_SIZE + 1)

    def reset(self) -> None:
        """Detector restarts; the combined fit is used until the first movement."""
        self.state[:] = 0.0

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        out[:] = rational_kernel(self.state, t, self.normalisation.xi(r), self.coef,
                                 self.mode == "split",
                                 self.direction.deadzone / self.normalisation.r0,
                                 self.direction.tau)

    def singular_in(self, r_lo: float, r_hi: float) -> float | None:
        """The first resistance in [r_lo, r_hi] where a branch has a real pole, or None."""
        lo, hi = self.normalisation.xi(np.array([r_lo, r_hi]))
        for row in self.coef:
            inside = _poles_in(row[3:], min(lo, hi), max(lo, hi))
            if inside.size:
                return float((inside[0] - self.normalisation.alpha) * self.normalisation.r0)
        return None

    def to_params(self) -> dict[str, Any]:
        params: dict[str, Any] = {"mode": self.mode}
        branches = _BRANCHES if self.mode == "split" else ("combined",)
        for i, branch in enumerate(branches):
            params[branch] = {"p": self.coef[i, :3].tolist(), "q": self.coef[i, 3:].tolist()}
        return params

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> Rational:
        mode = params.get("mode", "combined")
        if mode not in MODES:
            raise ParameterError("mode", f"must be one of {', '.join(MODES)}, got {mode!r}")
        coef = {}
        for branch in _BRANCHES if mode == "split" else ("combined",):
            node = params.get(branch)
            if not isinstance(node, Mapping):
                raise ParameterError(branch, "missing or not a mapping with p and q")
            try:
                p = require_vector(node, "p", length=3)
                q = require_vector(node, "q", length=2)
            except ParameterError as err:
                raise ParameterError(f"{branch}.{err.field}", err.problem) from None
            coef[branch] = np.concatenate([p, q])
        return cls(coef, mode, normalisation, direction)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, mode: str = "combined", **options: Any
            ) -> Rational:
        """``mode``: combined or split."""
        xi = np.concatenate([normalisation.xi(seg.r) for seg in segments])
        s = np.concatenate([seg.s for seg in segments])
        if xi.size < 5:
            raise FitError(f"rational: needs at least 5 samples, got {xi.size}")
        span = float(np.ptp(xi))
        guard = (float(xi.min()) - _GUARD_MARGIN * span, float(xi.max()) + _GUARD_MARGIN * span)
        coef = {"combined": fit_rat22(xi, s, guard=guard)}
        if mode == "split":
            # label with the model's own online branch choice (detector on xi, as in the kernel)
            scaled = DirectionSettings(direction.deadzone / normalisation.r0, direction.tau)
            labels = [_branches(DirectionDetector(scaled).run(seg.t, normalisation.xi(seg.r)))
                      for seg in segments]
            label = np.concatenate(labels)
            for index, name in ((1, "loading"), (2, "unloading")):
                mask = label == index
                if mask.sum() < 20:
                    raise FitError(f"rational split: only {int(mask.sum())} {name} samples "
                                   "(R {}) after direction detection; record both directions "
                                   "or check the dead zone".format(
                                       "rising" if index == 1 else "falling"))
                coef[name] = fit_rat22(xi[mask], s[mask], guard=guard, what=f"rational {name}")
        return cls(coef, mode, normalisation, direction)
