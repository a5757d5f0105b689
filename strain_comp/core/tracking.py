"""Baseline tracking: the rest level follows a sensor whose resistance at rest drifts.

After weighing instruments' automatic zero-tracking (OIML R76-1, section 4.6.9: only while
the instrument is at rest, only within a band around zero, at a bounded rate), the tare
gain (``Engine.track_baseline``, counted in the sensor's health and so in /diagnostics)
is nudged so that the resistance read at rest becomes the
calibration's rest again, but only:

* while the direction detector says hold (0) over a whole ``CHUNK_SECONDS`` stretch of used
  samples (no movement),
* when that stretch reads at rest: its estimate within ``BAND`` of the calibrated strain
  span of the fitted rest strain, or its resistance at or beyond the calibrated rest on the
  rest side (below it for a sensor whose R rises with strain: a rest that fell after a
  release reads below the calibrated range and pins the estimate to the range floor),
* by at most ``RATE`` of the rest level per second.

A held strain (detector at hold, estimate far from rest) is never tracked. The engine runs
the samples in stretches of ``CHUNK_SECONDS``; its state carries from one to the next
exactly, so between corrections the numbers are the batch path's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.core.tare import REST_BAND
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.core.calibration import ValidRange
    from strain_comp.core.engine import BatchOutput, Engine, SensorOutput

TRACKING_MODES = ("off", "on")
"""Baseline tracking off (default: the benchmark shows no gain, docs/generalisation.md)
or on."""
CHUNK_SECONDS = 1.0
"""Length of the stretches the tracker judges [s]."""
BAND = REST_BAND
"""An estimate within this share of the calibrated strain span of the rest strain is rest."""
RATE = 0.002
"""Largest change of the rest level per second (share of it)."""


def tracker_for(engine: Engine, mode: str) -> BaselineTracker | None:
    """A tracker of ``engine`` for ``mode`` ``on``, None for ``off``; InputError else."""
    if mode not in TRACKING_MODES:
        raise InputError(f"--baseline-tracking {mode!r}: expected one of "
                         f"{', '.join(TRACKING_MODES)}")
    return BaselineTracker(engine) if mode == "on" else None


def fitted_rest(valid_range: ValidRange) -> tuple[float, float]:
    """(rest strain, strain span) the calibration was fitted over: its valid strain range
    less the ``RANGE_MARGIN`` of the span the fit adds on each side."""
    from strain_comp.core.engine import RANGE_MARGIN

    span = (valid_range.s_hi - valid_range.s_lo) / (1.0 + 2.0 * RANGE_MARGIN)
    return valid_range.s_lo + RANGE_MARGIN * span, span


@dataclass
class BaselineTracker:
    """Tracks the rest level of every sensor of ``engine`` it is asked to run."""

    engine: Engine
    rate: float = RATE
    band: float = BAND
    pending: dict[str, list[tuple[float, float, int, int, float]]] = field(
        default_factory=dict)
    """Per sensor, the stepped samples of its current stretch (``observe``)."""

    def run(self, name: str, t: np.ndarray, r: np.ndarray,
            temperature: np.ndarray | None = None) -> BatchOutput:
        """``engine.run`` over ``t``, ``r`` in stretches, tracking between them."""
        from strain_comp.core.engine import concatenate

        t = np.asarray(t, dtype=np.float64)
        if t.size == 0:
            return self.engine.run(name, t, r, temperature)
        edges = np.flatnonzero(np.diff(np.floor((t - t[0]) / CHUNK_SECONDS))) + 1
        outs = []
        for a, b in zip([0, *edges.tolist()], [*edges.tolist(), t.size], strict=True):
            temp = None if temperature is None else temperature[a:b]
            out = self.engine.run(name, t[a:b], np.asarray(r)[a:b], temp)
            self.update(name, t[a:b], out)
            outs.append(out)
        return concatenate(outs)

    def observe(self, name: str, t: float, out: SensorOutput, ohm: float) -> None:
        """One stepped sample (the node): kept until its stretch of ``CHUNK_SECONDS`` is
        complete, which is then judged as in ``run``. ``ohm``: what the model read
        (``Engine.model_input``)."""
        from strain_comp.core.engine import BatchOutput

        kept = self.pending.setdefault(name, [])
        if kept and np.floor((t - kept[0][0]) / CHUNK_SECONDS) > 0:
            ts, strain, direction, status, r = (np.array(c) for c in zip(*kept, strict=True))
            kept.clear()
            self.update(name, ts, BatchOutput(strain, direction, status.astype(np.int8),
                                              np.zeros(ts.size, bool), r))
        kept.append((t, out.strain, out.direction, int(out.status), ohm))

    def update(self, name: str, t: np.ndarray, out: BatchOutput) -> None:
        """Nudge ``name``'s tare gain after one stretch ``out`` (if it was a rest)."""
        from strain_comp.core.engine import used_mask

        cal = self.engine.calibration.sensors[name]
        used = used_mask(np.asarray(out.status))
        if used.sum() < 2 or np.any(np.asarray(out.direction)[used] != 0):
            return
        duration = float(t[used][-1] - t[used][0])
        if not duration > 0:
            return
        span = cal.input.zero_span
        rest = span[1] if span is not None else cal.rest_resistance
        if rest is None:
            return
        level = float(np.median(np.asarray(out.resistance)[used]))
        s_rest, s_span = fitted_rest(cal.valid_range)
        estimate = float(np.median(np.asarray(out.strain)[used]))
        below = (level - rest) * cal.direction.sign <= 0.0
        if not (below or abs(estimate - s_rest) <= self.band * s_span):
            return
        k, c = cal.input.span_map()
        gain = self.engine.input_gain(name)
        raw = (level - c) / (k * gain)  # the measured resistance at this rest
        if not (raw > 0 and math.isfinite(raw)):
            return
        target = (rest - c) / (k * raw)
        step = self.rate * duration
        new = gain * float(np.clip(target / gain, 1.0 - step, 1.0 + step))
        if new != gain:
            self.engine.track_baseline(name, new, duration)
