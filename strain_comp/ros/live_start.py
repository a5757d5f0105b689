"""``~/start`` of a live node: the next stretch and return on the reference topics, then the
offline session start (``strain_comp.offline.session_start.start``); its states and rules:
docs/ros.md, "Services"."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError, ParameterError
from strain_comp.io.recording import Recording, hold_latest
from strain_comp.offline.session_start import MIN_CYCLE_SHARE, cycle_end
from strain_comp.offline.session_start import start as session_start

RECENT_S = 5.0
"""A sensor has a reference when one arrived within this many seconds of ``~/start``."""
MAX_WATCH_S = 600.0
"""A stretch not complete this long after ``~/start`` is refused."""
MAX_SAMPLES = 2**20
"""Samples kept per sensor while watching (past them the start is refused)."""
CHECK_EVERY_S = 0.5
"""The stretch is looked for at most this often [s of reference time]."""


@dataclass
class _Series:
    """A sensor's samples since ``~/start``: inputs and references."""

    t: list[float] = field(default_factory=list)
    r: list[float] = field(default_factory=list)
    ref_t: list[float] = field(default_factory=list)
    ref: list[float] = field(default_factory=list)


class LiveStart:
    """``~/start``'s state and the samples it watches."""

    def __init__(self) -> None:
        self.state = "idle"
        self.detail = "~/start not called"
        self.since = math.nan
        self.series: dict[str, _Series] = {}
        self._last_reference: dict[str, float] = {}
        self._checked = -math.inf

    def request(self, now: float, sensors: list[str]) -> bool:
        """Watch the sensors with a recent reference (True), or none has one (False)."""
        if self.state in ("waiting", "recording"):
            raise ParameterError("start", f"refused: already {self.state} (since "
                                 f"{self.since:.1f} s); the stretch applies when it returns")
        referenced = [s for s in sensors
                      if now - self._last_reference.get(s, -math.inf) <= RECENT_S]
        if not referenced:
            return False
        self.series = {s: _Series() for s in referenced}
        self.state, self.since, self._checked = "waiting", now, -math.inf
        self.detail = ("waiting for a stretch and return on "
                       + ", ".join(f"{s}/strain_reference" for s in referenced))
        return True

    def outcome(self, state: str, detail: str) -> None:
        """Set a final state (``applied`` or ``refused``)."""
        self.state, self.detail, self.series = state, detail, {}

    def seen_inputs(self, sensors: tuple[str, ...], t: np.ndarray, raw: np.ndarray) -> None:
        """Raw input samples (columns: ``sensors``), kept for the sensors watched."""
        for j, sensor in enumerate(sensors if self.series else ()):
            if sensor in self.series:
                room = max(MAX_SAMPLES - len(self.series[sensor].t), 0)
                self.series[sensor].t.extend(t[:room].tolist())
                self.series[sensor].r.extend(raw[:room, j].tolist())

    def seen_reference(self, sensor: str, t: float, value: float,
                       calibration: Calibration) -> Calibration | None:
        """A reference of ``sensor``: the started calibration once every stretch returned."""
        self._last_reference[sensor] = t
        series = self.series.get(sensor)
        if series is None or not math.isfinite(value):
            return None
        series.ref_t.append(t)
        series.ref.append(float(value))
        if t - self._checked < CHECK_EVERY_S:
            return None
        self._checked = t
        if t - self.since > MAX_WATCH_S or len(series.t) >= MAX_SAMPLES:
            self.outcome("refused", f"refused: no complete stretch and return within "
                         f"{MAX_WATCH_S:g} s of ~/start")
            return None
        done = [self._progress(name, s, calibration) for name, s in self.series.items()]
        if not all(done):
            return None
        return self._apply(calibration)

    def _progress(self, name: str, series: _Series, calibration: Calibration) -> bool:
        """Has ``name``'s stretch returned? (``recording`` once it moved far enough.)"""
        vr = calibration.sensors[name].valid_range
        ref = np.array(series.ref)
        if ref.size < 2 or not ref.max() - ref.min() >= MIN_CYCLE_SHARE * (vr.s_hi - vr.s_lo):
            return False
        if self.state == "waiting":
            self.state = "recording"
            self.detail = "recording the stretch on " + ", ".join(self.series)
        return cycle_end(np.array(series.ref_t), ref) is not None

    def _apply(self, calibration: Calibration) -> Calibration | None:
        """``strain-comp start``'s session start on the recorded stretch (None: refused)."""
        recordings = {name: Recording(name, np.array(s.t), np.array(s.r),  # the reference held
                                      hold_latest(s.t, s.ref_t, s.ref))
                      for name, s in self.series.items()}
        watched = Calibration({n: calibration.sensors[n] for n in recordings})
        ends = [float(r.t[-1] - r.t[0]) for r in recordings.values() if r.t.size]
        try:
            started = session_start(watched, recordings, window=(0.0, max(ends, default=0.0)),
                            source="the stretch recorded after ~/start")
        except InputError as err:
            self.outcome("refused", f"refused: {err}")
            return None
        self.outcome("applied", "applied: stretch RMSE " + ", ".join(
            f"{r.sensor} {r.rmse:.4g} {r.unit}" for r in started.records))
        return Calibration({**calibration.sensors, **started.calibration.sensors})

