"""Sparse references fused online into the output gain and offset by a Kalman filter
(docs/models.md, "Fusion of known strains", equations (1)-(3))."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from strain_comp.base.samples import used_mask
from strain_comp.core.correction import Correction
from strain_comp.core.range_policy import fitted_rest
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.core.calibration import SensorCalibration
    from strain_comp.core.outputs import BatchOutput


# The fusion's numbers, in shares of the calibrated strain span where a strain is meant.
# docs/results.md gives what keeps each: the largest change of a benchmark case with the
# number set neutral.
GAIN_SD = 0.3  # prior sd of the gain around 1: 30 % off is plausible (0: a case 15 %)
OFFSET_SHARE = 0.05  # prior sd of the offset around 0 (0: a case 6 %)
GAIN_WALK = 0.02  # gain random walk [1/sqrt(s)]: 0.15 in a minute (0: a case 40 %)
OFFSET_WALK_SHARE = 0.2 / 60.0  # offset random walk [span/sqrt(s)]: 2.6 % a minute (0: 5 %)
NOISE_SHARE = 0.1  # sd of what a gain and offset do not explain (0.001: a case 75 %)
GATE = 5.0  # a reference beyond this many innovation sds is refused (inf: a case 45 %)


@dataclass
class OutputFusion:
    """The Kalman filter (3) on one sensor's output gain and offset."""

    span: float
    """The calibrated strain span the prior, walk and noise are shares of."""
    start: tuple[float, float] = (1.0, 0.0)
    """The calibration's output gain and offset the filter starts from (a_0, b_0)."""
    gain: float = field(init=False)
    offset: float = field(init=False)
    covariance: np.ndarray = field(init=False)
    n_used: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    last_reference_t: float | None = None
    """Time of the latest reference used or refused for its value [s]."""

    def __post_init__(self) -> None:
        self.gain, self.offset = self.start
        prior = np.diag([GAIN_SD ** 2, (OFFSET_SHARE * self.span) ** 2])
        self.covariance = self._coordinates(prior)

    def _coordinates(self, p: np.ndarray) -> np.ndarray:
        """A covariance of the map relative to ``start`` in the filter's coordinates."""
        a0, b0 = self.start
        tr = np.array([[a0, 0.0], [b0, 1.0]])
        out: np.ndarray = tr @ p @ tr.T
        return out

    @classmethod
    def for_calibration(cls, cal: SensorCalibration) -> OutputFusion:
        """A sensor's fusion at its calibrated span, from its correction's output map."""
        correction = Correction.of(cal)
        span = fitted_rest(cal.valid_range)[1]
        return cls(span if math.isfinite(span) and span > 0 else 1.0,
                   (correction.output_gain, correction.output_offset))

    def relative(self) -> tuple[float, float]:
        """(g, b) of the fused map on the engine's estimate (through ``start``)."""
        a0, b0 = self.start
        g = self.gain / a0
        return g, self.offset - g * b0

    @property
    def n_refused(self) -> int:
        return sum(self.refused.values())

    def apply(self, estimate: Any) -> Any:
        """The fused strain g s_hat + b of an estimate of the engine (a float or an array)."""
        g, b = self.relative()
        return g * estimate + b

    def update(self, t: float, estimate: float, reference: Any) -> str | None:
        """Fuse ``reference`` at ``t`` [s]; None when used, else why it was refused."""
        reason = self._screen(t, estimate, reference)
        if reason is not None:
            self.refused[reason] += 1
            return reason
        dt = 0.0 if self.last_reference_t is None else t - self.last_reference_t
        walk = np.diag([GAIN_WALK ** 2, (OFFSET_WALK_SHARE * self.span) ** 2])
        p = self.covariance + self._coordinates(walk) * dt
        a0, b0 = self.start
        estimate = (estimate - b0) / a0  # before the calibration's output map
        h = np.array([estimate, 1.0])
        innovation = float(reference) - (self.gain * estimate + self.offset)
        var = float(h @ p @ h) + (NOISE_SHARE * self.span) ** 2
        self.last_reference_t = t
        if abs(innovation) > GATE * math.sqrt(var):
            reason = (f"beyond the gate ({GATE:g} sd): innovation {innovation:.4g} against "
                      f"sd {math.sqrt(var):.4g}")
            self.refused["beyond the gate"] += 1
            self.covariance = p  # the time still passed
            return reason
        k = p @ h / var
        self.gain += float(k[0]) * innovation
        self.offset += float(k[1]) * innovation
        self.covariance = p - np.outer(k, h @ p)
        self.covariance = 0.5 * (self.covariance + self.covariance.T)
        self.n_used += 1
        return None

    def refuse(self, reason: str) -> str:
        """Count a reference refused before it reached ``update``; the reason."""
        self.refused[reason] += 1
        return reason

    def _screen(self, t: float, estimate: float, reference: Any) -> str | None:
        if isinstance(reference, bool) or not isinstance(reference, (int, float, np.floating,
                                                                     np.integer)):
            return "not a number"
        if not math.isfinite(float(reference)):
            return "non-finite reference"
        if not math.isfinite(estimate):
            return "no estimate yet"
        if not math.isfinite(t):
            return "non-finite time"
        if self.last_reference_t is not None and t < self.last_reference_t:
            return "time before the previous reference"
        return None

    def state(self) -> dict[str, Any]:
        """What /diagnostics and the JSON show of the filter."""
        return {"gain": self.gain, "offset": self.offset,
                "gain_sd": math.sqrt(max(float(self.covariance[0, 0]), 0.0)),
                "offset_sd": math.sqrt(max(float(self.covariance[1, 1]), 0.0)),
                "gain_offset_cov": float(self.covariance[0, 1]),
                "n_used": self.n_used, "n_refused": self.n_refused,
                "refused": dict(self.refused),
                "last_reference_t": (math.nan if self.last_reference_t is None
                                     else self.last_reference_t)}

    def diagnostic_values(self) -> dict[str, str]:
        """``state`` as /diagnostics key-values (``fusion_*``)."""
        st = self.state()
        values = {f"fusion_{k}": f"{st[k]:.6g}" for k in ("gain", "offset", "gain_sd",
                                                          "offset_sd", "gain_offset_cov")}
        values["fusion_n_used"] = str(self.n_used)
        values["fusion_n_refused"] = str(self.n_refused)
        values["fusion_last_reference_t"] = ("none" if self.last_reference_t is None
                                             else repr(self.last_reference_t))
        values.update({f"fusion_refused[{k}]": str(v) for k, v in sorted(self.refused.items())})
        return values


@dataclass
class SparseFusion:
    """One sensor's run in pieces, fused with a reference near each multiple of ``every`` s."""

    fusion: OutputFusion
    every: float
    origin: float | None = None
    k: int = 1
    """The next multiple of ``every`` waiting for its reference."""
    before: tuple[float, float, float] | None = None
    """The latest eligible sample of earlier pieces (t, estimate, reference)."""
    record: bool = False
    """Keep ``judged`` (replay's /diagnostics ticks read it)."""
    judged: list[tuple[float, dict[str, str]]] = field(default_factory=list)
    """With ``record``: (time, ``OutputFusion.diagnostic_values``) of each judged reference."""

    def run(self, t: np.ndarray, estimate: np.ndarray, reference: np.ndarray,
            eligible: np.ndarray) -> np.ndarray:
        """The fused estimate of one piece."""
        t = np.asarray(t, dtype=np.float64)
        estimate = np.asarray(estimate, dtype=np.float64)
        out = np.array(estimate, dtype=np.float64)
        if t.size == 0:
            return out
        if self.origin is None:
            self.origin = float(t[0])
            check_every(self.every, t)
        idx = np.flatnonzero(eligible)
        t_idx = t[idx]
        lo = 0  # the eligible samples not yet passed: idx[lo:]
        pos = 0
        half = 0.5 * self.every

        def sample(j: int) -> tuple[float, float, float]:
            """(t, estimate, reference) of the ``j``-th eligible sample."""
            return float(t[idx[j]]), float(estimate[idx[j]]), float(reference[idx[j]])

        while True:
            target = self.origin + self.k * self.every
            j = lo + int(np.searchsorted(t_idx[lo:], target, side="left"))
            if j == idx.size:  # no eligible sample at or after the target in this piece
                if lo < idx.size:
                    self.before = sample(idx.size - 1)
                break
            candidates: list[tuple[float, int, tuple[float, float, float]]] = []
            if j > lo:
                candidates.append((target - t_idx[j - 1], j - 1, sample(j - 1)))
            elif self.before is not None:
                candidates.append((target - self.before[0], -1, self.before))
            candidates.append((t_idx[j] - target, j, sample(j)))
            distance, chosen, (t_ref, s_hat, y) = min(candidates, key=lambda c: c[0])
            if distance <= half:
                index = int(idx[chosen]) if chosen >= 0 else -1
                out[pos:index + 1] = self.fusion.apply(estimate[pos:index + 1])
                pos = index + 1
                self.fusion.update(t_ref, s_hat, y)
                if self.record:
                    self.judged.append((t_ref, self.fusion.diagnostic_values()))
                lo = max(lo, chosen + 1)
                self.before = None
            self.k = max(self.k + 1, math.floor((t_ref - self.origin) / self.every) + 1)
        out[pos:] = self.fusion.apply(estimate[pos:])
        return out

    @classmethod
    def for_calibration(cls, cal: SensorCalibration, every: float, *, record: bool = False
                        ) -> SparseFusion:
        """A sensor's fusion at its calibrated strain span, fed every ``every`` seconds."""
        return cls(OutputFusion.for_calibration(cal), check_every(every), record=record)

    def fuse(self, t: np.ndarray, out: BatchOutput, reference: np.ndarray) -> BatchOutput:
        """``out`` with its strain fused on the used samples within the calibrated range."""
        strain = np.asarray(out.strain, dtype=np.float64)
        reference = np.asarray(reference, dtype=np.float64)
        eligible = (used_mask(out.status) & ~np.asarray(out.out_of_range, bool)
                    & np.isfinite(reference) & np.isfinite(strain))
        return replace(out, strain=self.run(t, strain, reference, eligible))


def check_every(every: float, t: npt.ArrayLike | None = None) -> float:
    """``every`` if finite, > 0 s and not below the sampling interval of ``t``."""
    if not (isinstance(every, (int, float)) and math.isfinite(every) and every > 0):
        raise InputError(f"--references-every {every!r}: must be a number of seconds > 0")
    steps = np.diff(np.asarray(t if t is not None else [], dtype=np.float64))
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if steps.size and every < float(np.median(steps)):
        raise InputError(f"--references-every {every:g}: below the sampling interval "
                         f"({float(np.median(steps)):.4g} s), more references than samples; "
                         f"give at least {float(np.median(steps)):.4g}")
    return float(every)


def fusion_note(name: str, state: dict[str, Any], every: float, unit: str) -> str:
    """One line on what the fusion of ``name`` did (``OutputFusion.state``)."""
    refused = ", ".join(f"{k} {v}" for k, v in state["refused"].items())
    return (f"{name}: a reference every {every:g} s: {state['n_used']} used, "
            f"{state['n_refused']} refused{' (' + refused + ')' if refused else ''}; "
            f"output gain {state['gain']:.4g}, offset {state['offset']:.4g} {unit}")
