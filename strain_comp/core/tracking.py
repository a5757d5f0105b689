"""Baseline tracking: the rest level follows a sensor whose resistance at rest drifts.

After weighing instruments' automatic zero-tracking (OIML R76-1, section 4.6.9: only while
the instrument is at rest, only within a band around zero, at a bounded rate), the tare
gain (``Engine.track_baseline``, counted in the sensor's health and so in /diagnostics)
is nudged so that the resistance read at rest becomes the
calibration's rest again, but only:

* while the direction detector says hold (0) over a whole ``chunk_seconds`` stretch of used
  samples (no movement),
* when that stretch reads a rest that moved to the rest side: its resistance at or beyond
  the calibrated rest on the rest side (below it for a sensor whose R rises with strain:
  a rest that fell after a release reads below the calibrated range and pins the
  estimate to the range floor) and its estimate at most ``band`` of the calibrated strain
  span above the fitted rest strain (a resistance that peaks and falls with strain, as
  carbon black's, reads a rest resistance at a large strain). A stretch on the strain side
  only undoes the tracker's own correction (where it would read at or beyond the rest
  without it: the rest came back), never beyond it: a rest that rose, a held small strain
  and a resistance still relaxing down after an unload (carbon black) read the same, and a
  strain is never tracked,
* by at most ``rate`` of the rest level per second,
* and only for a calibration that reads its own rest resistance as its rest strain
  (``rest_is_read_as_rest``) and has no effect terms but an output gain and offset
  (``models_what_moves``: the loop's terms already model what moves).

A held strain (detector at hold, estimate far from rest) is never tracked. The numbers are
those of running the engine once per judged stretch of ``chunk_seconds``, each judged
before the next runs; the engine's state carries from one call to the next exactly, so
``run`` runs many stretches in one call and judges them afterwards, in order. Where a
judgement corrects the gain (rare: only at a rest), the engine rewinds to that stretch's
end (``Engine.save_state`` / ``restore_state``, then the samples since the save again) and
goes on from the corrected gain. A stretch whose judgement, and the next one's, cannot
correct (not a hold, or a hold on the strain side with no correction to undo) is judged
from counts over the call's output, without keeping its samples: the cost is linear in the
samples, whatever time they span, but at a rest being corrected (one call per stretch, a
call after a correction running one piece, then twice as many each time). A stretch
keeps only its used samples (at most ``chunk_seconds`` times the sample rate): a stopped
clock (repeated stamps are not used) or one that runs backwards holds O(1) state per
sensor.
The numbers are the fields of ``TrackingPolicy`` (``TRACKING``; docs/policies.md gives
what keeps each).
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field, fields, replace

import numpy as np

from strain_comp.core.calibration import Calibration, SensorCalibration, ValidRange
from strain_comp.core.effects import RECALIBRATION_TERMS
from strain_comp.core.engine import Engine
from strain_comp.core.outputs import BatchOutput, SensorOutput, concatenate
from strain_comp.core.range_policy import RANGE
from strain_comp.core.samples import Status, used_mask
from strain_comp.core.tare import TARE
from strain_comp.errors import InputError

TRACKING_MODES = ("off", "on")
"""Baseline tracking off or on."""
DEFAULT_TRACKING = "on"
"""The default of evaluate, replay and the node (docs/generalisation.md: neutral on
``scripts/generalisation.py``, no measured table worse, a rest that fell followed)."""


@dataclass(frozen=True)
class TrackingPolicy:
    """The tuned numbers of baseline tracking (docs/policies.md: each one's measure)."""

    chunk_seconds: float = 1.0
    """Length of the stretches the tracker judges [s]."""
    band: float = TARE.rest_band
    """An estimate within this share of the calibrated strain span of the rest strain is
    rest [share of the strain span] (the tare's rest band)."""
    rate: float = 0.002
    """Largest change of the rest level per second [share of the level per s]."""
    settle_rate: float = 0.02
    """A rest whose resistance still moves by more than this share per second of its
    distance from the calibrated rest is relaxing (a time constant under 50 s) and is not
    tracked [share per s]."""


TRACKING = TrackingPolicy()
"""The policy every tracker uses unless given another."""
MAX_BATCH = 1024
"""Most pieces (each ending with a judged stretch) the engine runs in one call."""


def tracker_for(engine: Engine, mode: str) -> BaselineTracker | None:
    """A tracker of ``engine`` for ``mode`` ``on``, None for ``off``; InputError else.

    Args:
        engine: The engine tracked.
        mode: ``on`` or ``off``.

    Returns:
        The tracker, or None.

    Raises:
        InputError: ``mode`` is neither.

    """
    if mode not in TRACKING_MODES:
        raise InputError(f"--baseline-tracking {mode!r}: expected one of "
                         f"{', '.join(TRACKING_MODES)}")
    return BaselineTracker(engine) if mode == "on" else None


def fitted_rest(valid_range: ValidRange) -> tuple[float, float]:
    """(rest strain, strain span) the calibration was fitted over: its valid strain range
    less the ``RangePolicy.margin`` of the span the fit adds on each side.

    Args:
        valid_range: The calibration's valid range.

    Returns:
        The rest strain and the strain span, in the calibration's strain unit.

    """
    span = (valid_range.s_hi - valid_range.s_lo) / (1.0 + 2.0 * RANGE.margin)
    return valid_range.s_lo + RANGE.margin * span, span


def models_what_moves(cal: SensorCalibration) -> bool:
    """Whether ``cal`` has effect terms (the residual loop's: temperature, drift,
    relaxation, ...) beyond an output gain and offset. They model how the reading moves,
    the rest level included; tracking the rest as well would correct it twice.

    Args:
        cal: The sensor's calibration.

    Returns:
        True if it has such terms.

    """
    return any(e.get("name") not in RECALIBRATION_TERMS for e in cal.effects)


def rest_is_read_as_rest(cal: SensorCalibration, raw_rest: float, band: float) -> bool:
    """Whether ``cal``, from a fresh state at the measured resistance ``raw_rest`` that it
    maps to its rest resistance, reads the fitted rest strain within ``band`` of the strain
    span. Tracking moves the rest toward that resistance; where the map reads it as a
    strain (a rest resistance taken while the sensor still relaxed, a map that is flat
    near rest), tracking would move the zero.

    Args:
        cal: The sensor's calibration.
        raw_rest: The measured rest resistance [ohm].
        band: The tolerance, a share of the strain span.

    Returns:
        True if the rest reads as rest (False for a resistance not finite and > 0).

    """
    if not (raw_rest > 0 and math.isfinite(raw_rest)):
        return False
    out = Engine(Calibration({cal.name: cal})).run(cal.name, np.zeros(1), np.array([raw_rest]))
    s_rest, s_span = fitted_rest(cal.valid_range)
    return bool(abs(float(out.strain[-1]) - s_rest) <= band * s_span)


@dataclass(frozen=True)
class _Stream:
    """One ``run``'s samples, each one's stretch ``index``, and the ``cuts`` between the
    pieces the tracker judges (a piece ends with a stretch of two samples or more)."""

    t: np.ndarray
    r: np.ndarray
    temperature: np.ndarray | None
    index: np.ndarray
    cuts: list[int]

    def part(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(t, r, temperature) of samples ``lo`` to ``hi``."""
        temp = None if self.temperature is None else self.temperature[lo:hi]
        return self.t[lo:hi], self.r[lo:hi], temp


@dataclass(frozen=True)
class _Holds:
    """Counts over one engine call's output, from its first sample to each sample: used
    samples, used samples off hold (direction not 0) and used samples that read strictly
    on the strain side of the rest resistance."""

    used: np.ndarray
    moving: np.ndarray
    strained: np.ndarray

    @classmethod
    def of(cls, out: BatchOutput, rest: float, sign: int) -> _Holds:
        used = used_mask(np.asarray(out.status))
        moving = used & (np.asarray(out.direction) != 0)
        strained = used & ((np.asarray(out.resistance) - rest) * sign > 0.0)
        return cls(*(np.concatenate([[0], np.cumsum(c)]) for c in (used, moving, strained)))

    def may_correct(self, a: int, b: int, undoing: bool) -> bool:
        """Whether ``judge`` could correct after samples ``a`` to ``b``: two used samples or
        more, all at hold, and (unless the tracker has a correction to undo, ``undoing``)
        no more than half of them on the strain side (else their median is too)."""
        n = self.used[b] - self.used[a]
        if n < 2 or self.moving[b] != self.moving[a]:
            return False
        return undoing or not 2 * (self.strained[b] - self.strained[a]) > n


@dataclass
class _Stretch:
    """The used samples of one sensor's current stretch (``index``: its number from the
    sensor's first sample): time, strain, direction and the resistance the model read."""

    index: float
    columns: tuple[array[float], ...] = field(
        default_factory=lambda: tuple(array("d") for _ in range(4)))

    def add(self, t: np.ndarray, out: BatchOutput) -> None:
        used = used_mask(np.asarray(out.status))
        if not used.any():
            return
        for column, values in zip(self.columns, (t, out.strain, out.direction,
                                                 out.resistance), strict=True):
            column.frombytes(np.ascontiguousarray(np.asarray(values, np.float64)[used])
                             .tobytes())

    def output(self) -> tuple[np.ndarray, BatchOutput]:
        """(times, output) of the kept samples, all used."""
        t, strain, direction, resistance = (np.frombuffer(c, np.float64)
                                            for c in self.columns)
        return t, BatchOutput(strain, direction, np.full(t.size, int(Status.GOOD), np.int8),
                              np.zeros(t.size, bool), resistance)


@dataclass
class BaselineTracker:
    """Tracks the rest level of every sensor of ``engine`` it is asked to run."""

    engine: Engine
    policy: TrackingPolicy = field(default_factory=lambda: TRACKING)
    pending: dict[str, _Stretch] = field(default_factory=dict)
    """Per sensor, the used samples of its current stretch, not yet judged."""
    reads_rest: dict[str, bool] = field(default_factory=dict)
    """Per sensor, whether it may be tracked: its calibration reads its own rest resistance
    as the rest strain and models nothing that moves (``rest_is_read_as_rest``,
    ``models_what_moves``)."""
    last_hold: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Per sensor, (mean time, measured resistance) of the last stretch judged, if it was
    at hold."""
    applied: dict[str, float] = field(default_factory=dict)
    """Per sensor, the product of the gain factors the tracker applied."""
    batch: dict[str, int] = field(default_factory=dict)
    """Per sensor, how many pieces its next engine call runs (``run``)."""
    origin: dict[str, float] = field(default_factory=dict)
    """Per sensor, the time of its first sample: stretches of ``policy.chunk_seconds`` are counted
    from it, so a run in one batch, in streamed windows (replay) or sample by sample (the
    node) is tracked alike."""

    def _index(self, name: str, t: np.ndarray | float) -> np.ndarray:
        return np.floor((np.asarray(t, np.float64) - self.origin[name]) / self.policy.chunk_seconds)

    def run(self, name: str, t: np.ndarray, r: np.ndarray,
            temperature: np.ndarray | None = None) -> BatchOutput:
        """``engine.run`` over ``t``, ``r``, judging every stretch of two samples or more
        after it ran (stretches each too short to judge run with the next). The engine runs
        many stretches in one call (``MAX_BATCH`` at most, twice as many after each call
        without a correction, one after one); where a judgement corrects the gain, it
        rewinds to that stretch's end (``Engine.restore_state``, then the samples before it
        again) and goes on from the corrected gain, so the numbers are those of one call per
        judged stretch. A sensor that is never tracked (``models_what_moves``) is run in
        one call: the engine's state carries across stretches exactly, so its output is the
        same."""
        t = np.asarray(t, dtype=np.float64)
        cal = self.engine.calibration.sensors.get(name)
        if t.size == 0 or (cal is not None and models_what_moves(cal)):
            return self.engine.run(name, t, r, temperature)  # nothing to judge or never tracked
        self.origin.setdefault(name, float(t[0]))
        index = self._index(name, t)
        edges = np.flatnonzero(np.diff(index)) + 1
        starts = np.concatenate([[0], edges])
        ends = np.concatenate([edges, [t.size]])
        judged = ends - starts >= 2
        if name in self.pending and index[0] == self.pending[name].index:
            judged[0] = True  # continues the kept stretch: judged with it
        stream = _Stream(t, np.asarray(r), temperature, index,
                         [0, *ends[judged & (ends < t.size)].tolist(), t.size])
        outs: list[BatchOutput] = []
        piece = 0
        while piece < len(stream.cuts) - 1:
            piece = self._run_batch(name, stream, piece, outs)
        return concatenate(outs)

    def _run_batch(self, name: str, stream: _Stream, first: int,
                   outs: list[BatchOutput]) -> int:
        """Run the pieces of ``stream`` from ``first`` on in one engine call, judging each
        one's kept stretch before the next; append what stands to ``outs``; return the
        first piece not run."""
        correction = self._judge_kept(name, float(stream.t[stream.cuts[first]]))
        if correction is not None:
            self._correct(name, *correction)
        span = 1 if correction is not None else self.batch.get(name, 1)
        last = min(first + span, len(stream.cuts) - 1)
        lo, hi = stream.cuts[first], stream.cuts[last]
        saved = self.engine.save_state(name) if last - first > 1 else None
        out = self.engine.run(name, *stream.part(lo, hi))
        kept, quiet = self._kept(name, stream, (first, last), out)
        for piece in range(first, last):
            a, b = stream.cuts[piece], stream.cuts[piece + 1]
            correction = (None if piece == first
                          else self._judge_kept(name, float(stream.t[a])))
            if correction is not None and saved is not None:
                self.engine.restore_state(name, saved)  # back to where the correction applies
                self.engine.run(name, *stream.part(lo, a))
                self._correct(name, *correction)
                self.batch[name] = 1
                outs.append(_slice(out, 0, a - lo))
                return piece
            self._keep(name, (a, b), kept[piece - first], stream, out, lo,
                       quiet[piece - first])
        outs.append(out)
        self.batch[name] = min(2 * span, MAX_BATCH)
        return last

    def _kept(self, name: str, stream: _Stream, pieces: tuple[int, int], out: BatchOutput
              ) -> tuple[list[int], list[bool]]:
        """For each of ``pieces`` (first, end) run in ``out``: where its last stretch starts,
        and whether that stretch is quiet (``_keep``): neither its judgement nor the next
        one's, which alone reads what it leaves, can correct (``_Holds.may_correct``), and
        the next is judged in this call."""
        first, end = pieces
        cuts, index = stream.cuts, stream.index
        kept = [a + int(np.searchsorted(index[a:b], index[b - 1]))  # the last stretch's start
                for a, b in zip(cuts[first:end], cuts[first + 1:end + 1], strict=True)]
        if end - first < 3:
            return kept, [False] * len(kept)
        cal = self.engine.calibration.sensors[name]
        span = cal.input.zero_span
        rest = span[1] if span is not None else cal.rest_resistance
        may = [False] * len(kept)  # no rest resistance: ``judge`` never corrects
        if rest is not None:
            lo = cuts[first]
            holds = _Holds.of(out, rest, cal.direction.sign)
            undoing = self.applied.get(name, 1.0) != 1.0
            may = [holds.may_correct(a - lo, b - lo, undoing)
                   for a, b in zip(kept, cuts[first + 1:end + 1], strict=True)]
        return kept, [not (may[j] or may[j + 1]) for j in range(len(kept) - 2)] + [False] * 2

    def _keep(self, name: str, piece: tuple[int, int], start: int, stream: _Stream,
              out: BatchOutput, lo: int, quiet: bool) -> None:
        """Keep the last stretch of ``piece`` (samples ``start`` to its end; ``out`` starts
        at sample ``lo``) until it is judged; the stretches before it in the piece (fewer
        than two samples each) end any hold. A ``quiet`` one (``_kept``) is judged at once:
        what its judgement leaves is never read, so it only ends the hold remembered."""
        a, b = piece
        if start > a:  # whole stretches before it: fewer than two samples each
            self.pending.pop(name, None)
            self.last_hold.pop(name, None)
        if quiet and name not in self.pending:
            self.last_hold.pop(name, None)
            return
        stretch = self.pending.setdefault(name, _Stretch(float(stream.index[b - 1])))
        stretch.add(stream.t[start:b], _slice(out, start - lo, b - lo))

    def advance(self, name: str, t: float) -> None:
        """Before samples from ``t`` on are run: if ``t`` starts a new stretch, judge the
        stretch kept so far (``update``), so its correction applies from ``t`` on."""
        self.origin.setdefault(name, t)
        correction = self._judge_kept(name, t)
        if correction is not None:
            self._correct(name, *correction)

    def _judge_kept(self, name: str, t: float) -> tuple[float, float] | None:
        """If ``t`` starts a new stretch, judge the stretch kept so far (``judge``)."""
        kept = self.pending.get(name)
        if kept is None or float(self._index(name, t)) == kept.index:
            return None
        del self.pending[name]
        return self.judge(name, *kept.output())

    def observe(self, name: str, t: float, out: SensorOutput) -> None:
        """One stepped sample (the node; ``advance`` first), kept until its stretch is
        judged."""
        stretch = self.pending.setdefault(name, _Stretch(float(self._index(name, t))))
        stretch.add(np.array([t]), BatchOutput(
            np.array([out.strain]), np.array([out.direction]),
            np.array([int(out.status)], np.int8), np.zeros(1, bool),
            np.array([out.resistance])))

    def update(self, name: str, t: np.ndarray, out: BatchOutput) -> None:
        """Nudge ``name``'s tare gain after one stretch ``out`` (if it was a rest)."""
        correction = self.judge(name, t, out)
        if correction is not None:
            self._correct(name, *correction)

    def _correct(self, name: str, factor: float, duration: float) -> None:
        """Apply a judgement: the tare gain times ``factor`` after ``duration`` at rest."""
        self.applied[name] = self.applied.get(name, 1.0) * factor
        self.engine.track_baseline(name, self.engine.input_gain(name) * factor, duration)

    def judge(self, name: str, t: np.ndarray, out: BatchOutput) -> tuple[float, float] | None:
        """(factor on the tare gain, seconds at rest) after one stretch ``out``, if it was
        a rest to correct; None else. Changes only what the tracker remembers of holds."""
        cal = self.engine.calibration.sensors[name]
        policy = self.policy
        used = used_mask(np.asarray(out.status))
        previous = self.last_hold.pop(name, None)
        if used.sum() < 2 or np.any(np.asarray(out.direction)[used] != 0):
            return None
        duration = float(t[used][-1] - t[used][0])
        span = cal.input.zero_span
        rest = span[1] if span is not None else cal.rest_resistance
        if not duration > 0 or rest is None:
            return None
        level = float(np.median(np.asarray(out.resistance)[used]))
        k, c = cal.input.span_map()
        gain = self.engine.input_gain(name)
        raw = (level - c) / (k * gain)  # the measured resistance at this rest
        if not (raw > 0 and math.isfinite(raw)):
            return None
        now = float(np.mean(t[used]))
        self.last_hold[name] = (now, raw)
        off_rest = abs(raw - (rest - c) / (k * gain))
        if previous is None or not now - previous[0] <= 2.0 * policy.chunk_seconds:
            return None  # the first stretch of a hold (the last judged was not the one before)
        if abs(raw - previous[1]) > policy.settle_rate * off_rest * (now - previous[0]):
            return None  # still relaxing toward where it was: left to relax
        s_rest, s_span = fitted_rest(cal.valid_range)
        estimate = float(np.median(np.asarray(out.strain)[used]))
        applied = self.applied.get(name, 1.0)
        sign = cal.direction.sign
        below = (level - rest) * sign <= 0.0
        if below and estimate - s_rest > policy.band * s_span:
            return None  # read as a strain: a resistance that peaks and falls (carbon black)
        if not below and (applied == 1.0 or (c + (level - c) / applied - rest) * sign > 0.0):
            return None  # on the strain side without the tracker's correction too: never tracked
        if name not in self.reads_rest:
            self.reads_rest[name] = (not models_what_moves(cal)
                                     and rest_is_read_as_rest(cal, (rest - c) / k, policy.band))
        if not self.reads_rest[name]:
            return None
        target = (rest - c) / (k * raw)
        step = policy.rate * duration
        factor = float(np.clip(target / gain, 1.0 - step, 1.0 + step))
        if not below and (applied * factor - 1.0) * (applied - 1.0) < 0.0:
            factor = 1.0 / applied  # the tracker's correction undone, no further
        return (factor, duration) if factor != 1.0 else None


def _slice(out: BatchOutput, start: int, stop: int) -> BatchOutput:
    """``out``'s samples ``start`` to ``stop`` (every field)."""
    return replace(out, **{f.name: getattr(out, f.name)[start:stop] for f in fields(out)
                           if getattr(out, f.name) is not None})
