"""The session start on each validation run of ``diagnose --validate``, as ``start`` makes it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.candidates import added_effects
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.session_start import Started, Window, start_or_keep


def window_flag(window: Window | None) -> str:
    """``start``'s flag for a session start's stretch (``refused``: none)."""
    if window is None:
        return "refused"
    return f"--window {window[0]:.3g}:{window[1]:.3g}"


def session_errors(calibration: Calibration, recordings: Mapping[str, Recording],
                   sensor: str) -> np.ndarray:
    """``sensor``'s errors (as ``evaluate`` scores them) after the session start."""
    spanned = start_or_keep(calibration, recordings).calibration
    ev = evaluate_recordings(recordings, spanned, tare="calibration").sensors[sensor]
    return np.asarray(ev.estimate[ev.scored] - ev.reference[ev.scored], dtype=np.float64)


class SessionHeldOut:
    """``selection.HeldOut`` on the validation runs after their session start (cached)."""
    # the array's neighbours are started with the sensor, as a user starts the whole array

    def __init__(self, calibration: Calibration, sensor: str,
                 runs: Sequence[Mapping[str, Recording]], candidates: Sequence[dict[str, Any]]
                 ) -> None:
        self.calibration = calibration
        self.sensor = sensor
        self.candidates = candidates
        effects = [*calibration.sensors[sensor].effects, *candidates]
        # the sensor and the neighbours its cross-talk terms and candidates read
        self.names = list(dict.fromkeys([sensor, *(str(e["params"]["neighbour"]) for e in effects
                                                   if e.get("kind") == "crosstalk")]))
        self.runs: list[dict[str, Recording]] = [
            dict(bag) for bag in runs
            if bag.get(sensor) is not None and bag[sensor].s is not None]
        self._cache: dict[tuple[tuple[int, float], ...], list[np.ndarray]] = {}
        # each validation run's session start with the calibration as given
        self.starts: list[Started] = [start_or_keep(*self._restricted(calibration, bag))
                                      for bag in self.runs]

    def redundant(self, j: int) -> bool:
        """Is candidate ``j`` what the session start makes itself (an output offset or gain)?"""
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
            self._cache[key] = [session_errors(*self._restricted(trial, bag), self.sensor)
                                for bag in self.runs]
        return self._cache[key]

    def _restricted(self, calibration: Calibration, bag: Mapping[str, Recording]
                    ) -> tuple[Calibration, dict[str, Recording]]:
        """``calibration`` and ``bag`` of the sensor and those neighbours only."""
        names = [n for n in self.names if n in calibration.sensors and n in bag]
        return (Calibration({n: calibration.sensors[n] for n in names}),
                {n: bag[n] for n in self.names if n in bag})

