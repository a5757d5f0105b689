"""Which stretch of a recording a session start reads: its first seconds (``recalibrate
--first``), a window (``--window START:END``) that must hold a stretch and return, and where
a reference strain's first cycle ends (docs/design.md, "Command line"). The numbers are
the fields of ``SpanPolicy`` (``offline/span_policy.py``; docs/results.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError
from strain_comp.offline.span_policy import SPAN, SpanPolicy

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

FIRST_CYCLE_CAP = 0.4
"""The first cycle is at most this share of a run (a run that never returns to rest)."""


def cycle_end(t: np.ndarray, s: np.ndarray, policy: SpanPolicy | None = None) -> float | None:
    """Seconds from the first sample (``t[0]``, referenced or not) to the end of the first
    stretch and return of the reference ``s``: its first return to within ``cycle_back`` of
    its span above the minimum after first passing ``cycle_up`` of it (``policy``, ``SPAN``
    when None). None when there is none."""
    policy = SPAN if policy is None else policy
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    origin = _origin(t)
    ok = np.isfinite(t) & np.isfinite(s)
    t, s = t[ok], s[ok]
    if t.size < 2 or origin is None:
        return None
    lo, hi = float(s.min()), float(s.max())
    if not hi > lo:
        return None
    up = np.flatnonzero(s > lo + policy.cycle_up * (hi - lo))
    if not up.size:
        return None
    back = np.flatnonzero(s[up[0]:] < lo + policy.cycle_back * (hi - lo))
    return float(t[up[0] + back[0]] - origin) if back.size else None


def _origin(t: np.ndarray) -> float | None:
    """The first finite sample time: where a run's seconds count from (``cut``, ``--first``,
    ``--window``), samples without a reference included."""
    finite = t[np.isfinite(t)]
    return float(finite[0]) if finite.size else None


def stretch_and_return(s: np.ndarray, strain_range: float,
                       policy: SpanPolicy | None = None) -> bool:
    """True when the reference ``s`` of a window rises from within ``cycle_up`` of its span
    above its minimum to its maximum and falls back there, over at least
    ``min_cycle_share`` of ``strain_range`` (the calibration's): a load and unload
    (``policy``, ``SPAN`` when None)."""
    policy = SPAN if policy is None else policy
    s = np.asarray(s, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size < 3 or not np.ptp(s) >= policy.min_cycle_share * strain_range:
        return False
    low = s <= s.min() + policy.cycle_up * np.ptp(s)
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
           calibration: Calibration, source: str = "the bag",
           policy: SpanPolicy | None = None) -> dict[str, Recording]:
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
        if part.s is None or not stretch_and_return(part.s, vr.s_hi - vr.s_lo, policy):
            raise InputError(f"--window {start:g}:{end:g}: the reference strain of {name!r} "
                             f"makes no stretch and return in it (record a load and unload "
                             f"there)")
        whole = cut(rec, 0.0, end)
        assert whole.s is not None
        out[name] = replace(whole, s=np.where(whole.t < rec.t[0] + start, np.nan, whole.s))
    return out


def first_cycle(t: np.ndarray, s: np.ndarray) -> float | None:
    """Seconds from the start of a run (its first sample, referenced or not) to the end of
    its first load and unload (``cycle_end``); at most ``FIRST_CYCLE_CAP`` of the run.
    None when the reference never moves."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(s)
    if ok.sum() < 2 or not np.percentile(s[ok], 99) > np.percentile(s[ok], 1):
        return None
    finite = t[np.isfinite(t)]
    cap = FIRST_CYCLE_CAP * float(finite[-1] - finite[0])
    end = cycle_end(t, s)
    return cap if end is None else min(end, cap)


def second_cycle(t: np.ndarray, s: np.ndarray) -> tuple[float, float] | None:
    """(START, END) seconds of a run's second load and unload, the calibration stretch of
    the README's session start after a warm-up one (``recalibrate --window``): from the end
    of the first cycle (``first_cycle``) to the end of the next stretch and return
    (``cycle_end`` on the rest of the run). None when the rest of the run has none."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    first = first_cycle(t, s)
    return None if first is None else _cycle_after(t, s, first)


def _cycle_after(t: np.ndarray, s: np.ndarray, first: float) -> tuple[float, float] | None:
    """(START, END) [s] of the next load and unload after the first ``first`` seconds of a
    run (``first_cycle``'s, so the run has finite sample times)."""
    origin = _origin(t)
    assert origin is not None  # first_cycle found finite samples
    rest = t >= origin + first
    end = cycle_end(t[rest], s[rest]) if rest.sum() > 1 else None
    if end is None:
        return None
    start = float(t[rest][0] - origin)
    return start, start + end


def calibration_stretch(t: np.ndarray, s: np.ndarray) -> tuple[float, float] | None:
    """The stretch the README's session start reads on a run: its second load and unload
    after a warm-up one (``second_cycle``), else its first (START 0, ``first_cycle``)."""
    t, s = np.asarray(t, dtype=np.float64), np.asarray(s, dtype=np.float64)
    first = first_cycle(t, s)
    return None if first is None else _cycle_after(t, s, first) or (0.0, first)
