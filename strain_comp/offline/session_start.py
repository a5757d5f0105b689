"""The start of a session (``strain-comp start``, ``sc.session_start``): one recording with a
reference, a warm-up stretch and back, then the calibration stretch and back; the
calibration corrected on that stretch in one step.

``start`` finds the stretch itself from the reference (``stretch_of``: the second stretch
and return after a warm-up one, else the first; ``session_window.calibration_stretch``),
applies the correction the calibration's fit chose (``recalibrate.session_start``: the
input zero and span, then the output gain and offset on the sensors that take one,
``recalibrate.session_forms``), and says per sensor the stretch used, the correction and
the error (RMSE) on that stretch, beside the error the calibration expects on a new
session (``core.calibration.expected_error``). Where the second stretch takes fewer steps
than the first, the first is used (the README's fallback, measured on the benchmark:
docs/results.md). The one session start of the command line, the API, ``diagnose
--validate`` (``diagnosis.session``), ``fit --model auto`` (``offline.model_choice``) and
``scripts/generalisation.py``.

Refused, in one line that says what to record instead (``InputError``): a recording with no
calibrated sensor's reference, a reference with no stretch and return, one that never comes
back to rest after its largest strain, one that ends during its first stretch (shorter than
the warm-up), and a stretch on which no correction can be made.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.core.calibration import Calibration, expected_words, strain_unit_words
from strain_comp.errors import InputError
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.recalibrate import Window, reading, session_forms, session_start
from strain_comp.offline.session_window import (
    calibration_stretch,
    cycle_end,
    first_cycle,
    head,
    stretch_and_return,
)
from strain_comp.offline.session_window import window as window_of
from strain_comp.offline.span import span_reading
from strain_comp.offline.span_policy import SPAN

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

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
        """``s1: stretch 45-95 s, input zero ..., output gain ...; RMSE 0.81 % strain on
        the stretch (expected on a new session: ...)``."""
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
    """The stretches a start recording offers: its first stretch and return (START 0), and
    its calibration stretch after it (None: it has none fit to read), refused in the
    user's terms when it has no stretch and return a start can read."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(s)
    tt, ss = t[ok], s[ok]
    if ss.size < 3 or not np.ptp(ss) >= SPAN.min_cycle_share * strain_range:
        raise InputError(f"{source}: its reference strain makes no stretch and return (it "
                         f"moves through {np.ptp(ss) if ss.size else 0.0:.3g} of the "
                         f"calibrated {strain_range:.3g}): {RECORD}")
    lo, span = float(ss.min()), float(np.ptp(ss))
    top = int(np.argmax(ss))
    back = ss[top:] < lo + SPAN.cycle_back * span
    if not back.any():
        if cycle_end(tt, ss) is None and ss[-1] > lo + SPAN.cycle_up * span:
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
    """The session start on a recording with a reference (module docstring): the
    calibration stretch found (or ``window``), the correction made, a record per sensor."""
    names = [n for n, rec in recordings.items() if n in calibration.sensors
             and rec.s is not None and not (sensors and n not in sensors)]
    for name in sensors or ():
        if name not in calibration.sensors:
            raise InputError(f"sensor {name!r} is not in the calibration "
                             f"({', '.join(calibration.sensors)})")
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
    """``start``, or the calibration as it is (no step, no window, the refusal as its note)
    where the start refuses the run: what a user refused is left with, as the benchmark,
    the loop's validation runs and the pooled fit's choice score it."""
    try:
        return start(calibration, recordings, window=window)
    except InputError as err:
        return Started(calibration, None, notes=[str(err)])


def _why(note: str) -> str:
    """A step's refusal in the user's terms: the command and field names dropped."""
    step, _, why = note.partition(" not made: ")
    for prefix in ("recalibrate --input: ", "recalibrate --from: ", "recalibrate: "):
        why = why.removeprefix(prefix)
    why = re.sub(r"^--point \S+ and \S+: ", "", why)
    return f"{step} not made: {why}" if why else note


def _wanted(calibration: Calibration, name: str) -> int:
    """How many steps a start makes on the sensor (``session_forms``)."""
    return len(session_forms(calibration.sensors[name]))


Made = tuple[Calibration, dict[str, list[str]], list[str], Window]
"""A session start on one stretch (``_made``)."""


def _found(calibration: Calibration, recordings: Mapping[str, Recording],
           stretches: tuple[Window, Window | None], source: str) -> Made:
    """The start on the calibration stretch (the second), or on the first where the second
    is missing or takes fewer steps than the first (the README's fallback); the first read
    as it is (``recalibrate --first``), as the benchmark has always read it."""
    first, second = stretches
    made = None if second is None else _made(calibration, recordings, second, source)
    if made is not None and all(len(steps) == _wanted(calibration, n)
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
    """``recalibrate.session_start`` on ``span``: the calibration, the steps made per
    sensor, the lines of the steps not made, the window. The window's own refusal first:
    as ``--window`` says it where ``given``, in the start's terms where not, none where
    None (the first seconds read as they are)."""
    try:
        if given is not None:
            window_of(recordings, span, calibration, source)
    except InputError as err:
        if given:
            raise
        raise InputError(f"{source}: the stretch found at {span[0]:.4g}-{span[1]:.4g} s: "
                         f"{str(err).partition(': ')[2]}; {RECORD}") from None
    made = session_start(calibration, recordings, span, source)
    steps = {n: [form for form, names in made.made.items() if n in names]
             for n in recordings if n in calibration.sensors}
    notes = [_why(line) for line in made.lines if "not made" in line]
    return made.calibration, steps, notes, span
