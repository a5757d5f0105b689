"""Fitting orchestration: recordings (time, resistance, reference strain) -> calibration.

``fit_sensor`` turns one sensor's recordings into a ``SensorCalibration``; ``fit_bags`` does
it for every named sensor of a set of bags and returns one ``Calibration``. The model
equations and their fits live in ``strain_comp.models``; this module only prepares the
data and fills in what a calibration file needs besides the parameters:

* **Screening**: a sample is used only when ``strain_comp.core.samples.good_mask`` accepts it
  (the engine's rule: finite, R > 0 ohm, time increasing) and its reference strain is
  finite. As in the engine, a step back in time longer than ``GAP_SECONDS`` (a looped bag,
  a sim-time reset) is not a run of rejected samples but a new start: it cuts a segment.
* **Segments**: good samples are cut into ``Segment``s wherever the time between two
  consecutive good samples exceeds ``GAP_SECONDS`` (a recording pause, or a long stretch of
  bad samples), the engine's default ``gap_reset``: training resets model state exactly
  where the engine does. For an instrument so slow that ``GAP_INTERVALS`` of its median
  sample interval exceed that, the gap is that many intervals, and the calibration stores
  the interval (``sample_interval``) so that the engine counts gaps alike (a 0.1 Hz
  logger was cut at every sample and could not be fitted at all). Isolated bad samples
  do not cut a segment: online, a bad sample is skipped and the state kept, and the fit
  sees the same. Each recording starts a new
  segment (model state is reset per segment). Segments shorter than ``MIN_SEGMENT``
  samples are dropped.
* **Normalisation**: ``Normalisation.fit`` over all training samples ([Electrolycra]
  section II.C: the training data span [-1, 1]).
* **Valid range**: the training range of R and S widened by ``RANGE_MARGIN`` (5 %) of its
  span on each side (the resistance floor is kept above half the smallest training R, so it
  stays > 0 ohm). Inputs outside it are flagged as out of range, not silently trusted.
* **Direction detector** ([EGaIn] section V.E: dead zone = k sigma of dR/dt
  noise on a hold): the hold is the longest stretch where the *reference* strain is still
  (``|dS/dt|`` below ``HOLD_RATE_FRACTION`` of the 99.5th-percentile rate, at least
  ``MIN_HOLD_SAMPLES`` samples). Its second half is used, so that relaxation right after
  the stop does not count as noise, and ``strain_comp.core.direction.estimate_deadzone`` sets
  the dead zone from it. Without a usable hold, the resistance noise sigma is estimated
  robustly from the whole record (MAD of the second difference of R, which cancels any
  smooth motion: std(d2 R) = sqrt(6) sigma for white noise), and ``estimate_deadzone`` is
  given a synthetic hold of white noise with that sigma at the longest segment's own sample
  times (fixed seed, so fits are reproducible). Noise-free data get a tiny floor.
  The provenance records which of these set the dead zone (``direction_from``). Options
  ``deadzone`` (ohm/s, set directly), ``k_sigma`` and ``tau`` override this and are not
  passed to the model. ``sign`` is the sign of the correlation of R and S in the training
  data (-1 for a sensor whose R falls with strain), so the published direction is +1 on
  loading for every sensor (``strain_comp.core.engine``).
* **Measurement chain**: an alternation of the excitation every other sample
  (``strain_comp.core.chain.alternation``, found from R alone) switches on the calibration's
  ``input.alternation``: the models are fitted to, and the engine feeds them, a pair
  statistic of R[i] and R[i-1], so the alternation never reaches a model's memory or the
  detector: the mean, or the upper or lower of the two when the steps of the alternation's
  size while the reference strain is still (``STILL_FRACTION`` of its span within a
  window) show the alternation on one side of the signal (``strain_comp.core.chain.
  pair_branch``; the carbon-black strip), stored as ``input.pair``.
  Options ``alternation`` (true/false) and ``pair`` (mean/upper/lower) override the
  detection; the provenance records the reading (``measurement_chain``).
* **Long runs**: above ``strain_comp.offline.reduce.FIT_SAMPLE_BUDGET`` good samples the
  model is fitted on an anti-aliased reduction of the segments that keeps every reversal
  and hold (``strain_comp.offline.reduce``); everything else above, and the fit error, is
  computed on the full data. The provenance records the factor (``fit_reduction``). A
  model whose fit takes every sample in bounded memory (``Compensator.fit_full_rate``:
  creep_pi, whose low-pass states a decimation would alter) gets the full data.
* **Pooling runs** (``pool``, ``strain-comp fit --pool``): several training runs of one
  sensor are first put into one input space, as ``recalibrate --input`` zeroes and spans a
  run: R' = R_0,ref + k (R - R_0,run), each run's zero and sensitivity fitted jointly with
  one cubic through all mapped runs and anchored on the run of median sensitivity
  (``pooled_input``), where that lowers the cubic's error to at most ``POOL_GAIN`` of its
  error on the runs as recorded. Runs of one thread differ in sensitivity by up to 2x;
  pooled raw, the model fits their average and carries to none (docs/generalisation.md).
  The calibration's rest resistance and range are those of the spanned runs, so a session
  start (``recalibrate --input``) on a new run maps it into the same space.
  ``pool="raw"``: the runs as recorded. The provenance records the choice (``pooling``)
  and each run's map (``pooled_runs``).
* **Fit error**: the fitted calibration runs over the training segments through the
  engine (``training_error``); its RMSE, the fit time and the settings' sources go into
  the provenance.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from strain_comp.core.calibration import (
    PARAM_MAX,
    STRAIN_MAX,
    Calibration,
    InputSettings,
    SensorCalibration,
    ValidRange,
    provenance,
)
from strain_comp.core.calibration_file import check_calibration
from strain_comp.core.chain import PAIR_BRANCHES, alternation, pair_branch, pair_values
from strain_comp.core.direction import DirectionSettings, estimate_deadzone
from strain_comp.core.engine import GAP_RESET, Engine
from strain_comp.core.metrics import error_stats
from strain_comp.core.samples import GAP_INTERVALS, gap_for, good_mask
from strain_comp.core.tare import rest_resistance_from_reference
from strain_comp.errors import CalibrationError, FitError, InputError
from strain_comp.io.recording import load_recordings
from strain_comp.models import Normalisation, Segment, model_class
from strain_comp.offline.reduce import FIT_SAMPLE_BUDGET, reduce_segments

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

GAP_SECONDS = GAP_RESET
"""A step between good samples longer than this [s] cuts a segment (engine ``gap_reset``)."""
MIN_SEGMENT = 8
"""Segments with fewer good samples are not used for fitting."""
MIN_SPAN = 1e-9
"""Smallest span of the training resistance [ohm] and reference strain a fit accepts: a
finer one (a reference near 1e-300) is a unit mistake that the least-squares solvers
cannot resolve (LAPACK fails)."""
RANGE_MARGIN = 0.05
"""Valid range = training range widened by this fraction of its span on each side."""
HOLD_RATE_FRACTION = 0.01
"""|dS/dt| below this fraction of the 99.5th-percentile |dS/dt| counts as a hold (the high
percentile is a moving rate even when fast steps take only a few % of the record)."""
MIN_HOLD_SAMPLES = 40
"""A hold must have at least this many samples to set the dead zone."""
DEFAULT_K_SIGMA = 4.0
"""Dead zone = k sigma of the derivative noise ([EGaIn] section V.E: 3 or 4)."""
TAU_GRID = (0.0, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
"""Derivative low-pass time constants [s] tried, shortest (least lag) first."""
BURST_FRACTION = 0.25
"""Sample intervals shorter than this fraction of the median are bursts (``_tau_grid``)."""
DEADZONE_FRACTION = 0.5
"""The dead zone must stay below this fraction of the typical dR/dt while moving."""
STILL_FRACTION = 0.001
"""The reference strain is still where it moves by at most this share of its span in 1 s
(half the slowest ramp in the measured data: the fibre moves 0.2 % of its span per s)."""
POOLS = ("spanned", "raw")
"""How ``fit_sensor`` pools several runs: each run's input zero and span put onto a reference
run's first (default, module docstring), or the resistance as recorded."""
_DIRECTION_OPTIONS = ("deadzone", "k_sigma", "tau", "alternation", "pair", "fit_budget")
"""Options ``fit_sensor`` takes itself (direction detector, measurement chain, the sample
budget of a fit); the others go to the model's ``fit``."""


def parse_options(items: Iterable[str]) -> dict[str, Any]:
    """``["N=11", "mode=split", "sigmas=[0.1, 0.3]"]`` -> dict; values are parsed as YAML."""
    options: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"--option {item!r}: expected key=value")
        try:
            options[key] = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            raise InputError(f"--option {item!r}: value is not valid YAML") from None
    return options


def split_segments(t: np.ndarray, r: np.ndarray, s: np.ndarray, *,
                   gap: float = GAP_SECONDS) -> list[Segment]:
    """Good, referenced samples of one recording cut into segments (see module docstring)
    wherever the time steps back or forward by more than ``gap`` [s]."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    keep = good_mask(t, r) & np.isfinite(s)
    t, r, s = t[keep], r[keep], s[keep]
    if t.size < 2:
        return []
    step = np.diff(t)
    cuts = np.flatnonzero((step > gap) | (step < 0.0)) + 1
    bounds = np.concatenate(([0], cuts, [t.size]))
    return [Segment(t[a:b], r[a:b], s[a:b]) for a, b in pairwise(bounds)
            if b - a >= MIN_SEGMENT]


def valid_range(segments: Sequence[Segment], *, margin: float = RANGE_MARGIN) -> ValidRange:
    """Training range of R and S widened by ``margin`` x span on each side (R kept > 0)."""
    r = np.concatenate([seg.r for seg in segments])
    s = np.concatenate([seg.s for seg in segments])
    r_lo, r_hi = float(r.min()), float(r.max())
    s_lo, s_hi = float(s.min()), float(s.max())
    r_pad, s_pad = margin * (r_hi - r_lo), margin * (s_hi - s_lo)
    return ValidRange(max(r_lo - r_pad, 0.5 * r_lo), r_hi + r_pad, s_lo - s_pad, s_hi + s_pad)


def find_hold(segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray] | None:
    """(t, r) of the second half of the longest still stretch of the reference, or None."""
    rates = [np.abs(np.gradient(seg.s, seg.t)) for seg in segments]
    moving = np.concatenate(rates)
    scale = float(np.percentile(moving, 99.5)) if moving.size else 0.0
    if scale <= 0.0:
        return None
    best: tuple[int, int, int] | None = None  # (length, segment index, start)
    for index, rate in enumerate(rates):
        still = np.concatenate(([False], rate <= HOLD_RATE_FRACTION * scale, [False]))
        edges = np.flatnonzero(np.diff(still.astype(np.int8)))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            if best is None or stop - start > best[0]:
                best = (int(stop - start), index, int(start))
    if best is None or best[0] < MIN_HOLD_SAMPLES:
        return None
    length, index, start = best
    half = start + length // 2
    seg = segments[index]
    return seg.t[half:start + length], seg.r[half:start + length]


def _noise_sigma(segments: Sequence[Segment]) -> float:
    """Robust white-noise sigma of R [ohm] from second differences (smooth motion cancels).

    sigma = 1.4826 MAD(d2 R) / sqrt(6); when the MAD is zero (coarse ADC steps: most second
    differences are exactly 0) the plain standard deviation of d2 R / sqrt(6) is used.
    """
    d2 = np.concatenate([np.diff(seg.r, 2) for seg in segments if seg.r.size >= 3])
    if d2.size == 0:
        return 0.0
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    return (sigma or float(np.std(d2))) / np.sqrt(6.0)


def movement_rate(segments: Sequence[Segment]) -> float:
    """Typical |dR/dt| [ohm/s] while the reference moves: the gauge slope |dR/dS| (a line
    through all samples) times the median |dS/dt| of the moving samples (the reference is
    clean, so this is not inflated by resistance noise; on samples stamped in bursts dS/dt
    is taken on a regular grid, ``_regular_gradient``)."""
    r = np.concatenate([seg.r for seg in segments])
    s = np.concatenate([seg.s for seg in segments])
    gradient = np.gradient if _bursts(segments) is None else _regular_gradient
    rates = np.concatenate([np.abs(gradient(seg.s, seg.t)) for seg in segments])
    scale = float(np.percentile(rates, 99.5))
    moving = rates > 10 * HOLD_RATE_FRACTION * scale
    if scale <= 0.0 or not moving.any():
        return 0.0
    gain = abs(float(np.polyfit(s, r, 1)[0]))
    return gain * float(np.median(rates[moving]))


def _hold_samples(segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(t, r, source) of what nothing-moves noise looks like: the reference's longest hold,
    else white noise of the record's robust sigma at the longest segment's sample times
    (fixed seed); None for noise-free data."""
    hold = find_hold(segments)
    if hold is not None and np.ptp(hold[1]) > 0:
        return hold[0], hold[1], "hold"
    sigma = _noise_sigma(segments)
    longest = max(segments, key=lambda seg: seg.t.size)
    if sigma > 0 and longest.t.size >= 12:
        rng = np.random.default_rng(0)
        r_hold = float(np.median(longest.r)) + sigma * rng.standard_normal(longest.t.size)
        return longest.t, r_hold, "noise"
    return None


def direction_settings(segments: Sequence[Segment], options: Mapping[str, Any]) -> tuple[
        DirectionSettings, str]:
    """Dead-zone settings and their source: ``given``, ``hold``, ``noise`` or ``floor``.

    Without a ``tau`` option the derivative filter is the shortest on ``TAU_GRID`` whose
    dead zone (k sigma of the filtered derivative noise) stays below ``DEADZONE_FRACTION``
    of the typical movement rate: a raw first difference of a noisy, fast-sampled signal
    can have a 4-sigma dead zone above the slowest ramps, and the detector would never
    leave hold. When even the longest filter cannot get there, it is used anyway.
    """
    k_sigma = float(options.get("k_sigma", DEFAULT_K_SIGMA))
    if "deadzone" in options:
        deadzone = float(options["deadzone"])
        if not deadzone > 0:
            raise InputError(f"option deadzone must be > 0 ohm/s, got {deadzone}")
        tau = float(options.get("tau", 0.0))
        return DirectionSettings(deadzone=deadzone, tau=tau, k_sigma=None), "given"
    taus = [float(options["tau"])] if "tau" in options else _tau_grid(segments)
    hold = _hold_samples(segments)
    if hold is None:
        # Noise-free data (a clean simulation): a dead zone far below any real motion,
        # 1e-6 of the training R span per second of the longest segment.
        longest = max(segments, key=lambda seg: seg.t.size)
        t_span = float(longest.t[-1] - longest.t[0]) or 1.0
        r_span = float(np.ptp(np.concatenate([seg.r for seg in segments])))
        return DirectionSettings(deadzone=1e-6 * r_span / t_span, tau=taus[0],
                                 k_sigma=None), "floor"
    t_hold, r_hold, source = hold
    target = DEADZONE_FRACTION * movement_rate(segments)
    for tau in taus:
        settings = estimate_deadzone(t_hold, r_hold, k_sigma=k_sigma, tau=tau)
        if settings.deadzone <= target:
            break
    return settings, source


def _bursts(segments: Sequence[Segment]) -> float | None:
    """The median sample interval when the samples come in bursts (more than 1 % of the
    intervals below ``BURST_FRACTION`` of the median: stamps taken on arrival, as a bag's
    log time is), else None."""
    dt = np.concatenate([np.diff(seg.t) for seg in segments])
    if dt.size < 2:
        return None
    median = float(np.median(dt))
    return median if float(np.percentile(dt, 1)) < BURST_FRACTION * median else None


def _regular_gradient(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """dS/dt at the samples, from S interpolated onto a grid of the median interval (a
    burst's microseconds would turn the reference's own steps into huge rates)."""
    if t.size < 3:
        return np.zeros(t.size)
    step = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * step, step)
    if grid.size < 2:
        return np.zeros(t.size)
    return np.interp(t, grid, np.gradient(np.interp(grid, t, s), grid))


def _tau_grid(segments: Sequence[Segment]) -> list[float]:
    """``TAU_GRID``, without the filters shorter than two median sample intervals when the
    samples come in bursts (``_bursts``). A first difference over a
    burst's microseconds turns read-out noise into a derivative thousands of times its
    size (its dead zone then hides every movement, or the detector flickers); a filter of
    at least two sample intervals weights each difference by its dt and averages over the
    bursts, as a regular instrument's difference would be."""
    median = _bursts(segments)
    if median is None:
        return list(TAU_GRID)
    return [tau for tau in TAU_GRID if tau >= 2.0 * median] or [TAU_GRID[-1]]


def resistance_sign(r: np.ndarray, s: np.ndarray) -> int:
    """+1 when R rises with strain in the training data, -1 when it falls (the sign of
    their correlation; 0 correlation counts as +1). Sets ``DirectionSettings.sign``."""
    return -1 if float(np.mean((r - r.mean()) * (s - s.mean()))) < 0 else 1


def _check_options(fit: Callable[..., Any], model: str, options: Mapping[str, Any]) -> None:
    """InputError for an option that ``fit`` has no keyword for (when it names them all)."""
    params = inspect.signature(fit).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    known = [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY
             and n != "direction"]
    for key in options:
        if key not in known:
            raise InputError(f"model {model!r} has no option {key!r} "
                             f"(options: {', '.join(known + list(_DIRECTION_OPTIONS))})")


def training_error(calibration: SensorCalibration, segments: Sequence[Segment]) -> float:
    """RMSE [% strain] on the training segments through the engine's batch path.

    The engine (``strain_comp.core.engine.Engine``) is reset before every segment; it is the
    code ``evaluate``, ``replay`` and the node run, so on a training bag without gaps the
    fit error equals what ``strain-comp evaluate`` reports (the engine clamps estimates to
    the valid strain range plus its margin, which a raw model output is not).
    """
    engine = Engine(Calibration({calibration.name: calibration}))
    estimates, references = [], []
    for seg in segments:
        engine.reset()
        estimates.append(engine.run(calibration.name, seg.t, seg.r).strain)
        references.append(seg.s)
    return error_stats(np.concatenate(estimates), np.concatenate(references)).rmse


def strain_change(t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Change of the reference strain ``s`` over the second around each sample (from the
    last sample at or after t - 0.5 s to the last at or before t + 0.5 s)."""
    t = np.asarray(t, dtype=np.float64)
    lo = np.searchsorted(t, t - 0.5)
    hi = np.clip(np.searchsorted(t, t + 0.5, side="right") - 1, 0, t.size - 1)
    return s[hi] - s[lo]


def pair_side(recordings: Sequence[Recording]) -> str:
    """``strain_comp.core.chain.pair_branch`` over the training runs, still where the
    reference strain moves by at most ``STILL_FRACTION`` of its span over 1 s around a
    sample."""
    r_all, still_all = [], []
    for rec in recordings:
        if rec.s is None:
            continue
        s = np.asarray(rec.s, dtype=np.float64)
        span = float(np.nanmax(s) - np.nanmin(s)) if np.any(np.isfinite(s)) else 0.0
        moved = np.abs(strain_change(rec.t, s))
        r_all.append(np.asarray(rec.r, dtype=np.float64))
        still_all.append(np.isfinite(moved) & (moved <= STILL_FRACTION * span))
    if not r_all:
        return "mean"
    return pair_branch(np.concatenate(r_all), np.concatenate(still_all))


def slow_sample_interval(recordings: Sequence[Recording]) -> float | None:
    """The median interval [s] between the recordings' good samples when ``GAP_INTERVALS``
    of it exceed ``GAP_SECONDS`` (a slow instrument, module docstring), else None."""
    steps = [np.diff(np.asarray(rec.t, dtype=np.float64)[good_mask(rec.t, rec.r)])
             for rec in recordings]
    dt = np.concatenate(steps) if steps else np.empty(0)
    dt = dt[dt > 0.0]
    if not dt.size:
        return None
    interval = float(np.median(dt))
    return interval if GAP_INTERVALS * interval > GAP_SECONDS else None


def training_rest_resistance(recordings: Sequence[Recording], *, pair: str = "mean",
                             ) -> float | None:
    """The calibration's rest resistance [ohm]: the median over the training runs of each
    run's leading rest level (``strain_comp.core.tare.rest_resistance_from_reference``,
    the statistic an automatic tare uses at run time); None when no run starts at rest."""
    levels = [rest_resistance_from_reference(rec.t, rec.r, rec.s, pair=pair)
              for rec in recordings
              if rec.s is not None]
    found = [level for level in levels if level is not None]
    return float(np.median(found)) if found else None


def run_line(rec: Recording) -> tuple[float, float] | None:
    """(R_0, g): the least-squares line R = R_0 + g S of a run's good, referenced samples
    (its input zero [ohm] and sensitivity [ohm per strain unit]), in closed form (no LAPACK
    call to fail on a reference near 1e-300 or 1e300); None without a range of strain or a
    finite line."""
    if rec.s is None:
        return None
    ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
    s, r = np.asarray(rec.s, dtype=np.float64)[ok], np.asarray(rec.r, dtype=np.float64)[ok]
    if s.size < 2 or not np.ptp(s) > 0:
        return None
    with np.errstate(all="ignore"):
        ds, r_mean = s - s.mean(), r.mean()
        g = float(np.dot(ds, r - r_mean) / np.dot(ds, ds))
        r0 = float(r_mean - g * s.mean())
    return (r0, g) if np.isfinite(r0) and np.isfinite(g) and g != 0 else None


POOL_GAIN = 0.7
"""The per-run maps are kept where they lower the pooled cubic's RMSE to at most this share
of its RMSE on the runs as recorded (``pooled_input``; docs/generalisation.md: 0.31-0.62 on
the thread and the fibre, where pooling in one space helps, 0.82-1.25 on the carbon black
and the rig, where it does not)."""
POOL_DEGREE = 3
"""Degree of the pooled curve of strain on mapped resistance the input maps are fitted
through (``pooled_input``): the cubic model's."""
POOL_SAMPLES = 4000
"""Samples of each run (evenly thinned) the input maps are fitted on."""


def pooled_input(recordings: Sequence[Recording], pool: str = "spanned",
                 ) -> tuple[list[Recording], list[dict[str, float]], dict[str, Any]]:
    """The runs put into one input space for a pooled fit (module docstring, Pooling runs)
    and each run's map (``rest``, ``rest_calibrated``, ``span_gain``: the form of
    ``recalibrate --input``, R' = rest_calibrated + span_gain (R - rest)).

    The maps are a per-run affine nuisance fitted jointly with a pooled cubic of strain on
    mapped resistance (least squares over the maps, the cubic solved for at each step),
    started from each run's line of resistance on strain (``run_line``) and anchored on the
    run of median sensitivity (its map stays the identity), then dropped: the model is
    fitted on the mapped runs, where the maps lower the pooled cubic's RMSE to at most
    ``POOL_GAIN`` of its RMSE on the runs as recorded (runs that differ in zero and
    sensitivity, not in rate or memory). The runs as recorded (no maps) otherwise, for
    ``pool="raw"``, a single run, or runs whose lines disagree in sign. The third item says
    which, with both RMSEs (the provenance's ``pooling``)."""
    from scipy.optimize import least_squares

    if pool not in POOLS:
        raise InputError(f"--pool {pool!r}: expected one of {', '.join(POOLS)}")
    as_recorded: dict[str, Any] = {"pool": "raw"}
    if pool == "raw" or len(recordings) < 2:
        return list(recordings), [], as_recorded
    lines = [run_line(rec) for rec in recordings]
    if any(line is None for line in lines):
        return list(recordings), [], as_recorded
    found = [line for line in lines if line is not None]
    if len({np.sign(g) for _, g in found}) > 1:
        return list(recordings), [], {"pool": "raw", "why": "the runs' lines disagree in sign"}
    anchor = int(np.argsort([abs(g) for _, g in found])[(len(found) - 1) // 2])
    r0_ref, g_ref = found[anchor]
    data = []
    for rec in recordings:
        assert rec.s is not None  # run_line found a line
        ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
        step = max(1, int(ok.sum()) // POOL_SAMPLES)
        data.append((np.asarray(rec.r, dtype=np.float64)[ok][::step],
                     np.asarray(rec.s, dtype=np.float64)[ok][::step]))
    # map of run i: R' = r0_ref + k_i (R - z_i); started on the lines: z = R_0, k = g_ref / g
    start = np.array([v for i, (r0, g) in enumerate(found) if i != anchor
                      for v in (r0, g_ref / g)])
    scale = float(np.median(np.concatenate([np.abs(r) for r, _ in data])))
    s_all = np.concatenate([s for _, s in data])

    def unpack(x: np.ndarray) -> list[tuple[float, float]]:
        pairs = iter(zip(x[::2], x[1::2], strict=True))
        return [(r0_ref, 1.0) if i == anchor else next(pairs) for i in range(len(data))]

    def residual(x: np.ndarray) -> np.ndarray:  # the cubic solved for, given the maps
        mapped = np.concatenate([(r0_ref + k * (r - z)) / scale
                                 for (r, _), (z, k) in zip(data, unpack(x), strict=True)])
        return np.polyval(np.polyfit(mapped, s_all, POOL_DEGREE), mapped) - s_all

    gains = start[1::2]
    lower = np.ravel([(-np.inf, 0.2 * k) for k in gains])
    upper = np.ravel([(np.inf, 5.0 * k) for k in gains])
    fitted = least_squares(residual, start, x_scale=np.ravel([(scale, 1.0)] * gains.size),
                           bounds=(lower, upper), xtol=1e-10)
    x = fitted.x if fitted.success and np.all(np.isfinite(fitted.x)) else start
    rmse = {"raw": float(np.sqrt(np.mean(residual(np.tile([r0_ref, 1.0], gains.size)) ** 2))),
            "spanned": float(np.sqrt(np.mean(residual(x) ** 2)))}
    reading = {"curve_rmse": {k: round(v, 6) for k, v in rmse.items()}}
    if not rmse["spanned"] <= POOL_GAIN * rmse["raw"]:
        return list(recordings), [], {"pool": "raw", **reading}
    maps = unpack(x)
    out = [replace(rec, r=r0_ref + k * (np.asarray(rec.r, dtype=np.float64) - z))
           for rec, (z, k) in zip(recordings, maps, strict=True)]
    return out, [{"rest": z, "rest_calibrated": r0_ref, "span_gain": k} for z, k in maps], {
        "pool": "spanned", **reading}


def fit_sensor(recordings: Sequence[Recording], model: str, *, name: str,
               bags: Sequence[str | Path] = (), options: Mapping[str, Any] | None = None,
               budget: int = FIT_SAMPLE_BUDGET, pool: str = "spanned") -> SensorCalibration:
    """Fit ``model`` to one sensor's recordings (each with a reference strain).

    ``options`` go to the model's ``fit`` (N, M, mode, ...) except ``deadzone``, ``k_sigma``
    and ``tau``, which set the direction detector, ``alternation`` and ``pair`` (the
    measurement chain) and ``fit_budget`` (overrides ``budget``: good samples above which
    the model is fitted on a reduction, module docstring, Long runs). Raises FitError
    when the data cannot support a fit (no reference, too few good samples, no range of
    R or S). Several runs are pooled in one input space (``pool``, module docstring).
    """
    options = dict(options or {})
    cls = model_class(model)
    recordings, pool_maps, pooling = pooled_input(recordings, pool)
    segments: list[Segment] = []
    interval = slow_sample_interval(recordings)
    for rec in recordings:
        if rec.s is None:
            raise FitError(f"sensor {name!r}: recording has no strain_reference to fit to")
        segments.extend(split_segments(rec.t, rec.r, rec.s, gap=gap_for(interval)))
    if not segments:
        raise FitError(f"sensor {name!r}: no stretch of {MIN_SEGMENT} or more good samples "
                       "with a finite reference strain")
    r_all = np.concatenate([seg.r for seg in segments])
    s_all = np.concatenate([seg.s for seg in segments])
    if not (np.ptp(r_all) > 0 and np.ptp(s_all) > 0):
        raise FitError(f"sensor {name!r}: the training data span no range of resistance "
                       "or strain")
    span = valid_range(segments)
    if not max(abs(span.s_lo), abs(span.s_hi)) <= STRAIN_MAX:
        raise FitError(f"sensor {name!r}: the reference strain spans {s_all.min():.4g} to "
                       f"{s_all.max():.4g}, beyond the +/- {STRAIN_MAX:g} a calibration "
                       "holds; import it in a larger unit (microstrain to %: import-csv "
                       "--scales strain=1e-4)")
    for what, values, top in (("resistance", r_all, PARAM_MAX), ("strain", s_all, STRAIN_MAX)):
        # a span a float64 fit cannot resolve (1e-300) or values a calibration cannot hold
        if np.ptp(values) < MIN_SPAN or np.abs(values).max() > top:
            raise FitError(f"sensor {name!r}: the training {what} spans "
                           f"[{values.min():.3g}, {values.max():.3g}]: a fit needs a span of "
                           f"at least {MIN_SPAN:g} and values within +/- {top:g} "
                           "(a unit or scale mistake?)")
    r_raw = np.concatenate([np.asarray(rec.r) for rec in recordings])
    chain = alternation(r_raw)
    alternating = bool(options.get("alternation", chain.present))
    pair = str(options.get("pair", pair_side(recordings) if alternating else "mean"))
    if pair not in PAIR_BRANCHES:
        raise FitError(f"sensor {name!r}: option pair must be one of "
                       f"{', '.join(PAIR_BRANCHES)}, got {pair!r}")
    if pair != "mean" and not alternating:
        raise FitError(f"sensor {name!r}: option pair={pair} needs an alternating input "
                       "(found none; set alternation=true)")
    if alternating:  # the models learn what the engine will feed them
        segments = [Segment(seg.t, pair_values(seg.r, branch=pair), seg.s) for seg in segments]
        r_all = np.concatenate([seg.r for seg in segments])
    normalisation = Normalisation.fit(r_all, s_all)
    direction, direction_source = direction_settings(segments, options)
    direction = replace(direction, sign=resistance_sign(r_all, s_all))
    model_options = {k: v for k, v in options.items() if k not in _DIRECTION_OPTIONS}
    _check_options(cls.fit, model, model_options)
    budget = options.get("fit_budget", budget)
    if not (isinstance(budget, int) and not isinstance(budget, bool) and budget >= 1000):
        raise FitError(f"sensor {name!r}: option fit_budget must be an integer >= 1000, "
                       f"got {budget!r}")
    start = time.perf_counter()
    fit_segments, factor = ((segments, 1) if cls.fit_full_rate
                            else reduce_segments(segments, budget))
    compensator = cls.fit(fit_segments, normalisation, direction=direction, **model_options)
    fit_seconds = time.perf_counter() - start
    calibration = SensorCalibration(
        name=name, model=model, params=compensator.to_params(), normalisation=normalisation,
        valid_range=valid_range(segments), direction=direction,
        input=InputSettings(alternation=alternating, pair=pair),
        rest_resistance=training_rest_resistance(recordings, pair=pair),
        sample_interval=interval)
    try:  # the checks every reader applies, in the user's terms
        check_calibration(Calibration({name: calibration}))
    except CalibrationError as err:
        raise FitError(f"sensor {name!r}: the {model} fit cannot be used, nothing written: "
                       f"{err.field.removeprefix(f'sensors.{name}.')}: {err.problem}; try "
                       "another model (apl, cubic)") from None
    memory = memory_reading(compensator)
    rmse = training_error(calibration, segments)
    if not np.isfinite(rmse):
        raise FitError(f"sensor {name!r}: model {model!r} gives non-finite strain on its "
                       "own training data")
    calibration.provenance = provenance(
        [str(b) for b in bags], fit_rmse=rmse, n_samples=r_all.size, segments=len(segments),
        fit_seconds=round(fit_seconds, 3), direction_from=direction_source,
        measurement_chain=(chain.reading() + (f", read through the pair {pair}" if alternating
                                              else "")
                           if chain.present else "no alternation found"),
        options=model_options,
        **({"pooling": pooling} if len(bags) > 1 or pool_maps else {}),
        **({"pooled_runs": [{k: round(v, 6) for k, v in m.items()} for m in pool_maps]}
           if pool_maps else {}),
        **({"fit_reduction": {"factor": factor,
                              "samples": sum(seg.t.size for seg in fit_segments)}}
           if factor > 1 else {}),
        **({"memory": memory} if memory else {}))
    return calibration


def memory_reading(compensator: Any) -> dict[str, Any] | None:
    """What a model with memory cells (APL, PL, MPI) kept of its memory, from its fit
    report: ``memory_share`` (rounded), ``memoryless`` and the ``loop`` orientation its
    cell weights were held to; None for models without cells."""
    report = getattr(compensator, "fit_report", None)
    if not report or "memoryless" not in report:
        return None
    return {"memory_share": round(float(report["memory_share"]), 4),
            "memoryless": bool(report["memoryless"]), "loop": str(report["loop"])}


def memoryless_note(name: str, calibration: SensorCalibration) -> str | None:
    """The one-line note for a fit whose memory model ended up memoryless, else None."""
    memory = calibration.provenance.get("memory")
    if not memory or not memory.get("memoryless"):
        return None
    return (f"note: sensor {name!r}: {calibration.model} ended up memoryless (its cells give "
            f"{100 * memory['memory_share']:.2g} % of the output): on these data it is a "
            f"static map of R (the cells' sign: --option cell_weights=lead|lag|free)")


def fit_bags(paths: Sequence[str | Path], model: str, sensors: Sequence[str] | None = None,
             options: Mapping[str, Any] | None = None, *,
             report: Callable[[str], None] | None = None,
             pool: str = "spanned") -> Calibration:
    """One calibration for ``sensors`` (None or ``["all"]``: every sensor with a reference;
    one of those that cannot be fitted, e.g. a reference that is NaN throughout, is left
    out with a line to ``report``, unless none can be).

    Each sensor is fitted to its recordings from every bag that has it, pooled in one
    input space (``pool``, ``fit_sensor``). Bag problems
    (skipped chunks, unknown schemas) go to ``report``, one line each.
    """
    by_sensor: dict[str, list[tuple[str, Recording]]] = {}
    for path in paths:
        recordings, problems = load_recordings(path)
        for problem in problems:
            if report is not None:
                report(problem)
        for sensor, rec in recordings.items():
            by_sensor.setdefault(sensor, []).append((str(path), rec))
    referenced = [n for n, recs in by_sensor.items() if any(r.s is not None for _, r in recs)]
    bag_list = ", ".join(str(p) for p in paths)
    if sensors is None or "all" in sensors:
        if not referenced:
            raise InputError(f"{bag_list}: no sensor with a strain_reference topic "
                             f"(sensors found: {', '.join(by_sensor) or 'none'})")
        names = referenced
    else:
        names = list(dict.fromkeys(sensors))
        for sensor in names:
            if sensor not in by_sensor:
                raise InputError(f"sensor {sensor!r} is not in {bag_list} "
                                 f"(sensors found: {', '.join(by_sensor) or 'none'})")
            if sensor not in referenced:
                raise InputError(f"sensor {sensor!r} has no strain_reference in {bag_list}")
    calibrations = {}
    every = sensors is None or "all" in sensors
    for sensor in names:
        pairs = [(path, rec) for path, rec in by_sensor[sensor] if rec.s is not None]
        try:
            calibrations[sensor] = fit_sensor([rec for _, rec in pairs], model, name=sensor,
                                              bags=[path for path, _ in pairs],
                                              options=options, pool=pool)
        except FitError as err:
            if not every or len(names) == 1:
                raise
            if report is not None:  # "all": the sensors that can be fitted are
                report(f"not fitted: {err}")
    if not calibrations:
        raise FitError(f"{bag_list}: no sensor could be fitted")
    return Calibration(calibrations)
