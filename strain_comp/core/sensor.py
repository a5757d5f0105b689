"""One sensor in the engine and its per-sample path (docs/models.md, "The engine's
per-sample path"); one sample is a batch of one."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from strain_comp.base import samples as sc
from strain_comp.base.compensator import Compensator
from strain_comp.base.conversion import divider_all
from strain_comp.base.direction import DirectionDetector, DirectionSettings
from strain_comp.core import uncertainty
from strain_comp.core.calibration import SensorCalibration
from strain_comp.core.chain import DESPIKE_K, SPIKE, STEP, ChainCorrector, pair_values
from strain_comp.core.correction import Correction
from strain_comp.core.effects import EffectTerms, run_segments
from strain_comp.core.health import STATUSES, SensorHealth, add_counts
from strain_comp.core.outputs import BatchOutput
from strain_comp.core.range_policy import SensorRange
from strain_comp.core.stages import (
    bound_all,
    hold,
    saturate_all,
    screen_batch,
)
from strain_comp.core.uncertainty import std_run
from strain_comp.errors import InputError

Latest = Callable[[str], float]
"""A sensor name -> its latest clamped pre-effect strain (what cross-talk terms read)."""


@dataclass
class PendingBatch:
    """``run``'s first stage: screening, model and detector over a batch."""

    t: np.ndarray
    ohm: np.ndarray
    temperature: np.ndarray | None
    status: np.ndarray
    reset: np.ndarray
    last_good_t: float
    idx: np.ndarray
    """Indices of the used samples."""
    bounds: list[int]
    """Segment bounds in ``idx`` (a reset starts a segment)."""
    strain_used: np.ndarray
    dir_used: np.ndarray
    corrections: np.ndarray | None
    """The corrector's event per used sample (``BatchOutput.corrections``), if any."""

    def base(self, sensor: SensorState) -> np.ndarray:
        """Clamped pre-effect estimate at every sample, NaN where the sample was bad."""
        out = np.full(self.t.size, np.nan)
        out[self.idx] = np.clip(self.strain_used, sensor.limits.s_lo, sensor.limits.s_hi)
        return out


@dataclass
class SensorState:
    """Everything the engine keeps for one sensor."""

    cal: SensorCalibration
    model: Compensator
    detector: DirectionDetector
    limits: SensorRange
    health: SensorHealth = field(default_factory=SensorHealth)
    strain: float = math.nan
    direction: int = 0
    effects: EffectTerms = field(default_factory=lambda: EffectTerms([], []))
    base: float = math.nan
    """Latest clamped strain before effect terms (what neighbours' cross-talk terms read)."""
    gain: float = 1.0
    """Input gain (tare): the input map reads ``gain`` x the measured resistance."""
    correction: Correction = field(default_factory=Correction)
    previous: float = math.nan
    """Latest used resistance [ohm] (for pair means when the input alternates)."""
    corrector: ChainCorrector | None = None
    std: float = math.nan
    """Latest standard deviation of the estimate (NaN: no band in the calibration)."""
    band: np.ndarray = field(default_factory=uncertainty.new_state)
    """The uncertainty features' state (``strain_comp.core.uncertainty``)."""
    weights: np.ndarray | None = None
    """The calibration's uncertainty weights (None: no band)."""

    @classmethod
    def build(cls, cal: SensorCalibration, deadzone_scale: float,
              out_of_range: str = "clamp", limits: SensorRange | None = None
              ) -> SensorState:
        """A fresh sensor of ``cal``; ``limits``: those already built (None: build them)."""
        model = cal.build_model()
        if limits is None:
            limits = SensorRange.build(cal, out_of_range, model)
        else:
            model.reset()  # as SensorRange.build leaves it
        correction = Correction.of(cal)
        chain = cal.input  # a spike threshold or step size in the file asks for the corrector
        corrector = None if chain.despike is None and chain.baseline_step is None else \
            ChainCorrector(k=chain.despike or DESPIKE_K, alternating=chain.alternation,
                           step_k=chain.baseline_step or 0.0)
        return cls(cal=cal, model=model,
                   detector=DirectionDetector(scaled(cal.direction, deadzone_scale)),
                   limits=limits, effects=EffectTerms.from_dicts(correction.effects(cal.effects)),
                   correction=correction,
                   corrector=corrector,
                   weights=None if cal.uncertainty is None
                   else np.asarray(cal.uncertainty.weights, dtype=np.float64))

    def pair(self, t: np.ndarray, ohm: np.ndarray, previous: float
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """(what the models see of used samples ``ohm``, the corrector's events or None)."""
        if not self.cal.input.filtered or not ohm.size:
            return ohm, None
        self.previous = float(ohm[-1])
        if self.cal.input.alternation:
            ohm = pair_values(ohm, previous, self.cal.input.pair)
        if self.corrector is None:
            return ohm, None
        if math.isnan(previous):
            self.corrector.restart()
        ohm, events = self.corrector.run(t, ohm)
        events = np.where((events == SPIKE) | (events == STEP), events, 0).astype(np.int8)
        self.health.n_spikes += int(np.count_nonzero(events == SPIKE))
        self.health.n_baseline_steps += int(np.count_nonzero(events == STEP))
        return ohm, events

    def run_model(self, t: npt.ArrayLike, r: npt.ArrayLike,
                  temperature: npt.ArrayLike | None, gap_reset: float) -> PendingBatch:
        """``run``'s first stage: input fix, screen, input corrections, detector, model."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        raw = np.ascontiguousarray(r, dtype=np.float64)
        if t.ndim != 1 or t.shape != raw.shape:
            raise InputError("run: t and r must be 1-D arrays of one length")
        temp = (None if temperature is None
                else np.ascontiguousarray(temperature, dtype=np.float64))
        if self.cal.input.kind == "divider":  # the input-fix stage over a batch
            raw, forced = divider_all(raw, *self.cal.input.divider())
        else:
            forced = np.zeros(raw.shape, dtype=np.int8)
        ohm = self.correction.apply_input(raw, self.gain)
        lim, last = self.limits, self.health.last_good_t
        status, reset, last_good_t, idx, resets = screen_batch(
            t, ohm, forced, -math.inf if last is None else last, lim.r_short, lim.r_open,
            lim.r_lo, lim.r_hi, sc.gap_for(self.cal.sample_interval, gap_reset))
        if self.cal.input.filtered:
            ohm = ohm.copy()  # corrected samples replace the used ones below; raw intact
        bounds = [0, *resets.tolist(), idx.size] if resets.size else [0, idx.size]
        corrections = np.zeros(idx.size, np.int8) if self.corrector is not None else None
        strain_used = np.empty(idx.size)
        dir_used = np.empty(idx.size, dtype=np.int8)
        for k, (a, b) in enumerate(itertools.pairwise(bounds)):
            if b == a:
                continue
            if k > 0:
                self.model.reset()
                self.detector.reset()
            seg = idx[a:b] if idx.size < t.size else slice(a, b)
            seg_ohm, events = self.pair(t[seg], ohm[seg], self.previous if k == 0 else math.nan)
            if self.cal.input.filtered:
                ohm[seg] = seg_ohm
            if corrections is not None and events is not None:
                corrections[a:b] = events
            dir_used[a:b] = self.detector.run(t[seg], seg_ohm)
            strain_used[a:b] = self.model.run(t[seg], saturate_all(seg_ohm, lim.row))
        if self.cal.input.filtered:  # the range flag of what the model reads (``screen_one``)
            seen, inside = ohm[idx], np.where(reset[idx], sc.GAP_RESET, sc.GOOD)
            status[idx] = np.where((seen < lim.r_lo) | (seen > lim.r_hi), sc.OUT_OF_RANGE, inside)
        if self.cal.direction.sign < 0:
            dir_used = -dir_used
        return PendingBatch(t, ohm, temp, status, reset, last_good_t, idx, bounds,
                            strain_used, dir_used, corrections)

    def run_finish(self, p: PendingBatch, latest: Latest,
                   neighbours: Mapping[str, np.ndarray]) -> BatchOutput:
        """``run``'s second stage: effect terms, range, held outputs and counters."""
        t, status, reset, last_good_t, idx = p.t, p.status, p.reset, p.last_good_t, p.idx
        strain_used, dir_used = p.strain_used, p.dir_used
        if self.cal.effects and idx.size:  # the one place effect terms correct the strain
            t_used, ohm_used = t[idx], p.ohm[idx]
            temp = (np.full(idx.size, np.nan) if p.temperature is None
                    else p.temperature[idx])
            base = np.clip(strain_used, self.limits.s_lo, self.limits.s_hi)
            self.base = float(base[-1])
            nbrs = {n: neighbours[n][idx] if n in neighbours else np.full(idx.size, latest(n))
                    for n in self.effects.neighbours}
            corrected = run_segments(  # a reset at the first sample resets at once
                lambda k: self.effects.run(t_used[k], ohm_used[k], base[k], dir_used[k],
                                           temp[k], {n: v[k] for n, v in nbrs.items()}),
                self.effects.reset, idx.size, p.bounds[1:-1])
            # a correction that overflows (extreme inputs or coefficients) is not applied: the
            # estimate never becomes NaN; +-inf is clamped to the valid range below. Then the
            # output map (``Correction.apply_output``).
            strain_used = self.correction.apply_output(np.where(np.isnan(corrected), base,
                                                                corrected))
        strain_used = bound_all(p.ohm[idx], strain_used, self.limits.row)
        std = None
        if self.weights is not None:
            std_used = std_run(t[idx], dir_used, p.ohm[idx], strain_used, self.band,
                               self.limits.row, self.weights)
            std = hold(status, reset, idx, std_used, dir_used, self.std, self.direction)[0]
            if idx.size:
                self.std = float(std_used[-1])
        strain, direction, out_of_range, counts = hold(
            status, reset, idx, strain_used, dir_used, self.strain, self.direction)
        h = self.health
        add_counts(h, counts)
        if status.size:
            h.last_status = STATUSES[status[-1]]
        if idx.size:
            h.last_good_t = last_good_t
            self.strain, self.direction = float(strain_used[-1]), int(dir_used[-1])
        corrections = None
        if p.corrections is not None:
            corrections = np.zeros(t.size, np.int8)
            corrections[idx] = p.corrections
        return BatchOutput(strain, direction, status, out_of_range, p.ohm, reset, corrections,
                           std)


def run_together(sensors: Mapping[str, SensorState], t: npt.ArrayLike, r: np.ndarray,
                 temperature: Mapping[str, npt.ArrayLike | None], gap_reset: float,
                 latest: Latest) -> dict[str, BatchOutput]:
    """Sensors sampled together (``r``: a column each); cross-talk reads the same tick."""
    pending = {name: s.run_model(t, r[:, j], temperature.get(name), gap_reset)
               for j, (name, s) in enumerate(sensors.items())}
    bases = {name: p.base(sensors[name]) for name, p in pending.items()}
    return {name: sensors[name].run_finish(p, latest, bases) for name, p in pending.items()}


def scaled(settings: DirectionSettings, scale: float) -> DirectionSettings:
    """``settings`` with the dead zone times ``scale``."""
    return replace(settings, deadzone=settings.deadzone * scale)

