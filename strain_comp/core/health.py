"""Per-sensor health: counters by sample status, the diagnostic level and message
(diagnostic_msgs/DiagnosticStatus), and the health a batch had at given times."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

import numpy as np

from strain_comp.core.chain import SPIKE, STEP
from strain_comp.core.outputs import BatchOutput
from strain_comp.core.samples import STATUS_RULES, USED, USED_CODE, Status

_DIAG_OK, _DIAG_WARN, _DIAG_ERROR, _DIAG_STALE = 0, 1, 2, 3
LEVEL_NAMES = {_DIAG_OK: "OK", _DIAG_WARN: "WARN", _DIAG_ERROR: "ERROR", _DIAG_STALE: "STALE"}

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
    baseline_tracked_s: float = 0.0
    """Seconds at rest over which baseline tracking moved the zero
    (``strain_comp.core.tracking``)."""
    baseline_correction: float = 0.0
    """Its total change of the tare gain (share: +0.02 is 2 % more gain)."""

    def count(self, status: Status, n: int = 1) -> None:
        """Add ``n`` samples of ``status`` to the counters (``STATUS_RULES``)."""
        used, counter = STATUS_RULES[status]
        if used:
            self.n_good += n
        if counter is not None:
            setattr(self, counter, getattr(self, counter) + n)

    @property
    def n_bad(self) -> int:
        """Samples rejected (held estimate) of any kind."""
        return (self.n_nan + self.n_non_positive + self.n_time_backwards + self.n_open
                + self.n_short)

    def to_diagnostic(self) -> tuple[int, str, dict[str, str]]:
        """(level, message, key-values) as diagnostic_msgs/DiagnosticStatus carries them.

        STALE: no good sample for longer than ``stale_after`` (as of ``health(now)``);
        ERROR: the latest sample was rejected (the estimate is being held); WARN: the
        latest sample was out of range or followed a gap reset; OK otherwise.
        """
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
        if self.baseline_tracked_s > 0:
            values["baseline_tracked_s"] = f"{self.baseline_tracked_s:.6g}"
            values["baseline_correction"] = f"{self.baseline_correction:.6g}"
        return level, message, {k: str(v) for k, v in values.items()}


if {c for _, c in STATUS_RULES.values() if c} - {f.name for f in fields(SensorHealth)}:
    raise AssertionError("every counter of STATUS_RULES must be a SensorHealth field")


STATUSES = tuple(Status)
"""Every ``Status``, indexed by its code."""
_COUNTERS = tuple((("n_good",) if used else ()) + ((counter,) if counter else ())
                  for used, counter in (STATUS_RULES[s] for s in STATUSES))
"""The health counters a sample of each status code adds to (from ``STATUS_RULES``)."""


def add_counts(h: SensorHealth, counts: np.ndarray) -> None:
    """Add per-``Status`` sample counts (indexed by status code; a further entry, the gap
    resets, is left out) to ``h``'s counters."""
    for names, n in zip(_COUNTERS, counts.tolist(), strict=False):
        if n:
            for name in names:
                setattr(h, name, getattr(h, name) + n)


def health_at(before: SensorHealth, t: np.ndarray, out: BatchOutput, ticks: np.ndarray, *,
              stale_after: float) -> list[SensorHealth]:
    """A sensor's health at each of ``ticks`` [s] from one ``run``'s statuses: ``before``
    (its health when the run started) plus the counts of the samples at or before each tick
    (``t`` in order), what ``Engine.health(now=tick)`` would have said had the run been cut
    there."""
    n = t.size
    pos = np.searchsorted(np.maximum.accumulate(t), ticks, side="right")
    cum = np.zeros((n + 1, len(Status) + 1), np.int64)
    cum[1:, :len(Status)] = np.cumsum(
        out.status[:, None].astype(np.int64) == np.arange(len(Status)), axis=0)
    if out.reset is not None:
        cum[1:, -1] = np.cumsum(out.reset)
    fixes = np.zeros((n + 1, 2), np.int64)
    if out.corrections is not None:
        fixes[1:] = np.cumsum(out.corrections[:, None] == np.array([SPIKE, STEP]), axis=0)
    last_used = np.maximum.accumulate(np.where(USED_CODE[out.status], np.arange(n), -1))
    found = []
    for now, k in zip(ticks.tolist(), pos.tolist(), strict=True):
        h = replace(before)
        add_counts(h, cum[k, :-1])
        h.n_gaps += int(cum[k, -1])
        h.n_spikes += int(fixes[k, 0])
        h.n_baseline_steps += int(fixes[k, 1])
        if k:
            h.last_status = Status(int(out.status[k - 1]))
            if last_used[k - 1] >= 0:
                h.last_good_t = float(t[last_used[k - 1]])
        h.stale = h.last_good_t is None or now - h.last_good_t > stale_after
        found.append(h)
    return found


def diagnostics(health: Mapping[str, SensorHealth], *, prefix: str = "strain_comp"
                ) -> list[tuple[str, int, str, dict[str, str]]]:
    """``(name, level, message, values)`` per sensor, as BagWriter and the nodes publish."""
    return [(f"{prefix}: {name}", *h.to_diagnostic()) for name, h in health.items()]

