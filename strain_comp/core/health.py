"""Per-sensor health: counters by sample status, the diagnostic level and message, and
the health a batch had at given times, as arrays (``HealthCounter``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from strain_comp.base.samples import STATUS_RULES, USED, USED_CODE, Status
from strain_comp.core.chain import SPIKE, STEP
from strain_comp.core.outputs import BatchOutput

_DIAG_OK, _DIAG_WARN, _DIAG_ERROR, _DIAG_STALE = 0, 1, 2, 3

@dataclass
class SensorHealth:
    """Counters of one sensor since start (or ``reset``) and its current state."""

    n_good: int = 0
    n_nan: int = 0
    n_non_positive: int = 0
    n_time_backwards: int = 0
    n_open: int = 0
    n_short: int = 0
    n_out_of_range: int = 0
    n_gaps: int = 0
    n_spikes: int = 0
    """Isolated spikes the input corrector kept from the model (``input.despike``)."""
    n_baseline_steps: int = 0
    """Baseline steps it re-based (``input.baseline_step``: a connector re-seated?)."""
    last_good_t: float | None = None
    last_status: Status | None = None
    stale: bool = False

    @property
    def n_bad(self) -> int:
        """Samples rejected (held estimate) of any kind."""
        return (self.n_nan + self.n_non_positive + self.n_time_backwards + self.n_open
                + self.n_short)

    def to_diagnostic(self) -> tuple[int, str, dict[str, str]]:
        """(level, message, key-values) as diagnostic_msgs/DiagnosticStatus carries them."""
        last = self.last_status
        if self.stale:
            level, message = _DIAG_STALE, "stale: no good sample recently"
        elif last is None:
            level, message = _DIAG_WARN, "no sample yet"
        elif last not in USED:
            level, message = _DIAG_ERROR, f"bad input ({last.name.lower()}): estimate held"
        elif last is Status.OUT_OF_RANGE:
            level, message = _DIAG_WARN, "resistance out of the calibrated range"
        elif last is Status.GAP_RESET:
            level, message = _DIAG_WARN, "state reset after a gap"
        else:
            level, message = _DIAG_OK, "ok"
        values: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self)
                                     if f.name.startswith("n_")}
        values["last_good_t"] = "none" if self.last_good_t is None else repr(self.last_good_t)
        values["last_status"] = "none" if last is None else last.name
        return level, message, {k: str(v) for k, v in values.items()}


STATUSES = tuple(Status)
"""Every ``Status``, indexed by its code."""
COUNTERS = tuple(f.name for f in fields(SensorHealth) if f.name.startswith("n_"))
"""The counters of ``SensorHealth``, in the order ``to_diagnostic`` lists them."""
_ADDS = np.zeros((len(Status) + 3, len(COUNTERS)), np.int64)
"""Counters (columns) one event adds to: each status code, a gap reset, a spike, a step."""
for _status, (_used, _counter) in STATUS_RULES.items():
    for _name in (("n_good",) if _used else ()) + ((_counter,) if _counter else ()):
        _ADDS[_status, COUNTERS.index(_name)] = 1
for _row, _name in enumerate(("n_gaps", "n_spikes", "n_baseline_steps"), len(Status)):
    _ADDS[_row, COUNTERS.index(_name)] = 1


def add_counts(h: SensorHealth, counts: np.ndarray) -> None:
    """Add event counts (the rows of ``_ADDS``, or its first rows) to ``h``'s counters."""
    for name, n in zip(COUNTERS, (counts @ _ADDS[:counts.size]).tolist(), strict=True):
        if n:
            setattr(h, name, getattr(h, name) + n)


_STATES = [SensorHealth(stale=True).to_diagnostic()[:2],
           *(SensorHealth(last_status=s).to_diagnostic()[:2] for s in (None, *STATUSES))]
"""(level, message) when stale, with no sample yet, after each status code (row: code + 2)."""
LEVELS = np.array([level for level, _ in _STATES], np.uint8)
MESSAGES = np.array([message.encode() for _, message in _STATES])
_LAST_STATUS = np.array([b"none", *(s.name.encode() for s in STATUSES)])


@dataclass(frozen=True)
class HealthTicks:
    """A sensor's health at each of K ticks."""

    counters: np.ndarray
    """(K, len(COUNTERS)) int64."""
    last_status: np.ndarray
    """(K,) status code, -1: none yet."""
    last_good_t: np.ndarray
    """(K,) [s], NaN: none yet."""
    stale: np.ndarray
    """(K,) bool: no good sample for longer than the sensor's stale time."""

    def diagnostic(self, good_t: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, np.ndarray]]]:
        """``SensorHealth.to_diagnostic`` at each tick (``good_t``: ``times_text`` of them)."""
        state = np.where(self.stale, 0, self.last_status + 2)
        values = [(name, self.counters[:, j]) for j, name in enumerate(COUNTERS)]
        values += [("last_good_t", good_t), ("last_status", _LAST_STATUS[self.last_status + 1])]
        return LEVELS[state], MESSAGES[state], values


def times_text(t: np.ndarray) -> np.ndarray:
    """``repr`` of each time [s] as UTF-8 bytes, ``none`` for NaN (each distinct one once)."""
    found = np.full(t.size, b"none", dtype="S32")
    known = ~np.isnan(t)
    bits, where = np.unique(t[known].view(np.int64), return_inverse=True)  # -0.0 kept apart
    found[known] = np.array([repr(v).encode() for v in bits.view(np.float64).tolist()],
                            dtype="S32")[where]
    return found


class HealthCounter:
    """A sensor's health at any tick of one run: cumulative counts, so a tick is a lookup."""

    def __init__(self, before: SensorHealth, t: np.ndarray | None = None,
                 out: BatchOutput | None = None) -> None:
        self.before = before
        self.t = np.empty(0) if t is None or out is None else t
        n = self.t.size
        self.counts = np.array([[getattr(before, name) for name in COUNTERS]], np.int64)
        self.status = np.empty(0, np.int64)
        self.last_used = np.empty(0, np.int64)
        if out is not None and n:
            events = np.zeros((n + 1, _ADDS.shape[0]), np.int64)
            events[1:, :len(Status)] = out.status[:, None] == np.arange(len(Status))
            if out.reset is not None:
                events[1:, len(Status)] = out.reset
            if out.corrections is not None:
                events[1:, len(Status) + 1:] = (out.corrections[:, None]
                                                == np.array([SPIKE, STEP]))
            self.counts = self.counts + np.cumsum(events, axis=0) @ _ADDS
            self.status = out.status.astype(np.int64)
            self.last_used = np.maximum.accumulate(
                np.where(USED_CODE[out.status], np.arange(n), -1))
        self.order = np.maximum.accumulate(self.t)

    def at(self, ticks: np.ndarray, *, stale_after: float) -> HealthTicks:
        """The health at each of ``ticks`` [s] (as ``Engine.health(now=tick)``)."""
        before = self.before
        pos = np.searchsorted(self.order, ticks, side="right")
        last_status = np.full(ticks.size, -1 if before.last_status is None
                              else before.last_status.value, np.int64)
        last_good_t = np.full(ticks.size, np.nan if before.last_good_t is None
                              else before.last_good_t)
        seen = pos > 0
        last_status[seen] = self.status[pos[seen] - 1]
        used = np.full(ticks.size, -1)
        used[seen] = self.last_used[pos[seen] - 1]
        last_good_t[used >= 0] = self.t[used[used >= 0]]
        stale = np.isnan(last_good_t) | (ticks - last_good_t > stale_after)
        return HealthTicks(self.counts[pos], last_status, last_good_t, stale)


def diagnostics(health: Mapping[str, SensorHealth]) -> list[tuple[str, int, str, dict[str, str]]]:
    """``(name, level, message, values)`` per sensor, as BagWriter and the nodes publish."""
    return [(status_name(name), *h.to_diagnostic()) for name, h in health.items()]


def status_name(sensor: str) -> str:
    """The DiagnosticStatus name of ``sensor``'s health."""
    return f"strain_comp: {sensor}"

