"""The residual loop's selection rule in numbers (docs/results.md, "Residual loop").

Every number that decides whether the loop (``strain_comp.diagnosis.loop``) adds a term is a
field of ``LoopPolicy``, with its unit; docs/results.md gives for each the measured figure
that keeps it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LoopPolicy:
    """How the loop decides (docs/results.md, "Residual loop")."""

    margin: float = 0.03
    """[1, relative RMSE] Least fall of the error for a term (or a condition) to count:
    of the cross-validated RMSE on the diagnosed run, and of the validation runs' upper
    bound below (a term must lower it below ln(1 - margin))."""
    significance: float = 1.0
    """[standard errors over the cross-validation folds] The fold-wise drop of the
    squared error on the diagnosed run must exceed this many standard errors
    (``selection.significant``): a term that helps in a few stretches and hurts in
    others fits a coincidence of the profile."""
    level: float = 0.95
    """[one-sided probability] A term's upper bound is the prediction bound, at this
    level, of its log RMSE ratio on one more run, from the ratios on the validation runs
    after their session start (``selection.upper_bound``: Student's t with the runs less
    one degrees of freedom): what a later run may get, given how much the runs differ and
    how few of them there are. With two runs the bound is the mean plus 5.5 times their
    difference: a term is added only where both runs agree on its gain."""
    tried: int = 16
    """[candidates per step] The candidates that pass on the diagnosed run, best first,
    scored on the validation runs at each step (each costs one session start and one
    ``evaluate`` per validation run)."""
    max_effects: int = 3
    """[terms] The most terms one diagnosis adds to a sensor."""


LOOP_POLICY = LoopPolicy()
"""The product's policy."""
