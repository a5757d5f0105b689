"""The session-start recalibration, as a user makes it: the README's procedure, one
unreferenced warm-up load and unload, then the calibration stretch (``warmup_start``, on
``strain_comp.offline.recalibrate.session_start``).

``recalibrate --input --from BAG --window START:END`` (the input zero and span from the
rest and the largest strain of the run's second load and unload), then ``recalibrate --from
BAG --window START:END`` (the output gain and offset by least squares over the same
stretch, on the spanned input), then ``evaluate`` (``strain_comp.offline.recalibrate``,
``strain_comp.offline.evaluate``); on the first stretch (``--first SECONDS``) where the run
has no second one or a step is refused on it that the first makes. The headline workflow
of the generalisation benchmark (docs/generalisation.md, ``warmup``), which calls
``warmup_start`` too. The residual loop scores its terms after it
(``strain_comp.diagnosis.loop``), so that a term that only does what this recalibration
does anyway gets no credit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.candidates import added_effects
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.recalibrate import SessionStart, Window, forms_of, session_start
from strain_comp.offline.session_window import first_cycle, second_cycle


@dataclass(frozen=True)
class Stretches:
    """The stretches a run offers a session start: its first load and unload, and its
    second one (None: the run has none)."""

    first: float
    """Seconds from the start to the end of the first stretch (``first_cycle``)."""
    second: Window | None
    """The second stretch (``second_cycle``)."""

    @classmethod
    def of(cls, t: np.ndarray, s: np.ndarray) -> Stretches | None:
        """The stretches of a run's reference ``s`` at times ``t``; None when it never
        moves.

        Args:
            t: Sample times [s].
            s: Reference strain, one per sample.

        Returns:
            The stretches, or None.

        """
        first = first_cycle(t, s)
        return None if first is None else cls(first, second_cycle(t, s))


def window_flag(window: Window) -> str:
    """``recalibrate``'s flag for a session start's stretch: ``--first END`` for a window
    from 0, else ``--window START:END``.

    Args:
        window: (START, END) [s] after the run's start.

    Returns:
        The flag with its value.

    """
    if window[0] == 0.0:
        return f"--first {window[1]:.3g}"
    return f"--window {window[0]:.3g}:{window[1]:.3g}"


def warmup_start(calibration: Calibration, recordings: Mapping[str, Recording],
                 stretches: Stretches, at_first: SessionStart | None = None) -> SessionStart:
    """The README's session start: ``session_start`` on the run's second stretch, after an
    unreferenced warm-up one; on its first stretch (``at_first`` when given, the same
    object) where the run has no second stretch or the second makes fewer steps than the
    first (a step refused there that the first makes).

    Args:
        calibration: The calibration.
        recordings: The run's recordings by sensor name.
        stretches: The run's stretches (``Stretches.of`` its reference).
        at_first: The session start on the first stretch, when already made.

    Returns:
        The session start made.

    """
    warm = None
    if stretches.second is not None:
        warm = session_start(calibration, recordings, stretches.second)
        if len(warm.steps) == len(forms_of(calibration, recordings)):  # none refused
            return warm
    first = at_first or session_start(calibration, recordings, (0.0, stretches.first))
    return first if warm is None or len(warm.steps) < len(first.steps) else warm


def session_errors(calibration: Calibration, recordings: Mapping[str, Recording],
                   sensor: str, stretches: Stretches) -> np.ndarray:
    """``sensor``'s errors (estimate - reference over the samples ``evaluate`` scores) on
    ``recordings`` after the session start (``warmup_start``) on their ``stretches``.

    Args:
        calibration: The calibration.
        recordings: The run's recordings by sensor name.
        sensor: The sensor scored.
        stretches: The run's stretches.

    Returns:
        The errors, in the calibration's strain unit.

    Raises:
        InputError: No sensor of ``recordings`` can be scored.

    """
    spanned = warmup_start(calibration, recordings, stretches).calibration
    ev = evaluate_recordings(recordings, spanned, tare="calibration").sensors[sensor]
    return np.asarray(ev.estimate[ev.scored] - ev.reference[ev.scored], dtype=np.float64)


class SessionHeldOut:
    """The loop's held-out residual (``strain_comp.diagnosis.selection.HeldOut``) of one
    sensor's terms on validation runs as the product is used: the calibration with the
    terms added, recalibrated at the start of each run (``warmup_start``), evaluated over
    the whole run. In an array the sensor's neighbours are recalibrated with it on the
    sensor's stretches, as a user recalibrates the whole array: a stretch refused for one of
    them is refused for all. Cached by terms and coefficients."""

    def __init__(self, calibration: Calibration, sensor: str,
                 runs: Sequence[Mapping[str, Recording]], candidates: Sequence[dict[str, Any]]
                 ) -> None:
        self.calibration = calibration
        self.sensor = sensor
        self.candidates = candidates
        self.runs: list[tuple[dict[str, Recording], Stretches]] = []
        for bag in runs:
            rec = bag.get(sensor)
            stretches = None if rec is None or rec.s is None else Stretches.of(rec.t, rec.s)
            if stretches is not None:
                self.runs.append((dict(bag), stretches))
        self._cache: dict[tuple[tuple[int, float], ...], list[np.ndarray]] = {}
        self._starts: list[SessionStart] | None = None

    def starts(self) -> list[SessionStart]:
        """The session start of each validation run with the calibration as given (made
        once)."""
        if self._starts is None:
            self._starts = [warmup_start(self._restricted(self.calibration, bag),
                                         self._bag(bag), stretches)
                            for bag, stretches in self.runs]
        return self._starts

    def usable(self) -> bool:
        """A validation run whose session start makes at least one step."""
        return any(start.steps for start in self.starts())

    def redundant(self, j: int) -> bool:
        """Is candidate ``j`` what the session start makes itself (an output offset or
        gain)? Such a term is neither scored nor written after it."""
        kind = str(self.candidates[j]["kind"])
        power = self.candidates[j]["params"].get("power", 1)
        return kind == "offset" or (kind == "strain_level" and bool(power == 1))

    def __call__(self, cols: Sequence[int], coef: np.ndarray) -> np.ndarray:
        return np.concatenate(self.per_run(cols, coef))

    def per_run(self, cols: Sequence[int], coef: np.ndarray) -> list[np.ndarray]:
        """The errors of each validation run with terms ``cols`` (cached)."""
        keep = [k for k, j in enumerate(cols) if not self.redundant(j)]
        cols, coef = [cols[k] for k in keep], np.asarray(coef)[keep]
        key = tuple((int(j), float(c)) for j, c in zip(cols, coef, strict=True))
        if key not in self._cache:
            cal = self.calibration.sensors[self.sensor]
            trial = Calibration({**self.calibration.sensors, self.sensor: replace(
                cal, effects=[*cal.effects, *added_effects(self.candidates, cols, list(coef),
                                                           cal.effects)])})
            self._cache[key] = [session_errors(self._restricted(trial, bag), self._bag(bag),
                                               self.sensor, stretches)
                                for bag, stretches in self.runs]
        return self._cache[key]

    def _names(self) -> list[str]:
        """The sensor and the neighbours its cross-talk terms and candidates read."""
        effects = [*self.calibration.sensors[self.sensor].effects, *self.candidates]
        return list(dict.fromkeys([self.sensor, *(str(e["params"]["neighbour"]) for e in effects
                                                  if e.get("kind") == "crosstalk")]))

    def _restricted(self, calibration: Calibration, bag: Mapping[str, Recording]
                    ) -> Calibration:
        names = [n for n in self._names() if n in calibration.sensors and n in bag]
        return Calibration({n: calibration.sensors[n] for n in names})

    def _bag(self, bag: Mapping[str, Recording]) -> dict[str, Recording]:
        return {n: bag[n] for n in self._names() if n in bag}

