"""The estimators of a sensor's correction (``strain_comp.core.correction``): the input zero
and span, and the output gain and offset (docs/design.md, ``input.zero_span``; docs/results.md,
"Pooling and the session start").
"""

from __future__ import annotations

import functools
import math
import pickle
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.base.samples import good_mask
from strain_comp.core.calibration import (
    PARAM_MAX,
    SPAN_GAIN_MAX,
    STRAIN_MAX,
    Calibration,
    SensorCalibration,
    strain_unit_words,
)
from strain_comp.core.calibration_file import loadable
from strain_comp.core.correction import Correction
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR
from strain_comp.core.tare import REST_BAND, ohms, rest_resistance_from_reference
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

FORMS = ("output", "input")
"""Where the two-point map acts: on the engine's output strain or on its input resistance."""


# The session start's numbers (docs/results.md, "Policies": what each buys, measured by
# studies/policy_ablation.py).
SETTLE_SAMPLES = 200
"""Samples at a constant resistance (at 10 Hz) before a steady output is read."""
GRID_POINTS = 201
"""Resistances of the steady-output grid over the valid range (``calibrated_resistance``)."""
STATIC_TOLERANCE = 0.01
"""A slow ramp this close to the steady outputs [share of the strain span]: a static model."""
FIT_EVALUATIONS = 80
"""Engine runs the search of a memory model's zero and span may take (0: none)."""
FIT_STEP = (0.05, 0.2)
"""The search's first steps: calibrated rest [share of the R range], log of the span gain."""
FIT_TOLERANCE = (1e-3, 1e-4)
"""The search stops under these steps [as ``FIT_STEP``] and RMSE changes [strain unit]."""
FROM_COVER = 0.1
"""``--from``: the reference must move through this share of the calibrated strain span."""
CYCLE_UP = 0.5
"""A cycle (``cycle_end``): the reference passes this share of its span above its minimum,"""
CYCLE_BACK = 0.1
"""... then returns to within this share of it."""
MIN_CYCLE_SHARE = 0.1
"""A ``--window``'s stretch must span at least this share of the calibrated strain range."""


def steady_output(cal: SensorCalibration, r: float) -> float:
    """The calibration's output after ``SETTLE_SAMPLES`` samples at a constant ``r``."""
    return _settled(Engine(Calibration({cal.name: cal})), cal.name, r)


def _settled(engine: Engine, name: str, r: float) -> float:
    """``steady_output`` of ``engine``, reset first."""
    engine.reset()
    t = 0.1 * np.arange(SETTLE_SAMPLES)
    return float(engine.run(name, t, np.full(t.size, r)).strain[-1])


def steady_curve(cal: SensorCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(resistances, steady outputs) over the valid range from the rest end, cached, read-only."""
    bare = replace(cal, input=replace(cal.input, zero_span=None))
    return _steady_curve(pickle.dumps((bare, SETTLE_SAMPLES, GRID_POINTS),
                                      protocol=pickle.HIGHEST_PROTOCOL))


CURVES_KEPT = 64
"""Most steady curves ``steady_curve`` keeps (the least recently used goes first)."""


@functools.lru_cache(maxsize=CURVES_KEPT)
def _steady_curve(key: bytes) -> tuple[np.ndarray, np.ndarray]:
    """``steady_curve`` of its pickled key."""
    bare, _, points = pickle.loads(key)  # the bytes steady_curve just made
    grid = np.linspace(bare.valid_range.r_lo, bare.valid_range.r_hi, points)
    if bare.direction.sign < 0:
        grid = grid[::-1]
    engine = Engine(Calibration({bare.name: bare}))
    curve = (grid, np.empty(grid.size))
    for i, r in enumerate(grid):
        curve[1][i] = _settled(engine, bare.name, float(r))
    for values in curve:
        values.setflags(write=False)
    return curve


def calibrated_resistance(cal: SensorCalibration, strain: float,
                          curve: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """The resistance whose steady output is ``strain``, first from the rest end."""
    grid, steady = curve if curve is not None else steady_curve(cal)
    found = crossing(grid, steady, strain)
    if found is None:
        raise InputError(f"the calibration outputs no strain of {strain:g} "
                         f"{strain_unit_words(cal.strain_unit)} in its resistance range "
                         f"(it gives {steady.min():.4g} to {steady.max():.4g})")
    return found


def crossing(grid: np.ndarray, out: np.ndarray, strain: float) -> float | None:
    """Where ``out`` first crosses ``strain`` on ``grid``, linear between its points."""
    d = out - strain
    cross = np.flatnonzero(np.sign(d[:-1]) * np.sign(d[1:]) <= 0)
    if not cross.size:
        return None
    j = int(cross[0])
    w = d[j] / (d[j] - d[j + 1]) if d[j] != d[j + 1] else 0.0
    return float(grid[j] + w * (grid[j + 1] - grid[j]))


def through(points: Sequence[tuple[float, float]], c1: float, c2: float,
            ) -> tuple[float, float, float]:
    """The input zero and span reading two (R, S) ``points`` as resistances ``c1``, ``c2``."""
    (r1, s1), (r2, s2) = points
    k = (c2 - c1) / (r2 - r1) if r2 != r1 else float("nan")
    if not (np.isfinite(k) and k > 0):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: the resistance moves "
                         "against the calibration's direction (span gain "
                         f"{k:.4g} must be > 0)")
    return r1, c1, float(k)


def span_from_points(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                     curve: tuple[np.ndarray, np.ndarray] | None = None,
                     ) -> tuple[float, float, float]:
    """The input zero and span through two (R, S) points, inverting the steady outputs."""
    (r1, s1), (r2, s2) = sorted(points, key=lambda p: p[1])
    lo, hi = SHORT_FACTOR * cal.valid_range.r_lo, OPEN_FACTOR * cal.valid_range.r_hi
    for r, s in ((r1, s1), (r2, s2)):  # the engine screens such a reading as a short or open
        if not lo < r < hi:
            raise InputError(f"--point {r:g}:{s:g}: {r:g} ohm is beyond what the engine reads "
                             f"for this sensor ({lo:.4g} to {hi:.4g} ohm: below is a short, "
                             "above an open circuit)")
    if not abs(r2 - r1) > 1e-12 * max(abs(r1), abs(r2)):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: one resistance at two "
                         "strains gives no span")
    curve = curve if curve is not None else steady_curve(cal)
    return through([(r1, s1), (r2, s2)], calibrated_resistance(cal, s1, curve),
                   calibrated_resistance(cal, s2, curve))


def points_from_first_cycle(t: np.ndarray, r: np.ndarray, s: np.ndarray, *,
                            top: float = np.inf) -> list[tuple[float, float]]:
    """(R, S) medians at a cycle's first rest and at its largest strain (at most ``top``)."""
    ok = np.isfinite(t) & np.isfinite(r) & (r > 0) & np.isfinite(s)
    t, r, s = t[ok], r[ok], s[ok]
    rest = rest_resistance_from_reference(t, r, s)
    if rest is None:
        raise InputError("recalibrate --first/--window: the cycle has no rest at its lowest "
                         "strain or its reference strain never moves")
    span = float(np.ptp(s))
    low = s <= s.min() + REST_BAND * span
    high = np.abs(s - min(float(s.max()), top)) <= REST_BAND * span
    if not high.any():
        raise InputError("recalibrate --first/--window: no sample of the cycle at a strain the "
                         "calibration outputs")
    return [(rest, float(np.median(s[low]))),
            (float(np.median(r[high])), float(np.median(s[high])))]


def apply_span(cal: SensorCalibration, span: tuple[float, float, float],
               record: Mapping[str, Any]) -> SensorCalibration:
    """``cal`` reading its input through ``span`` (replacing an older one)."""
    history = [*cal.provenance.get("recalibrations", []),
               dict(record, rest=span[0], rest_calibrated=span[1], span_gain=span[2])]
    new = replace(Correction.of(cal).with_input(*span).written(cal),
                  provenance={**cal.provenance, "recalibrations": history})
    return loadable(new, span_reading(span))


def ramp_output(cal: SensorCalibration, grid: np.ndarray) -> np.ndarray:
    """The output, without input zero and span, along a slow (10 Hz) ramp over ``grid``, back
    and over it again (a sensor at a session's start was last unloaded)."""
    bare = replace(cal, input=replace(cal.input, zero_span=None))
    path = np.concatenate([grid, grid[::-1], grid])
    return Engine(Calibration({cal.name: bare})).run(cal.name, 0.1 * np.arange(path.size),
                                                     path).strain


def branch_resistance(grid: np.ndarray, out: np.ndarray, strain: float) -> float:
    """``crossing``, else the grid point of the nearest output."""
    found = crossing(grid, out, strain)
    return float(grid[int(np.argmin(np.abs(out - strain)))]) if found is None else found


def span_of_first_cycle(cal: SensorCalibration, rec: Recording,
                        ) -> tuple[float, float, float]:
    """The input zero and span from a run's first cycle: a static map inverted at two points,
    a memory model's read on its branches (rest unloading, stretch loading), then refined."""
    if rec.s is None:
        raise InputError(f"recalibrate --input: {rec.name!r} has no reference strain")
    curve = steady_curve(cal)
    n, out = curve[0].size, ramp_output(cal, curve[0])
    span = cal.valid_range.s_hi - cal.valid_range.s_lo
    static = np.max(np.abs(out[:2 * n] - np.concatenate([curve[1], curve[1][::-1]]))) <= \
        STATIC_TOLERANCE * span  # a static map: up and back on its steady outputs
    branch = (curve[1], curve[1]) if static else (out[n:2 * n][::-1], out[2 * n:])
    points = sorted(points_from_first_cycle(rec.t, cal.input.to_ohm(rec.r), rec.s,
                                            top=float(branch[1].max())), key=lambda p: p[1])
    try:
        if static:
            try:
                return span_from_points(cal, points, curve)
            except InputError:
                pass
        start = through(points, branch_resistance(curve[0], branch[0], points[0][1]),
                        branch_resistance(curve[0], branch[1], points[1][1]))
    except InputError:  # the calibration as tared, unrefined: a refinement from there fits
        # the cycle, not the run (a loop's exact memory term lost half its gain after it)
        if static or cal.rest_resistance is None:
            raise
        tared = (points[0][0], cal.rest_resistance, 1.0)
        if not cycle_error(replace(cal, input=replace(cal.input, zero_span=tared)), rec) < \
                cycle_error(cal, rec):
            raise
        return tared
    return start if static else span_through_run(cal, rec, start)


def cycle_error(cal: SensorCalibration, rec: Recording) -> float:
    """RMSE of the engine's output over ``rec`` against its finite reference strain."""
    assert rec.s is not None
    ok = np.isfinite(rec.s)
    strain = Engine(Calibration({cal.name: cal})).run(cal.name, rec.t, rec.r).strain
    value = float(np.sqrt(np.mean((strain[ok] - rec.s[ok]) ** 2)))
    return value if np.isfinite(value) else np.inf


def span_through_run(cal: SensorCalibration, rec: Recording,
                     start: tuple[float, float, float]) -> tuple[float, float, float]:
    """The input zero and span (the rest kept) reading the cycle ``rec`` best (Nelder-Mead
    from ``start`` or the calibration as tared, kept unless the fit is lower)."""
    from scipy.optimize import minimize

    if rec.s is None or FIT_EVALUATIONS <= 0 or not np.isfinite(rec.s).any():
        return start
    rest, rest_cal, k = start
    width = cal.valid_range.r_hi - cal.valid_range.r_lo

    def error(x: np.ndarray) -> float:
        span = (rest, rest_cal + width * float(x[0]), k * float(np.exp(x[1])))
        return cycle_error(replace(cal, input=replace(cal.input, zero_span=span)), rec)

    origin = np.zeros(2)
    first = error(origin)
    if cal.rest_resistance is not None:  # the calibration as tared: a zero, no span
        tared = np.array([(cal.rest_resistance - rest_cal) / width, -np.log(k)])
        if (tared_error := error(tared)) < first:
            origin, first = tared, tared_error
    step_zero, step_gain = FIT_STEP
    simplex = origin + np.array([[0.0, 0.0], [step_zero, 0.0], [0.0, step_gain]])
    best = minimize(error, origin, method="Nelder-Mead",
                    options={"initial_simplex": simplex, "xatol": FIT_TOLERANCE[0],
                             "fatol": FIT_TOLERANCE[1], "maxfev": FIT_EVALUATIONS})
    x = best.x if np.isfinite(best.fun) and best.fun < first else origin
    return rest, rest_cal + width * float(x[0]), k * float(np.exp(x[1]))


def span_reading(span: tuple[float, float, float]) -> str:
    """The input map in words: ``input zero 1.02 -> 1.00 ohm, span gain 0.81 (...)``."""
    rest, rest_cal, k = span
    return (f"input zero {ohms((rest, rest_cal)).replace(' vs ', ' -> ')}, span gain "
            f"{k:.4g} (sensitivity {100.0 * (1.0 / k - 1.0):+.1f} %)")


Line = tuple[float, float]
"""(R_0 [ohm], g [ohm per strain unit]) of R = R_0 + g S."""


def run_line(rec: Recording) -> Line | None:
    """(R_0, g) of the least-squares line R = R_0 + g S of a run's good referenced samples."""
    # closed form: no LAPACK call to fail on a reference near 1e-300
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


def stretch_span(cal: SensorCalibration, rec: Recording) -> tuple[float, float, float]:
    """The input zero and span putting the stretch's line onto the calibration's."""
    space = cal.input.stretch_line
    assert space is not None
    own = run_line(replace(rec, r=cal.input.to_ohm(rec.r)))
    if own is None or np.sign(own[1]) != np.sign(space[1]) or not own[0] > 0:
        raise InputError(f"recalibrate --input: sensor {cal.name!r}: its resistance does not "
                         "move with the reference strain in the stretch read as the "
                         "calibration's does (no line of resistance on strain there)")
    zero_span = own[0], space[0], space[1] / own[1]  # own's line put onto the calibration's
    if not (0.0 < zero_span[0] <= PARAM_MAX
            and 1.0 / SPAN_GAIN_MAX <= zero_span[2] <= SPAN_GAIN_MAX):
        raise InputError(f"recalibrate --input: sensor {cal.name!r}: the stretch read puts "
                         f"its rest at {zero_span[0]:.4g} ohm and its sensitivity "
                         f"{1.0 / zero_span[2]:.4g} times the calibration's: no session start "
                         "of this sensor (record a load and unload of it)")
    return zero_span


def number_pair(text: str) -> tuple[float, float]:
    """``"A:B"`` -> (A, B); NaN for both where the text is no such pair."""
    a_text, sep, b_text = text.partition(":")
    try:
        return (float(a_text), float(b_text)) if sep else (math.nan, math.nan)
    except ValueError:
        return math.nan, math.nan


def parse_point(text: str) -> tuple[float, float]:
    """``"R:S"`` (ohm, % strain) -> (R, S); InputError naming the flag otherwise."""
    r, s = number_pair(text)
    if not (np.isfinite(r) and np.isfinite(s) and r > 0):
        raise InputError(f"--point {text!r}: expected R:S with R > 0 ohm and S in the "
                         "calibration's strain unit (% unless it says otherwise)")
    if not abs(s) <= STRAIN_MAX:
        raise InputError(f"--point {text!r}: the strain must be within +/- {STRAIN_MAX:g}")
    return r, s


def map_from_points(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                    ) -> tuple[float, float]:
    """(a, b) through two (R [ohm], S) points, by the steady outputs there."""
    (r1, s1), (r2, s2) = points
    lo, hi = cal.valid_range.r_lo, cal.valid_range.r_hi
    for r, s in points:
        if not lo <= r <= hi:
            raise InputError(f"--point {r:g}:{s:g}: {r:g} ohm is outside the calibration's "
                             f"resistance range [{lo:.4g}, {hi:.4g}] ohm, where its output is "
                             "clamped; a sensor whose resistance moved that far needs a tare "
                             "(--tare auto, the node's ~/tare) or a new fit")
    o1, o2 = steady_output(cal, r1), steady_output(cal, r2)
    if not abs(o2 - o1) > 1e-9 * max(1.0, abs(o1)):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: the calibration gives "
                         f"the same strain ({o1:.4g} %) at both resistances")
    a = (s2 - s1) / (o2 - o1)
    return a, s1 - a * o1


def map_from_pairs(estimate: np.ndarray, reference: np.ndarray, *,
                   span: float | None = None) -> tuple[float, float]:
    """(a, b) of reference ~ a estimate + b by least squares over the finite pairs."""
    ok = np.isfinite(estimate) & np.isfinite(reference)
    if ok.sum() < 2 or not np.ptp(estimate[ok]) > 0:
        raise InputError(f"recalibrate --from: the bag gives {int(ok.sum())} scored samples "
                         "(at least two needed) or no range of estimated "
                         "strain")
    if span is not None and not np.ptp(reference[ok]) >= FROM_COVER * span:
        raise InputError(f"recalibrate --from: the reference moves through "
                         f"{np.ptp(reference[ok]):.4g} of the calibrated span {span:.4g}; a "
                         f"gain needs a stretch of at least {FROM_COVER:.0%} of it")
    a, b = np.polyfit(estimate[ok], reference[ok], 1)
    return float(a), float(b)


def apply_map(cal: SensorCalibration, a: float, b: float, record: Mapping[str, Any],
              ) -> SensorCalibration:
    """``cal`` whose output is a x (old output) + b, with ``record`` in its provenance."""
    if not (np.isfinite(a) and np.isfinite(b) and a > 0):
        raise InputError(f"recalibration of {cal.name!r}: gain {a:.4g} must be finite and "
                         "> 0 (its output falls where the known strain rises: the "
                         "calibration reads this sensor against its direction)")
    history = [*cal.provenance.get("recalibrations", []), dict(record, gain=a, offset=b)]
    new = replace(Correction.of(cal).with_output(a, b).written(cal),
                  provenance={**cal.provenance, "recalibrations": history})
    return loadable(new, reading(a, b, unit=cal.strain_unit))


def reading(a: float, b: float, *, unit: str = "%") -> str:
    """The map in words: ``output gain 1.22 (sensitivity -18.0 %), offset +0.42 % strain``."""
    return (f"output gain {a:.4g} (sensitivity {100.0 * (1.0 / a - 1.0):+.1f} %), "
            f"offset {b:+.3g} {strain_unit_words(unit)}")
