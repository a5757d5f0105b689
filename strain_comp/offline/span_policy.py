"""The tuned numbers of the session start: the input zero and span from a recording
(``offline/span.py``), its window and cycles (``offline/session_window.py``) and the output
map from a recording (``offline/recalibrate.py``). docs/results.md gives each one's value,
what it does and the measurement that keeps it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SpanPolicy:
    """The session start's numbers (resolutions, the search, the refusals)."""

    settle_samples: int = 200
    """Samples at a constant resistance (at 10 Hz) before a steady output is read
    [samples]."""
    grid_points: int = 201
    """Resistances of the steady-output grid over the valid range that
    ``calibrated_resistance`` inverts [points]."""
    static_tolerance: float = 0.01
    """A model whose slow ramp stays this close to its steady outputs is static (two
    points invert it); else it has memory and is spanned on its branches and through the
    run [share of the strain span]."""
    fit_evaluations: int = 80
    """Engine runs over the calibration stretch the search of a memory model's zero and
    span may take (Nelder-Mead; 0: the two-point span is kept) [runs]."""
    fit_step: tuple[float, float] = (0.05, 0.2)
    """The search's first steps: of the calibrated rest resistance [share of the valid
    resistance range] and of the log of the span gain [1]."""
    fit_tolerance: tuple[float, float] = (1e-3, 1e-4)
    """The search stops when its steps fall under the first [as ``fit_step``] and its
    RMSE changes less than the second [strain unit]."""
    from_cover: float = 0.1
    """Share of the calibrated strain span the reference must move through for ``--from``:
    a gain and offset are fitted over a stretch of the range, not a point of it (the
    README's session start, ``bags/demo_rates.mcap``, first 30 s, moves through 17 % of
    its span) [share of the strain span]."""
    cycle_up: float = 0.5
    """A cycle (``cycle_end``, ``stretch_and_return``): the reference passes this share of
    its span above its minimum [share of the reference's span] ..."""
    cycle_back: float = 0.1
    """... then returns to within this share of it [share of the reference's span]."""
    min_cycle_share: float = 0.1
    """A ``--window``'s stretch must span at least this share of the calibration's strain
    range [share of the strain span]."""


SPAN = SpanPolicy()
"""The policy every session start uses unless given another."""
