"""Recalibration of any model through known strains: an output gain and offset, or an
input zero and span (``offline/span.py``), from two points or a recording's window
(``offline/session_window.py``).

The spike-decay paper (Lee et al., spike_decay seed) recalibrates its output map f through
two known strains; here the same is done for every model, on the engine's output:

    S_new = a S_out + b

with (a, b) through two points (R_i, S_i), S_out(R_i) being the calibration's steady output
at the constant resistance R_i (``span.steady_output``, so a memory model has settled), or
by least squares over a bag with a reference strain (the engine's output over its used
samples, each run tared as asked).

One mechanism: the map is stored as effect terms (``strain_comp.core.effects``), which the
engine applies identically in step, run, replay, evaluate, diagnose and the node. With
S_corrected = S_hat - sum c_j g_j, the new output a S_corrected + b is S_hat minus
``recalibration_gain`` (kind ``strain_level``, power 1, coef 1 - a), minus
``recalibration_offset`` (kind ``offset``, coef -b), with every existing coefficient scaled
by a. A second recalibration composes with the first (the coefficients add).
Limits: ``strain_level`` reads the engine's estimate clamped to the valid strain range, so
the map is exact inside that range. A new input form replaces an older one (both map
measured resistance); the output gain and offset are kept. The numbers are the fields of
``SpanPolicy`` (``offline/span_policy.py``; docs/results.md).

A session start (``session_start``) is the input step, then the output step on the sensors
that take one (``session_forms``), over one stretch of a run, each step skipped where it
cannot be made, as a user skips it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.calibration import (
    PARAM_MAX,
    SPAN_GAIN_MAX,
    STRAIN_MAX,
    Calibration,
    SensorCalibration,
    strain_unit_words,
)
from strain_comp.core.calibration_file import loadable
from strain_comp.core.effects import RECALIBRATION_TERMS
from strain_comp.core.range_policy import fitted_rest
from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.recording import load_recordings
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.session_window import head, window
from strain_comp.offline.span import (
    apply_span,
    span_from_points,
    span_of_first_cycle,
    span_reading,
    steady_output,
)
from strain_comp.offline.span_policy import SPAN, SpanPolicy
from strain_comp.offline.stretch_line import onto, run_line

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

Window = tuple[float, float]
"""(START, END) seconds after a run's start of the stretch a session start reads; START 0
is ``--first END``, any other ``--window START:END``."""
FORMS = ("output", "input")
"""Where the two-point map acts: on the engine's output strain or on its input resistance."""
GAIN_NAME, OFFSET_NAME = RECALIBRATION_TERMS


def session_forms(cal: SensorCalibration) -> tuple[str, ...]:
    """The steps of a session start on a sensor, in order: the input zero and span, then the
    output gain and offset; the input step alone for a calibration with a stretch line
    (``InputSettings.stretch_line``), which places the run as the training runs' stretches
    lay, gain and offset included (``strain_comp.offline.stretch_line``)."""
    return ("input",) if cal.input.stretch_line is not None else ("input", "output")


def forms_of(calibration: Calibration, recordings: Mapping[str, Recording],
             ) -> dict[str, list[str]]:
    """The session start's steps on a run, in order, each with the sensors it recalibrates
    (``session_forms`` of each calibrated sensor the run holds with a reference)."""
    names = [n for n, rec in recordings.items() if n in calibration.sensors
             and rec.s is not None]
    by_form = {form: [n for n in names if form in session_forms(calibration.sensors[n])]
               for form in ("input", "output")}
    return {form: sensors for form, sensors in by_form.items() if sensors}


@dataclass
class SessionStart:
    """A calibration after the session-start recalibration on one run."""

    calibration: Calibration
    window: Window
    lines: list[str] = field(default_factory=list)
    """What each step did (``recalibrate``'s lines), or why it could not be made."""
    steps: list[str] = field(default_factory=list)
    """The forms made (``input``, ``output``)."""
    made: dict[str, list[str]] = field(default_factory=dict)
    """Each form made -> the sensors it recalibrated."""


def session_start(calibration: Calibration, recordings: Mapping[str, Recording],
                  window: Window, source: str = "") -> SessionStart:
    """``calibration`` after ``recalibrate --input --from RUN --window START:END`` and then
    ``recalibrate --from RUN --window START:END`` (``--first END`` for a window from 0; the
    output form on the spanned input, tare ``calibration``), the output step only on the
    sensors that take one (``session_forms``). A step that cannot be made (no
    rest in the stretch, a strain the calibration never outputs) is skipped, as it is for a
    user, and says why."""
    out = SessionStart(calibration, window)
    head = window[0] == 0.0
    forms = forms_of(calibration, recordings)
    if not forms:
        out.lines.append("no step made: the run holds no calibrated sensor with a strain "
                         "reference")
    for form, sensors in forms.items():
        tare = "calibration" if form == "output" else "auto"
        try:
            out.calibration, lines = recalibrate_recordings(
                out.calibration, recordings, form=form, tare=tare, sensors=sensors,
                first=window[1] if head else None, span=None if head else window,
                source=source)
        except StrainCompError as err:
            out.lines.append(f"the {form} step not made: {err}")
            continue
        out.steps.append(form)
        out.made[form] = list(sensors)
        out.lines += lines
    return out


def stretch_span(cal: SensorCalibration, rec: Recording) -> tuple[float, float, float]:
    """The input zero and span that puts the line of the stretch ``rec`` holds (its
    referenced samples) onto the calibration's stretch line (``stretch_line.onto``)."""
    space = cal.input.stretch_line
    assert space is not None
    own = run_line(replace(rec, r=cal.input.to_ohm(rec.r)))
    if own is None or np.sign(own[1]) != np.sign(space[1]) or not own[0] > 0:
        raise InputError(f"recalibrate --input: sensor {cal.name!r}: its resistance does not "
                         "move with the reference strain in the stretch read as the "
                         "calibration's does (no line of resistance on strain there)")
    zero_span = onto(own, space)
    if not (0.0 < zero_span[0] <= PARAM_MAX
            and 1.0 / SPAN_GAIN_MAX <= zero_span[2] <= SPAN_GAIN_MAX):
        raise InputError(f"recalibrate --input: sensor {cal.name!r}: the stretch read puts "
                         f"its rest at {zero_span[0]:.4g} ohm and its sensitivity "
                         f"{1.0 / zero_span[2]:.4g} times the calibration's: no session start "
                         "of this sensor (record a load and unload of it)")
    return zero_span


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


def map_from_points(cal: SensorCalibration, points: Sequence[tuple[float, float]],
                    policy: SpanPolicy | None = None) -> tuple[float, float]:
    """(a, b) through two (R [ohm], S [%]) points (steady outputs: ``policy``)."""
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
    o1, o2 = steady_output(cal, r1, policy), steady_output(cal, r2, policy)
    if not abs(o2 - o1) > 1e-9 * max(1.0, abs(o1)):
        raise InputError(f"--point {r1:g}:{s1:g} and {r2:g}:{s2:g}: the calibration gives "
                         f"the same strain ({o1:.4g} %) at both resistances")
    a = (s2 - s1) / (o2 - o1)
    return a, s1 - a * o1


def map_from_pairs(estimate: np.ndarray, reference: np.ndarray, *,
                   span: float | None = None, policy: SpanPolicy | None = None,
                   ) -> tuple[float, float]:
    """(a, b) of reference ~ a estimate + b by least squares over the finite pairs: at
    least two of them, the reference moving through ``from_cover`` of the
    calibrated strain ``span`` (when given; ``policy``, ``SPAN`` when None)."""
    policy = SPAN if policy is None else policy
    ok = np.isfinite(estimate) & np.isfinite(reference)
    if ok.sum() < 2 or not np.ptp(estimate[ok]) > 0:
        raise InputError(f"recalibrate --from: the bag gives {int(ok.sum())} scored samples "
                         "(at least two needed) or no range of estimated "
                         "strain")
    if span is not None and not np.ptp(reference[ok]) >= policy.from_cover * span:
        raise InputError(f"recalibrate --from: the reference moves through "
                         f"{np.ptp(reference[ok]):.4g} of the calibrated span {span:.4g}; a "
                         f"gain needs a stretch of at least {policy.from_cover:.0%} of it")
    a, b = np.polyfit(estimate[ok], reference[ok], 1)
    return float(a), float(b)


def apply_map(cal: SensorCalibration, a: float, b: float, record: Mapping[str, Any],
              ) -> SensorCalibration:
    """``cal`` whose output is a x (old output) + b, with ``record`` in its provenance."""
    if not (np.isfinite(a) and np.isfinite(b) and a > 0):
        raise InputError(f"recalibration of {cal.name!r}: gain {a:.4g} must be finite and "
                         "> 0 (its output falls where the known strain rises: the "
                         "calibration reads this sensor against its direction)")
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
    return loadable(new, reading(a, b, unit=cal.strain_unit))


def _check_named(calibration: Calibration, recordings: Mapping[str, Recording],
                 sensors: Sequence[str] | None, source: str) -> None:
    """InputError for a sensor named (``--sensor``) that the calibration or the run lacks."""
    for name in sensors or ():
        if name not in calibration.sensors:
            raise InputError(f"recalibrate --sensor {name}: not in the calibration (its "
                             f"sensors: {', '.join(calibration.sensors)})")
        if name not in recordings or recordings[name].s is None:
            raise InputError(f"recalibrate --sensor {name}: {source or 'the data'} holds no "
                             "recording of it with a strain reference")


def recalibrate_recordings(calibration: Calibration, recordings: Mapping[str, Recording], *,
                           form: str = "output", first: float | None = None,
                           sensors: Sequence[str] | None = None, tare: str = "calibration",
                           source: str = "", span: tuple[float, float] | None = None,
                           policy: SpanPolicy | None = None,
                           ) -> tuple[Calibration, list[str]]:
    """``recalibrate`` from recordings with a reference strain (their first ``first``
    seconds, or the ``span`` (START, END) seconds after their start, ``window``): the output
    map by least squares, or the input zero and span from the first rest and the largest
    strain (``span.span_of_first_cycle``); numbers: ``policy`` (``SPAN`` when None)."""
    if form not in FORMS:
        raise InputError(f"recalibrate: form {form!r} is not one of {', '.join(FORMS)}")
    if span is not None and first is not None:
        raise InputError("recalibrate: give --first or --window, not both")
    _check_named(calibration, recordings, sensors, source)
    if span is not None:
        chosen = {n: r for n, r in recordings.items()
                  if n in calibration.sensors and not (sensors and n not in sensors)}
        recs = window(chosen, span, calibration, source or "the bag", policy)
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
            by_line = cal.input.stretch_line is not None
            zero_span = (stretch_span(cal, rec) if by_line
                         else span_of_first_cycle(cal, rec, policy))
            out[name] = apply_span(cal, zero_span, {"from": source, "first": first,
                                                    "window": None if span is None
                                                    else list(span)})
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
                              span=fitted_rest(calibration.sensors[name].valid_range)[1],
                              policy=policy)
        out[name] = apply_map(out[name], a, b, {"from": source, "tare": tare, "first": first,
                                                "window": None if span is None else list(span)})
        lines.append(f"{name}: {reading(a, b, unit=ev.unit)} (from {where}, "
                     f"{int(ev.scored.sum())} samples)")
    return Calibration(out), lines


def recalibrate(calibration: Calibration, *, points: Sequence[tuple[float, float]] = (),
                bag: str | None = None, sensors: Sequence[str] | None = None,
                tare: str = "calibration", form: str = "output",
                first: float | None = None, span: tuple[float, float] | None = None,
                policy: SpanPolicy | None = None) -> tuple[Calibration, list[str]]:
    """The recalibrated calibration and one line per sensor (gain, offset, reading)."""
    if form not in FORMS:
        raise InputError(f"recalibrate: form {form!r} is not one of {', '.join(FORMS)}")
    out = dict(calibration.sensors)
    lines = []
    if bag is not None:
        return recalibrate_recordings(calibration, load_recordings(bag)[0], form=form,
                                      first=first, sensors=sensors, tare=tare,
                                      source=str(bag), span=span, policy=policy)
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
            span = span_from_points(out[name], points, policy=policy)
            out[name] = apply_span(out[name], span, {"points": [list(p) for p in points]})
            lines.append(f"{name}: {span_reading(span)} (through {len(points)} points)")
        else:
            a, b = map_from_points(out[name], points, policy)
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
