"""The start of a session (``strain-comp start``) and ``recalibrate``: the calibration stretch
found, and the estimators of the correction (``core.correction``) the calibration's fit chose
(docs/results.md, "Pooling and the session start")."""

from __future__ import annotations

import functools
import math
import pickle
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.base.samples import good_mask
from strain_comp.core.calibration import (
    PARAM_MAX,
    SPAN_GAIN_MAX,
    STRAIN_MAX,
    Calibration,
    SensorCalibration,
    expected_words,
    strain_unit_words,
)
from strain_comp.core.calibration_file import loadable
from strain_comp.core.correction import Correction
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR, fitted_rest
from strain_comp.core.tare import REST_BAND, ohms, rest_resistance_from_reference
from strain_comp.errors import InputError, StrainCompError
from strain_comp.offline.evaluate import evaluate_recordings

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
    ok = good_mask(t, r) & np.isfinite(s)
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
    """The output, no input zero and span, along a slow (10 Hz) ramp over ``grid``, back, over."""
    # back and over again: a sensor at a session's start was last unloaded
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
    """The input zero and span from a run's first cycle: through two points, or on the branches."""
    assert rec.s is not None  # recalibrate_recordings reads referenced runs only
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
    """The input zero and span (the rest kept) reading ``rec`` best, by Nelder-Mead."""
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


def run_line(t: np.ndarray, r: np.ndarray, s: np.ndarray | None) -> Line | None:
    """(R_0, g) of the least-squares line R = R_0 + g S of a run's good referenced samples."""
    # closed form: no LAPACK call to fail on a reference near 1e-300
    if s is None:
        return None
    ok = good_mask(t, r) & np.isfinite(s)
    s, r = np.asarray(s, dtype=np.float64)[ok], np.asarray(r, dtype=np.float64)[ok]
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
    own = run_line(rec.t, cal.input.to_ohm(rec.r), rec.s)
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


Window = tuple[float, float]
"""(START, END) seconds after a run's start of the stretch read (START 0: ``--first END``)."""
SPACES = ("joint", "stretch")
"""The session starts of a pooled fit (``choose_space``)."""

RECORD = ("record one stretch and back as a warm-up, then the calibration stretch and back, "
          "to about the largest strain you will use, each from rest")
"""What a start recording holds (README, "At the start of a session")."""


@dataclass(frozen=True)
class StartRecord:
    """What the session start did on one sensor."""

    sensor: str
    window: Window
    """The stretch read, (START, END) seconds after the recording's start."""
    correction: str
    """The correction made, in words."""
    rmse: float
    """The started calibration's RMSE on the stretch [strain unit]."""
    unit: str
    expected: str | None
    """The error the calibration expects on a new session, in words (None: not measured)."""

    def line(self) -> str:
        """``s1: stretch 45-95 s, input zero ...; RMSE 0.81 % strain on the stretch (...)``."""
        tail = "" if self.expected is None else f" ({self.expected})"
        return (f"{self.sensor}: stretch {self.window[0]:.4g}-{self.window[1]:.4g} s, "
                f"{self.correction}; RMSE {self.rmse:.3g} {strain_unit_words(self.unit)} on "
                f"the stretch{tail}")


@dataclass
class Started:
    """A calibration after the session start, and what was done on each sensor."""

    calibration: Calibration
    window: Window | None
    """The stretch read (None: the start was refused, ``diagnosis.session``)."""
    records: list[StartRecord] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    """Steps not made (and why) and the fallback to the first stretch, one line each."""
    steps: list[str] = field(default_factory=list)
    """The forms made on some sensor (``input``, ``output``), in order."""

    def lines(self) -> list[str]:
        """One line per sensor (``StartRecord.line``)."""
        return [r.line() for r in self.records]


def stretch_of(t: np.ndarray, s: np.ndarray, strain_range: float, source: str,
               ) -> tuple[Window, Window | None]:
    """(first stretch, the calibration stretch after it or None) of a start recording."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(s)
    tt, ss = t[ok], s[ok]
    if ss.size < 3 or not np.ptp(ss) >= MIN_CYCLE_SHARE * strain_range:
        raise InputError(f"{source}: its reference strain makes no stretch and return (it "
                         f"moves through {np.ptp(ss) if ss.size else 0.0:.3g} of the "
                         f"calibrated {strain_range:.3g}): {RECORD}")
    lo, span = float(ss.min()), float(np.ptp(ss))
    top = int(np.argmax(ss))
    back = ss[top:] < lo + CYCLE_BACK * span
    if not back.any():
        if cycle_end(tt, ss) is None and ss[-1] > lo + CYCLE_UP * span:
            raise InputError(f"{source} ends {tt[-1] - tt[0]:.4g} s in, during its first "
                             f"stretch: it is shorter than the warm-up; {RECORD}")
        raise InputError(f"{source}: the reference never came back to rest after its "
                         f"largest strain ({ss.max():.4g}, at {tt[top] - tt[0]:.4g} s): "
                         f"{RECORD}")
    first = first_cycle(t, s)
    assert first is not None  # the reference moves
    found = calibration_stretch(t, s)
    second = None if found is None or found[0] == 0.0 else found
    if second is not None:
        inside = (tt >= tt[0] + second[0]) & (tt <= tt[0] + second[1])
        if not stretch_and_return(ss[inside], strain_range):
            second = None
    return (0.0, first), second


def start(calibration: Calibration, recordings: Mapping[str, Recording], *,
          window: Window | None = None, sensors: Sequence[str] | None = None,
          source: str = "the recording", first: float | None = None) -> Started:
    """The session start on the stretch found (or ``window``, or the first ``first`` s)."""
    names = [n for n, rec in recordings.items() if n in calibration.sensors
             and rec.s is not None and not (sensors and n not in sensors)]
    _calibrated(calibration, sensors)
    if not names:
        raise InputError(f"{source} holds no strain reference of "
                         f"{', '.join(sensors or calibration.sensors)}: record the start "
                         "with the reference strain")
    used = {n: rec for n, rec in recordings.items() if n in names}
    lead = used[names[0]]
    assert lead.s is not None
    vr = calibration.sensors[names[0]].valid_range
    if first is not None:
        made = _made(calibration, used, (0.0, float(first)), source, given=None)
    elif window is not None:
        made = _made(calibration, used, window, source, given=True)
    else:
        made = _found(calibration, used, stretch_of(lead.t, lead.s, vr.s_hi - vr.s_lo,
                                                    source), source)
    started, steps, notes, used_window = made
    for name, taken in steps.items():
        if not taken:
            raise InputError(f"sensor {name!r}: no correction can be made on the stretch at "
                             f"{used_window[0]:.4g}-{used_window[1]:.4g} s of {source} "
                             f"({'; '.join(notes) or 'no step made'}): {RECORD}")
    out = Started(started, used_window, notes=notes,
                  steps=[f for f in ("input", "output") if any(f in v for v in steps.values())])
    cut = head(used, used_window[1]) if used_window[0] == 0.0 else window_of(
        used, used_window, calibration, source)
    scored = evaluate_recordings(cut, started, tare="calibration").sensors
    for name in names:
        cal = started.sensors[name]
        old = len(calibration.sensors[name].provenance.get("recalibrations", []))
        words = [span_reading((r["rest"], r["rest_calibrated"], r["span_gain"]))
                 if "span_gain" in r else reading(r["gain"], r["offset"], unit=cal.strain_unit)
                 for r in cal.provenance.get("recalibrations", [])[old:]]
        rmse = float(scored[name].stats.rmse) if name in scored else float("nan")
        out.records.append(StartRecord(name, used_window, ", ".join(words), rmse,
                                       cal.strain_unit, expected_words(cal)))
    return out


def start_or_keep(calibration: Calibration, recordings: Mapping[str, Recording], *,
                  window: Window | None = None) -> Started:
    """``start``, or the calibration as it is (the refusal as its note) where refused."""
    try:
        return start(calibration, recordings, window=window)
    except InputError as err:
        return Started(calibration, None, notes=[str(err)])


def started_error(cal: SensorCalibration, rec: Recording) -> tuple[Calibration, float]:
    """``cal`` started on a run left out (``start_or_keep``) and its RMSE there (NaN: none)."""
    started = Calibration({cal.name: cal})
    try:
        started = start_or_keep(started, {cal.name: rec}).calibration
        ev = evaluate_recordings({cal.name: rec}, started, tare="calibration")
        return started, float(ev.sensors[cal.name].stats.rmse)
    except StrainCompError:
        return started, float("nan")


def _why(note: str) -> str:
    """A step's refusal in the user's terms: the command and field names dropped."""
    step, _, why = note.partition(" not made: ")
    for prefix in ("recalibrate --input: ", "recalibrate --from: ", "recalibrate: "):
        why = why.removeprefix(prefix)
    why = re.sub(r"^--point \S+ and \S+: ", "", why)
    return f"{step} not made: {why}" if why else note


Made = tuple[Calibration, dict[str, list[str]], list[str], Window]
"""A session start on one stretch (``_made``)."""


def _found(calibration: Calibration, recordings: Mapping[str, Recording],
           stretches: tuple[Window, Window | None], source: str) -> Made:
    """The start on the second stretch, or the first where that is missing or takes fewer steps."""
    first, second = stretches
    made = None if second is None else _made(calibration, recordings, second, source)
    if made is not None and all(len(steps) == len(session_forms(calibration.sensors[n]))
                                for n, steps in made[1].items()):
        return made
    at_first = _made(calibration, recordings, first, source, given=None)
    if made is not None and sum(map(len, at_first[1].values())) <= \
            sum(map(len, made[1].values())):
        return made
    if made is not None and second is not None:
        at_first[2].append(f"the stretch at {second[0]:.4g}-{second[1]:.4g} s took fewer "
                           "steps than the first: the first used")
    return at_first


def _made(calibration: Calibration, recordings: Mapping[str, Recording], span: Window,
          source: str, *, given: bool | None = False) -> Made:
    """Each step (``session_forms``) made on ``span``, checked first (``given``: a --window)."""
    try:
        if given is not None:
            window_of(recordings, span, calibration, source)
    except InputError as err:
        if given:
            raise
        raise InputError(f"{source}: the stretch found at {span[0]:.4g}-{span[1]:.4g} s: "
                         f"{str(err).partition(': ')[2]}; {RECORD}") from None
    steps: dict[str, list[str]] = {n: [] for n in recordings if n in calibration.sensors}
    notes = []
    head = span[0] == 0.0
    for form in ("input", "output"):
        sensors = [n for n in steps if form in session_forms(calibration.sensors[n])]
        if not sensors:
            continue
        try:
            calibration, _ = recalibrate_recordings(  # the input form reads no tare
                calibration, recordings, form=form, sensors=sensors,
                first=span[1] if head else None, span=None if head else span, source=source)
        except StrainCompError as err:
            notes.append(_why(f"the {form} step not made: {err}"))
            continue
        for name in sensors:
            steps[name].append(form)
    return calibration, steps, notes, span

# The stretch a session start reads (``recalibrate --first``, ``--window``, ``start``).

FIRST_CYCLE_CAP = 0.4
"""The first cycle is at most this share of a run (a run that never returns to rest)."""


def cycle_end(t: np.ndarray, s: np.ndarray) -> float | None:
    """Seconds from the first sample to the end of the first stretch and return of ``s``."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    origin = _origin(t)
    ok = np.isfinite(t) & np.isfinite(s)
    t, s = t[ok], s[ok]
    if t.size < 2 or origin is None:
        return None
    lo, hi = float(s.min()), float(s.max())
    if not hi > lo:
        return None
    up = np.flatnonzero(s > lo + CYCLE_UP * (hi - lo))
    if not up.size:
        return None
    back = np.flatnonzero(s[up[0]:] < lo + CYCLE_BACK * (hi - lo))
    return float(t[up[0] + back[0]] - origin) if back.size else None


def _origin(t: np.ndarray) -> float | None:
    """The first finite sample time, where a run's seconds count from."""
    finite = t[np.isfinite(t)]
    return float(finite[0]) if finite.size else None


def stretch_and_return(s: np.ndarray, strain_range: float) -> bool:
    """True for a load and unload over ``MIN_CYCLE_SHARE`` of ``strain_range``."""
    s = np.asarray(s, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size < 3 or not np.ptp(s) >= MIN_CYCLE_SHARE * strain_range:
        return False
    low = s <= s.min() + CYCLE_UP * np.ptp(s)
    top = int(np.argmax(s))
    return bool(low[:top].any() and low[top:].any())


def parse_window(text: str) -> tuple[float, float]:
    """``"START:END"`` (seconds from a bag's start) -> (START, END); InputError otherwise."""
    start, end = number_pair(text)
    if not (np.isfinite(start) and np.isfinite(end) and start >= 0):
        raise InputError(f"--window {text!r}: expected START:END in seconds from the bag's "
                         "start, START >= 0")
    if not end > start:
        raise InputError(f"--window {text!r}: END must be after START")
    return start, end


def head(recordings: Mapping[str, Recording], seconds: float | None,
         ) -> dict[str, Recording]:
    """Each recording's first ``seconds`` (all of it when None): ``window`` (0, seconds)."""
    if seconds is None:  # > 0 otherwise: checked where the user gives it (api.inputs)
        return dict(recordings)
    return {name: cut(rec, 0.0, seconds) for name, rec in recordings.items()}


def cut(rec: Recording, start: float, end: float) -> Recording:
    """The samples of ``rec`` from ``start`` to ``end`` seconds after its first sample."""
    if not rec.t.size:
        return rec
    a = int(np.searchsorted(rec.t, rec.t[0] + start, side="left"))
    b = int(np.searchsorted(rec.t, rec.t[0] + end, side="right"))
    return replace(rec, t=rec.t[a:b], r=rec.r[a:b], s=None if rec.s is None else rec.s[a:b],
                   temperature=None if rec.temperature is None else rec.temperature[a:b])


def window_of(recordings: Mapping[str, Recording], span: tuple[float, float],
           calibration: Calibration, source: str = "the bag") -> dict[str, Recording]:
    """Each referenced recording up to ``span[1]``, its reference NaN before ``span[0]``."""
    # the warm-up kept: a memory model enters the window in the state it left
    start, end = span
    out = {}
    for name, rec in recordings.items():
        if rec.s is None or not rec.t.size:
            continue
        length = float(rec.t[-1] - rec.t[0])
        if end > length + float(np.median(np.diff(rec.t)) if rec.t.size > 1 else 0.0):
            raise InputError(f"--window {start:g}:{end:g}: {source} has {length:.4g} s of "
                             f"sensor {name!r}, the window runs beyond it")
        part = cut(rec, start, end)
        vr = calibration.sensors[name].valid_range
        if part.s is None or not stretch_and_return(part.s, vr.s_hi - vr.s_lo):
            raise InputError(f"--window {start:g}:{end:g}: the reference strain of {name!r} "
                             f"makes no stretch and return in it (record a load and unload "
                             f"there)")
        whole = cut(rec, 0.0, end)
        assert whole.s is not None
        out[name] = replace(whole, s=np.where(whole.t < rec.t[0] + start, np.nan, whole.s))
    return out


def first_cycle(t: np.ndarray, s: np.ndarray) -> float | None:
    """Seconds to the end of a run's first load and unload, at most ``FIRST_CYCLE_CAP``."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(s)
    if ok.sum() < 2 or not np.percentile(s[ok], 99) > np.percentile(s[ok], 1):
        return None
    finite = t[np.isfinite(t)]
    cap = FIRST_CYCLE_CAP * float(finite[-1] - finite[0])
    end = cycle_end(t, s)
    return cap if end is None else min(end, cap)


def calibration_stretch(t: np.ndarray, s: np.ndarray) -> tuple[float, float] | None:
    """(START, END) seconds of the second load and unload, else the first (START 0)."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    first = first_cycle(t, s)
    if first is None:
        return None
    origin = _origin(t)
    assert origin is not None  # first_cycle found finite samples
    rest = t >= origin + first
    end = cycle_end(t[rest], s[rest]) if rest.sum() > 1 else None
    if end is None:
        return 0.0, first
    start = float(t[rest][0] - origin)
    return start, start + end


# The steps of a session start, and ``recalibrate`` from a recording or two points.

def session_forms(cal: SensorCalibration) -> tuple[str, ...]:
    """The steps of a session start on a sensor: input, then output unless a stretch line."""
    return ("input",) if cal.input.stretch_line is not None else ("input", "output")


def _check_named(calibration: Calibration, recordings: Mapping[str, Recording],
                 sensors: Sequence[str] | None, source: str) -> None:
    """InputError for a sensor named (``--sensor``) that the calibration or the run lacks."""
    _calibrated(calibration, sensors)
    for name in sensors or ():
        if name not in recordings or recordings[name].s is None:
            raise InputError(f"recalibrate --sensor {name}: {source or 'the data'} holds no "
                             "recording of it with a strain reference")


def recalibrate_recordings(calibration: Calibration, recordings: Mapping[str, Recording], *,
                           form: str = "output", first: float | None = None,
                           sensors: Sequence[str] | None = None, tare: str = "calibration",
                           source: str = "", span: tuple[float, float] | None = None,
                           ) -> tuple[Calibration, list[str]]:
    """``recalibrate --from`` on the first ``first`` seconds or ``span`` of recordings."""
    if span is not None and first is not None:
        raise InputError("recalibrate: give --first or --window, not both")
    _check_named(calibration, recordings, sensors, source)
    if span is not None:
        chosen = {n: r for n, r in recordings.items()
                  if n in calibration.sensors and not (sensors and n not in sensors)}
        recs = window_of(chosen, span, calibration, source or "the bag")
        where = f"{source}, {span[0]:g} to {span[1]:g} s"
    else:
        recs = head(recordings, first)
        where = f"{source}{'' if first is None else f', first {first:g} s'}"
    out = dict(calibration.sensors)
    lines = []
    record = {"from": source, "first": first, "window": None if span is None else list(span)}
    if form == "input":
        for name, rec in recs.items():
            if name not in calibration.sensors or rec.s is None or (sensors and
                                                                     name not in sensors):
                continue
            cal = calibration.sensors[name]
            by_line = cal.input.stretch_line is not None
            zero_span = (stretch_span(cal, rec) if by_line
                         else span_of_first_cycle(cal, rec))
            out[name] = apply_span(cal, zero_span, record)
            lines.append(f"{name}: {span_reading(zero_span)} (from {where}"
                         + ("; the stretch's line put onto the calibration's: the whole "
                            "session start, no output step)" if by_line else ")"))
        if not lines:
            raise InputError(f"recalibrate: {source or 'the data'} has no calibrated sensor "
                             "with a strain_reference")
        return Calibration(out), lines
    result = evaluate_recordings(recs, calibration, tare=tare)
    for name, ev in result.sensors.items():
        if sensors and name not in sensors:
            continue
        a, b = map_from_pairs(ev.estimate[ev.scored], ev.reference[ev.scored],
                              span=fitted_rest(calibration.sensors[name].valid_range)[1])
        out[name] = apply_map(out[name], a, b, {"from": source, "tare": tare, **record})
        lines.append(f"{name}: {reading(a, b, unit=ev.unit)} (from {where}, "
                     f"{int(ev.scored.sum())} samples)")
    return Calibration(out), lines


def _calibrated(calibration: Calibration, sensors: Sequence[str] | None) -> None:
    """InputError for a sensor of ``sensors`` the calibration lacks."""
    for name in sensors or ():
        if name not in calibration.sensors:
            raise InputError(f"sensor {name!r} is not in the calibration (its sensors: "
                             f"{', '.join(calibration.sensors)})")


def one_sensor(calibration: Calibration, sensors: Sequence[str] | None, what: str) -> str:
    """The one sensor ``sensors`` names, else the calibration's only one; InputError otherwise."""
    names = list(sensors or calibration.sensors)
    if len(names) != 1:
        raise InputError(f"{what}: name one sensor (the calibration has "
                         f"{', '.join(calibration.sensors)})")
    _calibrated(calibration, names)
    return names[0]


def recalibrate(calibration: Calibration, *, points: Sequence[tuple[float, float]] = (),
                sensors: Sequence[str] | None = None, form: str = "output",
                ) -> tuple[Calibration, list[str]]:
    """``recalibrate --point``: the calibration through two known points on one sensor."""
    if len(points) != 2:
        raise InputError(f"recalibrate needs exactly two --point R:S, got {len(points)}")
    name = one_sensor(calibration, sensors, "recalibrate --point")
    cal, record = calibration.sensors[name], {"points": [list(p) for p in points]}
    if form == "input":
        span = span_from_points(cal, points)
        new, words = apply_span(cal, span, record), span_reading(span)
    else:
        a, b = map_from_points(cal, points)
        new, words = apply_map(cal, a, b, record), reading(a, b, unit=cal.strain_unit)
    return (Calibration({**calibration.sensors, name: new}),
            [f"{name}: {words} (through {len(points)} points)"])


Fit = Callable[[Sequence["Recording"]], SensorCalibration]
"""Fits the choice's model (the cubic) on runs pooled with the stretch line."""


def choose_space(recordings: Sequence[Recording], fit: Fit) -> tuple[str, dict[str, Any]]:
    """The session start of a pooled fit (``joint``, ``stretch``) scoring lower on runs left out."""
    errors: dict[str, list[float]] = {space: [] for space in SPACES}
    for j, held in enumerate(recordings):
        rest = [rec for i, rec in enumerate(recordings) if i != j]
        try:
            cal = fit(rest)
        except StrainCompError:
            continue
        if cal.input.stretch_line is None:
            continue
        fold = {space: started_error(cal if space == "stretch" else replace(
            cal, input=replace(cal.input, stretch_line=None)), held)[1] for space in SPACES}
        if all(np.isfinite(v) for v in fold.values()):
            for space, value in fold.items():
                errors[space].append(value)
    measured = {space: float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")
                for space, v in errors.items()}
    chosen = SPACES[1] if measured[SPACES[1]] < measured[SPACES[0]] else SPACES[0]
    return chosen, {"left_out_rmse": {k: round(v, 6) if np.isfinite(v) else None
                                      for k, v in measured.items()},
                    "runs_left_out": len(errors[SPACES[0]])}
