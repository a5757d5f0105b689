"""Two-point recalibration of any model: an output gain and offset through known strains.

The spike-decay paper (Lee et al., spike_decay seed) recalibrates its output map f through
two known strains; here the same is done for every model, on the engine's output:

    S_new = a S_out + b

with (a, b) through two points (R_i, S_i), S_out(R_i) being the calibration's steady output
at the constant resistance R_i (the engine run for ``SETTLE_SAMPLES`` samples at R_i, so a
memory model has settled), or by least squares over a bag with a reference strain (the
engine's output over its used samples, each run tared as asked).

One mechanism: the map is stored as effect terms (``strain_comp.core.effects``), which the
engine applies identically in step, run, replay, evaluate, diagnose and the node. With
S_corrected = S_hat - sum c_j g_j, the new output a S_corrected + b is S_hat minus
``recalibration_gain`` (kind ``strain_level``, power 1, coef 1 - a), minus
``recalibration_offset`` (kind ``offset``, coef -b), with every existing coefficient scaled
by a. A second recalibration composes with the first (the coefficients add).
Limits: ``strain_level`` reads the engine's estimate clamped to the valid strain range, so
the map is exact inside that range.

The input form (``form="input"``, ``recalibrate --input``) corrects the resistance instead,
as one zeroes and spans a gauge: R' = R_rest,cal + k (R - R_rest,run), stored as the
calibration's ``input.zero_span`` (``strain_comp.core.calibration.InputSettings``) and
applied by the engine before the model, so the model's memory, its range flag and the
effect terms that read resistance all see corrected resistance. Through two points
(R_i, S_i): R'_i is the calibrated resistance whose steady output is S_i
(``calibrated_resistance``, the steady output inverted on a grid over the valid range),
k = (R'_2 - R'_1) / (R_2 - R_1), R_rest,run = R_1. From a bag's first ``first`` seconds
(the first load and unload of a session): point 1 is the first rest (reference strain
within ``REST_BAND`` of its minimum, ``rest_resistance_from_reference``), point 2 the
samples within ``REST_BAND`` of the reference's maximum (medians of R and S). The measured
points may lie outside the calibrated resistance range: a sensor that became more
sensitive is what the input form is for. A memory model (one that does not follow its
steady outputs along a slow ramp, ``follows_steady_curve``) is not on its held map in
use: its rest point is read on its unloading branch and the stretch on its loading branch
(``branches``, ``span_on_branches``), and the span is then refined by least squares of
the engine's output over the cycle (``span_through_run``); a static model's point whose
strain its held map never outputs is read at the map's nearest output
(``span_of_first_cycle``). A new input form replaces an older one (both map measured
resistance); the output gain and offset are kept.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import (
    STRAIN_MAX,
    Calibration,
    SensorCalibration,
    strain_unit_words,
)
from strain_comp.core.calibration_file import check_calibration
from strain_comp.core.effects import RECALIBRATION_TERMS
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR
from strain_comp.core.tare import REST_BAND, ohms, rest_resistance_from_reference
from strain_comp.core.tracking import fitted_rest
from strain_comp.errors import CalibrationError, InputError
from strain_comp.io.recording import load_recordings
from strain_comp.offline.evaluate import evaluate_recordings

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

FORMS = ("output", "input")
"""Where the two-point map acts: on the engine's output strain or on its input resistance."""
EXTEND = 0.1
"""A strain this share of the output span beyond the steady outputs is still inverted."""
GRID_POINTS = 201
"""Resistances of the steady-output grid that ``calibrated_resistance`` inverts."""
SETTLE_SAMPLES = 200
"""Samples at a constant resistance (at 10 Hz) before the output is read."""
STATIC_TOLERANCE = 0.01
"""Share of the strain span within which a model's ramp equals its steady outputs."""
SPAN_FIT_EVALUATIONS = 80
"""Engine runs over the first cycle the input zero and span from a recording may take."""
SPAN_FIT_MIN_SAMPLES = 20
"""Fewer scored samples in the first cycle: the two-point span is kept as it is."""
GAIN_NAME, OFFSET_NAME = RECALIBRATION_TERMS


def parse_point(text: str) -> tuple[float, float]:
    """``"R:S"`` (ohm, % strain) -> (R, S); InputError naming the flag otherwise."""
    r_text, sep, s_text = text.partition(":")
    try:
        r, s = float(r_text), float(s_text)
    except ValueError:
        r, s = float("nan"), float("nan")
    if not sep or not (np.isfinite(r) and np.isfinite(s) and r > 0):
        raise InputError(f"--point {text!r}: expected R:S with R > 0 ohm and S in the "
                         "calibration's strain unit (% unless it says otherwise)")
    if not abs(s) <= STRAIN_MAX:
        raise InputError(f"--point {text!r}: the strain must be within +/- {STRAIN_MAX:g}")
    return r, s


def steady_output(cal: SensorCalibration, r: float) -> float:
    """The calibration's output [%] after ``SETTLE_SAMPLES`` samples at constant ``r``."""
    engine = Engine(Calibration({cal.name: cal}))
    t = 0.1 * np.arange(SETTLE_SAMPLES)
    return float(engine.run(cal.name, t, np.full(t.size, r)).strain[-1])


def map_from_points(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                    ) -> tuple[float, float]:
    """(a, b) through two (R [ohm], S [%]) points."""
    if len(points) != 2:
        raise InputError(f"recalibrate needs exactly two --point R:S, got {len(points)}")
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


def steady_curve(cal: SensorCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(resistances [ohm], steady outputs) on ``GRID_POINTS`` resistances over the valid
    range, from the rest end (the low end for a sensor whose R rises with strain), read
    by the models directly (an existing input zero and span left out: the resistances are
    the calibrated ones)."""
    bare = replace(cal, input=replace(cal.input, zero_span=None))
    grid = np.linspace(cal.valid_range.r_lo, cal.valid_range.r_hi, GRID_POINTS)
    if cal.direction.sign < 0:
        grid = grid[::-1]
    return grid, np.array([steady_output(bare, float(r)) for r in grid])


def calibrated_resistance(cal: SensorCalibration, strain: float,
                          curve: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """The resistance [ohm] whose steady output through ``cal`` is ``strain``: the first
    crossing from the rest end of ``steady_curve``, interpolated linearly; a strain just
    beyond what the range outputs (within ``EXTEND`` of the output span: the fit's own
    error at the range's ends) extends the end segment. InputError when no resistance
    gives that strain."""
    grid, steady = curve if curve is not None else steady_curve(cal)
    out = steady - strain
    cross = np.flatnonzero(np.sign(out[:-1]) * np.sign(out[1:]) <= 0)
    if cross.size:
        j = int(cross[0])
    else:
        j = 0 if abs(out[0]) < abs(out[-1]) else GRID_POINTS - 2
        if not abs(out[j + (j > 0)]) <= EXTEND * np.ptp(out):
            raise InputError(f"the calibration outputs no strain of {strain:g} "
                             f"{strain_unit_words(cal.strain_unit)} in its resistance range "
                             f"(it gives {steady.min():.4g} to {steady.max():.4g})")
    if out[j] == out[j + 1]:
        return float(grid[j])
    w = out[j] / (out[j] - out[j + 1])
    return float(grid[j] + w * (grid[j + 1] - grid[j]))


def span_from_points(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                     curve: tuple[np.ndarray, np.ndarray] | None = None,
                     ) -> tuple[float, float, float]:
    """The input zero and span (rest, rest_calibrated, k) through two measured (R, S)
    points, the first at rest (or the smaller strain)."""
    if len(points) != 2:
        raise InputError(f"recalibrate needs exactly two --point R:S, got {len(points)}")
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
    c1, c2 = calibrated_resistance(cal, s1, curve), calibrated_resistance(cal, s2, curve)
    k = (c2 - c1) / (r2 - r1)
    if not (np.isfinite(k) and k > 0):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: the resistance moves "
                         "against the calibration's direction (span gain "
                         f"{k:.4g} must be > 0)")
    return r1, c1, float(k)


def points_from_first_cycle(t: np.ndarray, r: np.ndarray, s: np.ndarray, *,
                            top: float = np.inf) -> list[tuple[float, float]]:
    """(R, S) at the first rest and at a known stretch of a run's first cycle (``t``,
    measured ``r`` [ohm], reference ``s``): the stretch is the largest strain of the cycle,
    or ``top`` (the largest the calibration outputs) when lower; medians of the samples
    within ``REST_BAND`` of the span of each. InputError when it does not rest or move."""
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
    return replace(cal, input=replace(cal.input, zero_span=span),
                   provenance={**cal.provenance, "recalibrations": history})


def ramp_output(cal: SensorCalibration, grid: np.ndarray) -> np.ndarray:
    """The calibration's output along a slow ramp over ``grid`` and back (10 Hz, from a
    fresh state at the rest end; an existing input zero and span left out)."""
    bare = replace(cal, input=replace(cal.input, zero_span=None))
    path = np.concatenate([grid, grid[::-1]])
    return Engine(Calibration({cal.name: bare})).run(cal.name, 0.1 * np.arange(path.size),
                                                     path).strain


def follows_steady_curve(cal: SensorCalibration,
                         curve: tuple[np.ndarray, np.ndarray]) -> bool:
    """True when the calibration's output along a slow ramp over its resistance range and
    back (``ramp_output`` on ``steady_curve``'s grid) is its steady output at each
    resistance within ``STATIC_TOLERANCE`` of the strain span: a static map, which two
    points invert exactly. A model with memory is on a loading or unloading branch in use
    instead."""
    grid, steady = curve
    out = ramp_output(cal, grid)
    span = cal.valid_range.s_hi - cal.valid_range.s_lo
    return bool(np.max(np.abs(out - np.concatenate([steady, steady[::-1]])))
                <= STATIC_TOLERANCE * span)


def branches(cal: SensorCalibration, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unloading, loading) outputs of a memory model on ``grid`` (from its rest end): a
    slow ramp up, down and up again; the unloading branch from the top, the loading branch
    after that full unload, as a sensor at the start of a session was last unloaded."""
    n = grid.size
    out = ramp_output(cal, np.concatenate([grid, grid[::-1], grid]))
    return out[n:2 * n][::-1], out[2 * n:3 * n]


def branch_resistance(grid: np.ndarray, out: np.ndarray, strain: float) -> float:
    """The resistance of ``grid`` where ``out`` first crosses ``strain`` from the rest end
    (linear between grid points), else the grid point of the nearest output."""
    d = out - strain
    cross = np.flatnonzero(np.sign(d[:-1]) * np.sign(d[1:]) <= 0)
    if not cross.size:
        return float(grid[int(np.argmin(np.abs(d)))])
    j = int(cross[0])
    w = d[j] / (d[j] - d[j + 1]) if d[j] != d[j + 1] else 0.0
    return float(grid[j] + w * (grid[j + 1] - grid[j]))


def span_on_branches(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                     grid: np.ndarray, branch: tuple[np.ndarray, np.ndarray],
                     ) -> tuple[float, float, float]:
    """The input zero and span through two measured (R, S) points read on two branches of
    outputs over ``grid`` (``branch_resistance``): the rest point on the first (a memory
    model's unloading branch, ``branches``), the stretch on the second (its loading
    branch); a static model's held map for both."""
    (r1, s1), (r2, s2) = sorted(points, key=lambda p: p[1])
    c1 = branch_resistance(grid, branch[0], s1)
    c2 = branch_resistance(grid, branch[1], s2)
    k = (c2 - c1) / (r2 - r1) if r2 != r1 else float("nan")
    if not (np.isfinite(k) and k > 0):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: the resistance moves "
                         "against the calibration's direction (span gain "
                         f"{k:.4g} must be > 0)")
    return r1, c1, float(k)


def span_of_first_cycle(cal: SensorCalibration, rec: Recording) -> tuple[float, float, float]:
    """The input zero and span (rest, rest_calibrated, k) from a run's first cycle ``rec``
    (``points_from_first_cycle``). A static model: its held map inverted at the two points
    (``span_from_points``); where the map never outputs a point's strain, the resistance
    of its nearest output (the output map made after the span corrects what remains). A
    memory model: the two points read on its branches (``span_on_branches``), then the
    span refined through the run (``span_through_run``); where the branches give no span,
    the calibration as tared (the run's rest onto its rest resistance, gain 1) if that
    reads the cycle better than the calibration as it is (``cycle_error``), not refined
    (a refinement from there fits the cycle, not the run: a loop's exact memory term lost
    half its gain on the run after it)."""
    if rec.s is None:
        raise InputError(f"recalibrate --input: {rec.name!r} has no reference strain")
    curve = steady_curve(cal)
    if follows_steady_curve(cal, curve):
        points = points_from_first_cycle(rec.t, cal.input.to_ohm(rec.r), rec.s,
                                         top=float(curve[1].max()))
        try:
            return span_from_points(cal, points, curve)
        except InputError:
            return span_on_branches(cal, points, curve[0], (curve[1], curve[1]))
    branch = branches(cal, curve[0])
    points = points_from_first_cycle(rec.t, cal.input.to_ohm(rec.r), rec.s,
                                     top=float(branch[1].max()))
    try:
        start = span_on_branches(cal, points, curve[0], branch)
    except InputError:
        if cal.rest_resistance is None:
            raise
        tared = (min(points, key=lambda p: p[1])[0], cal.rest_resistance, 1.0)
        if not cycle_error(replace(cal, input=replace(cal.input, zero_span=tared)), rec) < \
                cycle_error(cal, rec):
            raise
        return tared
    return span_through_run(cal, rec, start)


def cycle_error(cal: SensorCalibration, rec: Recording) -> float:
    """RMSE of the engine's output over ``rec`` against its finite reference strain."""
    assert rec.s is not None
    ok = np.isfinite(rec.s)
    strain = Engine(Calibration({cal.name: cal})).run(cal.name, rec.t, rec.r).strain
    value = float(np.sqrt(np.mean((strain[ok] - rec.s[ok]) ** 2)))
    return value if np.isfinite(value) else np.inf


def span_through_run(cal: SensorCalibration, rec: Recording,
                     start: tuple[float, float, float]) -> tuple[float, float, float]:
    """The input zero and span (rest, rest_calibrated, k) whose engine output over ``rec``
    (the first cycle) is closest to its reference strain (least squares, Nelder-Mead from
    ``start``, the two-point span; the measured rest kept): for a model that does not
    follow its steady outputs (``follows_steady_curve``). The engine runs the model along
    the path the sensor took, so a memory model is spanned on its loading and unloading
    branches, not on a constant-resistance map it does not follow in use. The search starts
    from ``start`` or from the calibration as tared (the run's rest onto the calibration's
    rest resistance, span gain 1), whichever reads the cycle better (a model whose held
    outputs have not settled in ``SETTLE_SAMPLES``, such as slow creep states, can give a
    far-off two-point span), and keeps that start unless the fit lowers the error."""
    from scipy.optimize import minimize


    if rec.s is None or np.isfinite(rec.s).sum() < SPAN_FIT_MIN_SAMPLES:
        return start
    rest, rest_cal, k = start
    width = cal.valid_range.r_hi - cal.valid_range.r_lo
    ok = np.isfinite(rec.s)
    reference = rec.s[ok]

    def error(x: np.ndarray) -> float:
        span = (rest, rest_cal + width * float(x[0]), k * float(np.exp(x[1])))
        trial = replace(cal, input=replace(cal.input, zero_span=span))
        strain = Engine(Calibration({cal.name: trial})).run(cal.name, rec.t, rec.r).strain
        value = float(np.sqrt(np.mean((strain[ok] - reference) ** 2)))
        return value if np.isfinite(value) else np.inf

    origin = np.zeros(2)
    first = error(origin)
    if cal.rest_resistance is not None:  # the calibration as tared: a zero, no span
        tared = np.array([(cal.rest_resistance - rest_cal) / width, -np.log(k)])
        if (tared_error := error(tared)) < first:
            origin, first = tared, tared_error
    best = minimize(error, origin, method="Nelder-Mead",
                    options={"initial_simplex": origin + np.array([[0.0, 0.0], [0.05, 0.0],
                                                                   [0.0, 0.2]]),
                             "xatol": 1e-3, "fatol": 1e-4, "maxfev": SPAN_FIT_EVALUATIONS})
    x = best.x if np.isfinite(best.fun) and best.fun < first else origin
    return rest, rest_cal + width * float(x[0]), k * float(np.exp(x[1]))


def span_reading(span: tuple[float, float, float]) -> str:
    """The input map in words: ``input zero 1.02 -> 1.00 ohm, span gain 0.81
    (sensitivity +23.5 %)``."""
    rest, rest_cal, k = span
    return (f"input zero {ohms((rest, rest_cal)).replace(' vs ', ' -> ')}, span gain "
            f"{k:.4g} (sensitivity {100.0 * (1.0 / k - 1.0):+.1f} %)")


FROM_SAMPLES = 20
"""Scored samples ``recalibrate --from`` needs at least."""
FROM_COVER = 0.1
"""Share of the calibrated strain span the reference must move through for ``--from``: a
gain and offset are fitted over a stretch of the range, not a point of it. The README's
session start (``bags/demo_rates.mcap``, first 30 s) moves through 17 % of its span."""


def map_from_pairs(estimate: np.ndarray, reference: np.ndarray, *,
                   span: float | None = None) -> tuple[float, float]:
    """(a, b) of reference ~ a estimate + b by least squares over the finite pairs: at
    least ``FROM_SAMPLES`` of them, the reference moving through ``FROM_COVER`` of the
    calibrated strain ``span`` (when given)."""
    ok = np.isfinite(estimate) & np.isfinite(reference)
    if ok.sum() < FROM_SAMPLES or not np.ptp(estimate[ok]) > 0:
        raise InputError(f"recalibrate --from: the bag gives {int(ok.sum())} scored samples "
                         f"(at least {FROM_SAMPLES} needed) or no range of estimated strain")
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
                         "> 0 (the points contradict the calibration's direction)")
    effects = [dict(e, coef=a * float(e["coef"])) for e in cal.effects]
    for name, kind, params, coef in ((GAIN_NAME, "strain_level", {"power": 1}, 1.0 - a),
                                     (OFFSET_NAME, "offset", {}, -b)):
        old = next((e for e in effects if e["name"] == name), None)
        if old is None:
            effects.append({"name": name, "kind": kind, "params": params, "coef": coef})
        else:
            old["coef"] = float(old["coef"]) + coef
    history = [*cal.provenance.get("recalibrations", []), dict(record, gain=a, offset=b)]
    new = replace(cal, effects=effects,
                  provenance={**cal.provenance, "recalibrations": history})
    try:  # the checks every reader applies, in the user's terms
        check_calibration(Calibration({cal.name: new}))
    except CalibrationError as err:
        raise InputError(f"recalibration of {cal.name!r}: {reading(a, b, unit=cal.strain_unit)}"
                         f" gives a calibration that would not load ({err.problem}); check "
                         f"the known strains (in {strain_unit_words(cal.strain_unit)})"
                         ) from None
    return new


CYCLE_UP, CYCLE_BACK = 0.5, 0.1
"""A cycle (``cycle_end``): the reference passes this share of its span above its minimum,
then returns to within the second share of it."""


def cycle_end(t: np.ndarray, s: np.ndarray) -> float | None:
    """Seconds from ``t[0]`` to the end of the first stretch and return of the reference
    ``s``: its first return to within ``CYCLE_BACK`` of its span (1st to 99th percentile)
    above the minimum after first passing ``CYCLE_UP`` of it. None when there is none."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(s)
    t, s = t[ok], s[ok]
    if t.size < 2:
        return None
    lo, hi = np.percentile(s, [1, 99])
    if not hi > lo:
        return None
    up = np.flatnonzero(s > lo + CYCLE_UP * (hi - lo))
    if not up.size:
        return None
    back = np.flatnonzero(s[up[0]:] < lo + CYCLE_BACK * (hi - lo))
    return float(t[up[0] + back[0]] - t[0]) if back.size else None


MIN_CYCLE_SHARE = 0.1
"""A window's stretch must span at least this share of the calibration's strain range."""


def stretch_and_return(s: np.ndarray, strain_range: float) -> bool:
    """True when the reference ``s`` of a window rises from within ``CYCLE_UP`` of its span
    above its minimum to its maximum and falls back there, over at least
    ``MIN_CYCLE_SHARE`` of ``strain_range`` (the calibration's): a load and unload."""
    s = np.asarray(s, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size < 3 or not np.ptp(s) >= MIN_CYCLE_SHARE * strain_range:
        return False
    low = s <= s.min() + CYCLE_UP * np.ptp(s)
    top = int(np.argmax(s))
    return bool(low[:top].any() and low[top:].any())


def parse_window(text: str) -> tuple[float, float]:
    """``"START:END"`` (seconds from a bag's start) -> (START, END); InputError otherwise."""
    a_text, sep, b_text = text.partition(":")
    try:
        start, end = float(a_text), float(b_text)
    except ValueError:
        start, end = float("nan"), float("nan")
    if not (sep and np.isfinite(start) and np.isfinite(end) and start >= 0):
        raise InputError(f"--window {text!r}: expected START:END in seconds from the bag's "
                         "start, START >= 0")
    if not end > start:
        raise InputError(f"--window {text!r}: END must be after START")
    return start, end


def head(recordings: Mapping[str, Recording], seconds: float | None,
         ) -> dict[str, Recording]:
    """Each recording's first ``seconds`` (all of it when None): ``window`` (0, seconds)."""
    if seconds is None:
        return dict(recordings)
    if not (np.isfinite(seconds) and seconds > 0):
        raise InputError(f"--first {seconds!r}: expected a duration > 0 s")
    return {name: cut(rec, 0.0, seconds) for name, rec in recordings.items()}


def cut(rec: Recording, start: float, end: float) -> Recording:
    """The samples of ``rec`` from ``start`` to ``end`` seconds after its first sample."""
    if not rec.t.size:
        return rec
    a = int(np.searchsorted(rec.t, rec.t[0] + start, side="left"))
    b = int(np.searchsorted(rec.t, rec.t[0] + end, side="right"))
    return replace(rec, t=rec.t[a:b], r=rec.r[a:b], s=None if rec.s is None else rec.s[a:b],
                   temperature=None if rec.temperature is None else rec.temperature[a:b])


def window(recordings: Mapping[str, Recording], span: tuple[float, float],
           calibration: Calibration, source: str = "the bag") -> dict[str, Recording]:
    """Each referenced recording up to ``span[1]`` seconds after its start, its reference
    strain left out (NaN) before ``span[0]`` (``recalibrate --window``): the engine runs the
    calibration from the bag's start, so a memory model enters the window in the state the
    warm-up left, and only the window's reference is fitted to. InputError for a window
    beyond a recording's end or one in which its reference strain makes no stretch and
    return (``stretch_and_return`` over the strain range of its sensor's calibration)."""
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


def recalibrate_recordings(calibration: Calibration, recordings: Mapping[str, Recording], *,
                           form: str = "output", first: float | None = None,
                           sensors: Sequence[str] | None = None, tare: str = "calibration",
                           source: str = "", span: tuple[float, float] | None = None,
                           ) -> tuple[Calibration, list[str]]:
    """``recalibrate`` from recordings with a reference strain (their first ``first``
    seconds, or the ``span`` (START, END) seconds after their start, ``window``): the output
    map by least squares, or the input zero and span from the first rest and the largest
    strain (``points_from_first_cycle``)."""
    if form not in FORMS:
        raise InputError(f"recalibrate: form {form!r} is not one of {', '.join(FORMS)}")
    if span is not None and first is not None:
        raise InputError("recalibrate: give --first or --window, not both")
    if span is not None:
        chosen = {n: r for n, r in recordings.items()
                  if n in calibration.sensors and not (sensors and n not in sensors)}
        recs = window(chosen, span, calibration, source or "the bag")
        where = f"{source}, {span[0]:g} to {span[1]:g} s"
    else:
        recs = head(recordings, first)
        where = f"{source}{'' if first is None else f', first {first:g} s'}"
    out = dict(calibration.sensors)
    lines = []
    if form == "input":
        for name, rec in recs.items():
            if name not in calibration.sensors or rec.s is None or (sensors and
                                                                     name not in sensors):
                continue
            cal = calibration.sensors[name]
            zero_span = span_of_first_cycle(cal, rec)
            out[name] = apply_span(cal, zero_span, {"from": source, "first": first,
                                                    "window": None if span is None
                                                    else list(span)})
            lines.append(f"{name}: {span_reading(zero_span)} (from {where})")
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
        out[name] = apply_map(out[name], a, b, {"from": source, "tare": tare, "first": first,
                                                "window": None if span is None else list(span)})
        lines.append(f"{name}: {reading(a, b, unit=ev.unit)} (from {where}, "
                     f"{int(ev.scored.sum())} samples)")
    return Calibration(out), lines


def recalibrate(calibration: Calibration, *, points: Sequence[tuple[float, float]] = (),
                bag: str | None = None, sensors: Sequence[str] | None = None,
                tare: str = "calibration", form: str = "output",
                first: float | None = None, span: tuple[float, float] | None = None,
                ) -> tuple[Calibration, list[str]]:
    """The recalibrated calibration and one line per sensor (gain, offset, reading).

    ``points``: two (R, S) points (one sensor: ``sensors`` or the calibration's only one);
    ``bag``: a bag with a reference strain (every calibrated sensor in it; its first
    ``first`` seconds, or ``span``: the window (START, END) seconds after its start, which
    must hold a stretch and return). ``form``: ``output`` (gain and offset of the strain)
    or ``input`` (zero and span of the resistance). Raises InputError (the input calibration is
    untouched) when the map cannot be made.
    """
    if form not in FORMS:
        raise InputError(f"recalibrate: form {form!r} is not one of {', '.join(FORMS)}")
    out = dict(calibration.sensors)
    lines = []
    if bag is not None:
        return recalibrate_recordings(calibration, load_recordings(bag)[0], form=form,
                                      first=first, sensors=sensors, tare=tare,
                                      source=str(bag), span=span)
    else:
        names = list(sensors or calibration.sensors)
        if len(names) != 1:
            raise InputError("recalibrate --point: name one --sensor (the calibration has "
                             f"{', '.join(calibration.sensors)})")
        name = names[0]
        if name not in calibration.sensors:
            raise InputError(f"sensor {name!r} is not in the calibration "
                             f"({', '.join(calibration.sensors)})")
        if form == "input":
            span = span_from_points(out[name], points)
            out[name] = apply_span(out[name], span, {"points": [list(p) for p in points]})
            lines.append(f"{name}: {span_reading(span)} (through {len(points)} points)")
        else:
            a, b = map_from_points(out[name], points)
            out[name] = apply_map(out[name], a, b, {"points": [list(p) for p in points]})
            lines.append(f"{name}: {reading(a, b, unit=out[name].strain_unit)} (through "
                         f"{len(points)} points)")
    return Calibration(out), lines


def reading(a: float, b: float, *, unit: str = "%") -> str:
    """The map in words: ``output gain 1.22 (sensitivity -18.0 %), offset +0.42 % strain``
    (the sensor's sensitivity against the calibration's is 1 / a; the offset in the
    calibration's strain ``unit``)."""
    return (f"output gain {a:.4g} (sensitivity {100.0 * (1.0 / a - 1.0):+.1f} %), "
            f"offset {b:+.3g} {strain_unit_words(unit)}")
