"""creep_pi: play operators and Prony-series creep states, linear in its weights
([Electrolycra] eq. (4), appendix eq. (6) with sigma = 0; [Nanocomposite] Equation (3));
the model and its cross-validated ridge fit: docs/design.md, "creep_pi".
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.compensator import (
    Compensator,
    Normalisation,
    Segment,
    require_float,
    require_vector,
)
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.lift import LiftedArray, lift
from strain_comp.base.registry import register, register_array
from strain_comp.errors import FitError, ParameterError
from strain_comp.models import creep_kernels as kern

TAUS = (0.3, 3.0, 30.0, 300.0)  # default time constants [s] of the creep states
N_PLAY = 8
DIRECTION_WIDTH = 0.05  # of the direction play operator, normalised (2.5 % of the span)
TAU_RANGE = (1e-3, 1e6)  # time constants [s] a calibration may hold
N_TAU_MAX = 12
N_PLAY_MAX = 50
WIDTH_MAX = 100.0  # largest play threshold, normalised (the training range spans 2)
SCALE_MIN = 1e-12
LAM_MAX = 1e6
LAM_GRID = np.geomspace(1e-9, 1e1, 41)  # per sample, on standardised features
CV_BLOCKS = 4  # contiguous folds of a single training segment
CHUNK = 1 << 16  # samples whose features are held at once during a fit
FLAT = 1e-9  # a feature whose training standard deviation is below this gets scale 1


def n_features(n_play: int, n_tau: int) -> int:
    return kern.N_FIXED + n_play + n_tau


def play_thresholds(n_play: int) -> np.ndarray:
    """r_j = j / (J + 1), j = 1..J ([Electrolycra] eq. (6))."""
    return np.arange(1, n_play + 1, dtype=np.float64) / (n_play + 1)


@register
class CreepPI(Compensator):
    """Play operators + Prony creep states + cubic + direction terms, linear in ``weights``."""

    name = "creep_pi"
    param_names = ("taus", "thresholds", "direction_width", "mean", "scale", "weights",
                   "intercept", "penalty")
    fit_full_rate = True

    def __init__(self, *, taus: npt.ArrayLike, thresholds: npt.ArrayLike,
                 direction_width: float, mean: npt.ArrayLike, scale: npt.ArrayLike,
                 weights: npt.ArrayLike, intercept: float, penalty: float,
                 normalisation: Normalisation) -> None:
        super().__init__(normalisation)
        self.taus = np.ascontiguousarray(taus, dtype=np.float64)
        self.thresholds = np.ascontiguousarray(thresholds, dtype=np.float64)
        self.direction_width = float(direction_width)
        self.mean = np.ascontiguousarray(mean, dtype=np.float64)
        self.scale = np.ascontiguousarray(scale, dtype=np.float64)
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        self.intercept = float(intercept)
        self.penalty = float(penalty)
        # The standardisation folded into the weights of the raw features.
        w = self.weights / self.scale
        self._bias = float(self.intercept - np.dot(w, self.mean))
        self._coef = kern.folded(w, self.thresholds.size, self.taus.size)
        if not (np.all(np.isfinite(self._coef)) and math.isfinite(self._bias)):
            raise ParameterError("weights", "weights / scale overflow")
        self._widths = np.append(self.thresholds, self.direction_width)
        self._norm = np.array([normalisation.r0, normalisation.alpha, normalisation.s0,
                               normalisation.beta])
        self.z = np.zeros(self.taus.size)
        self.play = np.zeros(self._widths.size)
        self._clock = np.zeros(3)
        self._decay = np.zeros(self.taus.size)
        self.reset()

    def reset(self) -> None:
        """Forget the state: the next good sample starts it at rest at its input."""
        self.z[:] = 0.0
        self.play[:] = 0.0
        self._clock[:] = (0.0, 0.0, -1.0)

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        kern.run_kernel(t, r, self.z, self.play, self._clock, self._decay, out, self._norm,
                        self.taus, self._widths, self._coef, self._bias)

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> CreepPI:
        taus = require_vector(params, "taus", lo=TAU_RANGE[0], hi=TAU_RANGE[1])
        thresholds = require_vector(params, "thresholds", lo=0.0, strict=True)
        width = require_float(params, "direction_width", lo=0.0, strict=True)
        for key, values, most in (("taus", taus, N_TAU_MAX), ("thresholds", thresholds,
                                                                N_PLAY_MAX)):
            if values.size > most:
                raise ParameterError(key, f"must hold 1 to {most} numbers, got {values.size}")
        for key, value in (("thresholds", thresholds.max()), ("direction_width", width)):
            if value > WIDTH_MAX:
                raise ParameterError(key, f"must be <= {WIDTH_MAX:g}, got {value:g}")
        n_f = n_features(thresholds.size, taus.size)
        return cls(taus=taus, thresholds=thresholds, direction_width=width,
                   mean=require_vector(params, "mean", length=n_f),
                   scale=require_vector(params, "scale", length=n_f, lo=SCALE_MIN),
                   weights=require_vector(params, "weights", length=n_f),
                   intercept=require_float(params, "intercept"),
                   penalty=require_float(params, "penalty", lo=0.0),
                   normalisation=normalisation)

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, taus: Sequence[float] = TAUS, n_play: int = N_PLAY,
            lam: float | None = None, **options: Any) -> CreepPI:
        """Ridge fit of the weights (docs/design.md, "creep_pi")."""
        tau = np.asarray(taus, dtype=np.float64)
        thresholds = play_thresholds(n_play)
        grams = fold_grams(segments, normalisation, tau, thresholds)
        n_f = n_features(n_play, tau.size)
        total = grams.sum(axis=0)
        n = total[0, 0]
        if n < n_f + 2:
            raise FitError(f"{cls.name}: needs at least {n_f + 2} samples, got {int(n)}")
        mean = total[0, 1:n_f + 1] / n
        var = np.diag(total)[1:n_f + 1] / n - mean ** 2
        scale = np.sqrt(np.maximum(var, 0.0))
        scale[scale < FLAT] = 1.0
        # [1, f, y] -> [1, (f - mean) / scale, y]
        to_std = np.eye(n_f + 2)
        to_std[0, 1:n_f + 1] = -mean / scale
        to_std[1:n_f + 1, 1:n_f + 1] = np.diag(1.0 / scale)
        grams = np.einsum("ji,fjk,kl->fil", to_std, grams, to_std)
        total = grams.sum(axis=0)
        report: dict[str, Any] = {"folds": int(grams.shape[0])}
        if lam is None:  # two or more folds: n >= 9 samples split into n // 4 blocks
            errors = cross_validate(grams, LAM_GRID) / grams[:, 0, 0]
            cv = np.median(errors, axis=1) if len(segments) == 1 else errors.mean(axis=1)
            best = int(np.argmin(cv))
            lam = float(LAM_GRID[best])
            report.update(cv_rmse=float(normalisation.s0 * math.sqrt(cv[best])),
                          at_grid_edge=best in (0, LAM_GRID.size - 1))
        theta = ridge(total, float(lam))
        model = cls(taus=tau, thresholds=thresholds, direction_width=DIRECTION_WIDTH,
                    mean=mean, scale=scale, weights=theta[1:n_f + 1], intercept=theta[0],
                    penalty=float(lam), normalisation=normalisation)
        model.fit_report = {"penalty": float(lam), **report}
        return model


@register_array
@lift(kern.step_sensor, fastmath=kern.FASTMATH)
class CreepPIArray(LiftedArray):
    """K creep_pi sensors (same shapes) stepped together in one kernel call."""

    model_type = CreepPI

    @staticmethod
    def rows(model: CreepPI) -> tuple[tuple[np.ndarray, ...], tuple[Any, ...]]:
        return ((model.z, model.play, model._clock, model._decay),
                (model._norm, model.taus, model._widths, model._coef, model._bias))


def fold_grams(segments: Sequence[Segment], normalisation: Normalisation, tau: np.ndarray,
               thresholds: np.ndarray) -> np.ndarray:
    """Gram matrices of [1, features, psi] per fold: a segment each, or CV_BLOCKS of one."""
    widths = np.append(thresholds, DIRECTION_WIDTH)
    n_f = n_features(thresholds.size, tau.size)
    single = len(segments) == 1
    n_folds = (min(CV_BLOCKS, segments[0].t.size // CV_BLOCKS) or 1) if single else len(segments)
    grams = np.zeros((n_folds, n_f + 2, n_f + 2))
    rows = np.empty((min(CHUNK, max(seg.t.size for seg in segments)), n_f + 2))
    rows[:, 0] = 1.0
    for s, seg in enumerate(segments):
        xi = normalisation.xi(seg.r)
        psi = normalisation.psi(seg.s)
        z, play = np.zeros(tau.size), np.zeros(widths.size)
        clock, decay = np.array([0.0, 0.0, -1.0]), np.zeros(tau.size)
        size = seg.t.size
        fold = (np.arange(size) * n_folds // size if single else np.full(size, s))
        for lo in range(0, size, CHUNK):
            hi = min(lo + CHUNK, size)
            block = rows[:hi - lo]
            kern.features_kernel(seg.t[lo:hi], xi[lo:hi], z, play, clock, decay, tau, widths,
                                 block[:, 1:n_f + 1])
            block[:, n_f + 1] = psi[lo:hi]
            for f in np.unique(fold[lo:hi]):
                part = block[fold[lo:hi] == f]
                grams[f] += part.T @ part
    return grams


def ridge(gram: np.ndarray, lam: float) -> np.ndarray:
    """theta = [intercept, weights, -1] of the ridge fit (residuals a . theta) on ``gram``."""
    p = gram.shape[0] - 2
    n = gram[0, 0]
    mx = gram[0, 1:p + 1] / n
    my = gram[0, p + 1] / n
    cxx = gram[1:p + 1, 1:p + 1] - n * np.outer(mx, mx)
    cxy = gram[1:p + 1, p + 1] - n * mx * my
    a = cxx + (lam * n + 1e-12 * max(np.trace(cxx), 1e-300) / p) * np.eye(p)
    w = np.linalg.solve(a, cxy)
    return np.concatenate([[my - mx @ w], w, [-1.0]])


def cross_validate(grams: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """Held-out squared error per penalty and fold, each fold predicted by the others' fit."""
    total = grams.sum(axis=0)
    errors = np.zeros((lams.size, grams.shape[0]))
    for i, lam in enumerate(lams):
        for f, gram in enumerate(grams):
            theta = ridge(total - gram, float(lam))
            errors[i, f] = max(float(theta @ gram @ theta), 0.0)
    return errors
