"""Tare: the sensor's resistance at rest, read at the start of a run or of a fit; the engine
scales the input by (calibrated rest / rest now) (docs/results.md, "Tare")."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from strain_comp.base.direction import DirectionDetector, DirectionSettings
from strain_comp.base.samples import good_mask
from strain_comp.core.chain import pair_values
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.core.engine import Engine


# The tare's numbers. docs/results.md gives what keeps each: the largest change of a
# benchmark case with the number set neutral.
REST_WINDOW = 5.0  # s: longest leading stretch an automatic tare reads (inf: a case 20 %)
MIN_REST_SAMPLES = 3  # fewest rest samples a tare accepts... (1: a case 62 %)
MIN_REST_SECONDS = 1.0  # s: ...unless they span this long, a slow instrument (0: 62 %)
# Largest drift of the rest level over REST_WINDOW a tare accepts (share of the level): a
# level moving more within the first seconds is a relaxation going on for minutes (inf: 39 %).
MAX_REST_DRIFT = 0.005
REST_BAND = 0.02  # reference strain this share of its span above its minimum is rest (0.1: 93 %)


def rest_level(r: np.ndarray, *, pair: str = "mean") -> float:
    """Median of the pair statistic ``pair`` (cancels an alternation; ignores spikes)."""
    return float(np.median(pair_values(r, branch=pair)[1:] if r.size >= 2 else r))


def rest_resistance_at_start(t: npt.ArrayLike, r: npt.ArrayLike,
                             direction: DirectionSettings, *, pair: str = "mean",
                             ended: bool = True) -> float | None:
    """Rest resistance [ohm] of a run from its first seconds (no reference needed); InputError
    when too few or drifting; None while the rest goes on in a run not ``ended`` (the node)."""
    ta = np.asarray(t, dtype=np.float64)
    ra = np.asarray(r, dtype=np.float64)
    good = good_mask(ta, ra)  # the samples the engine feeds its model
    ta, ra = ta[good], ra[good]
    if ta.size == 0:
        if not ended:
            return None
        raise InputError("tare: no good resistance sample at the start of the run")
    head = int(np.searchsorted(ta, ta[0] + REST_WINDOW, side="right"))
    complete = head < ta.size or ta[-1] - ta[0] >= REST_WINDOW
    ta, ra = ta[:head], ra[:head]
    # the detector reads pair values: an alternation every other sample is not movement
    pairs = pair_values(ra, branch=pair)[1:] if ra.size >= 2 else ra
    states = DirectionDetector(direction).run(ta[ta.size - pairs.size:], pairs)
    moving = np.flatnonzero(states != 0)
    if not (moving.size or complete or ended):  # still at rest: the rest may go on
        return None
    stop = int(moving[0]) + (ra.size - pairs.size) if moving.size else ra.size
    if stop == 0 or (stop < MIN_REST_SAMPLES
                     and ta[stop - 1] - ta[0] < MIN_REST_SECONDS):
        raise InputError(f"tare: the run does not start at rest (the direction detector "
                         f"leaves hold after {stop} samples, {MIN_REST_SAMPLES} or "
                         f"{MIN_REST_SECONDS:g} s needed)")
    drift = rest_drift(ta[:stop], ra[:stop], pair=pair)
    if abs(drift) > MAX_REST_DRIFT:
        raise InputError(f"tare: the run starts while the resistance still drifts "
                         f"({100 * drift:+.2f} % over {REST_WINDOW:g} s, at most "
                         f"{100 * MAX_REST_DRIFT:g} % at rest): no rest level; record "
                         "the run from a few still seconds at rest, or start the session "
                         "on a stretch and back (strain-comp start)")
    return rest_level(ra[:stop], pair=pair)


def rest_drift(t: np.ndarray, r: np.ndarray, *, pair: str = "mean") -> float:
    """Drift of a rest stretch over ``REST_WINDOW`` s as a share of its level."""
    if r.size < 4:
        return 0.0
    half = r.size // 2
    first, second = rest_level(r[:half], pair=pair), rest_level(r[half:], pair=pair)
    dt = float(np.median(t[half:]) - np.median(t[:half]))
    if not dt > 0:
        return 0.0
    return (second - first) / first * REST_WINDOW / dt


def _referenced(t: npt.ArrayLike, r: npt.ArrayLike, s: npt.ArrayLike, min_samples: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The good referenced samples; None when too few or the reference never moves."""
    ta = np.asarray(t, dtype=np.float64)
    ra = np.asarray(r, dtype=np.float64)
    sa = np.asarray(s, dtype=np.float64)
    good = good_mask(ta, ra) & np.isfinite(sa)
    ta, ra, sa = ta[good], ra[good], sa[good]
    if ta.size < min_samples or not np.ptp(sa) > 0:
        return None
    return ta, ra, sa


def unsettled_start(t: npt.ArrayLike, r: npt.ArrayLike, s: npt.ArrayLike, *,
                    pair: str = "mean",
                    ) -> tuple[float, float]:
    """(seconds, drift) of a run that starts while its resistance still relaxes."""
    referenced = _referenced(t, r, s, MIN_REST_SAMPLES)
    if referenced is None:
        return 0.0, 0.0
    ta, ra, sa = referenced
    moves = np.flatnonzero(np.abs(sa - sa[0]) > REST_BAND * np.ptp(sa))
    stop = int(moves[0])  # the span is > 0, so the reference leaves the band somewhere
    head = int(np.searchsorted(ta, ta[0] + REST_WINDOW, side="right"))
    if stop < head:  # a rest shorter than the window: no drift to judge
        return 0.0, 0.0
    drift = rest_drift(ta[:head], ra[:head], pair=pair)
    if abs(drift) <= MAX_REST_DRIFT:
        return 0.0, drift
    return float(ta[stop] - ta[0]), drift


def rest_resistance_from_reference(t: npt.ArrayLike, r: npt.ArrayLike, s: npt.ArrayLike,
                                   *, pair: str = "mean",
                                   ) -> float | None:
    """Rest resistance [ohm] of a training run: its first stay at minimum strain."""
    referenced = _referenced(t, r, s, MIN_REST_SAMPLES)
    if referenced is None:
        return None
    ta, ra, sa = referenced
    rest = np.concatenate(([False], sa <= sa.min() + REST_BAND * np.ptp(sa), [False]))
    edges = np.flatnonzero(np.diff(rest.astype(np.int8)))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if start == 0 or stop - start >= MIN_REST_SAMPLES:
            end = min(int(stop), int(np.searchsorted(ta, ta[start] + REST_WINDOW,
                                                     side="right")))
            return rest_level(ra[start:end], pair=pair)
    return None


TARE_MODES = ("calibration", "auto")
"""Where the rest resistance comes from: the calibration (gain 1) or the run's start."""


def ohms(values: tuple[float, ...]) -> str:
    """Resistances in the prefix that suits the largest: ``35.1 vs 39.9 kohm``."""
    top = max(abs(v) for v in values)
    scale, prefix = next(((f, p) for f, p in ((1e6, "M"), (1e3, "k")) if top >= f), (1.0, ""))
    return " vs ".join(f"{v / scale:.4g}" for v in values) + f" {prefix}ohm"


def tare_reading(calibrated: float, measured: float) -> str:
    """A tare in words: ``rest resistance 12.0 % below calibration (35.1 vs 39.9 kohm)``."""
    change = 100.0 * (measured / calibrated - 1.0)
    side = "above" if change >= 0 else "below"
    return (f"rest resistance {abs(change):.1f} % {side} calibration "
            f"({ohms((measured, calibrated))})")


def tare_engine(engine: Engine, runs: Mapping[str, tuple[npt.ArrayLike, npt.ArrayLike]],
                mode: str) -> dict[str, str]:
    """Apply ``mode`` (``TARE_MODES``) to ``engine`` for the sensors of ``runs``."""
    if mode not in TARE_MODES:
        raise InputError(f"--tare {mode!r}: expected one of {', '.join(TARE_MODES)}")
    lines: dict[str, str] = {}
    if mode == "calibration":
        return lines
    for name, (t, r) in runs.items():
        if name not in engine.sensors:
            continue
        cal = engine.calibration.sensors[name]
        zero = cal.input_rest
        if cal.rest_resistance is None or zero is None:
            lines[name] = "not tared: the calibration stores no rest_resistance (refit it)"
            continue
        try:
            rest = rest_resistance_at_start(t, cal.input.to_ohm(r), cal.direction,
                                            pair=cal.input.pair)
            assert rest is not None  # a whole run (ended) always decides
        except InputError as err:
            lines[name] = f"not tared: {str(err).removeprefix('tare: ')}"
            continue
        engine.tare(name, rest)
        lines[name] = "tare: " + tare_reading(zero, rest)
    return lines
