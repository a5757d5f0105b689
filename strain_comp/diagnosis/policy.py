"""The residual loop's selection rule in numbers: each field with its unit; docs/results.md
("Residual loop", ``LoopPolicy``) gives what each does and the measured figure that keeps it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LoopPolicy:
    """How the loop decides (``studies/measured_diagnose.py --policy FIELD=VALUE`` varies it)."""

    margin: float = 0.03
    """[1, relative RMSE] least fall of the error for a term (or a condition) to count."""
    significance: float = 1.0
    """[standard errors over the folds] least fold-wise drop on the diagnosed run."""
    level: float = 0.95
    """[one-sided probability] of the prediction bound of one more run's log RMSE ratio."""
    tried: int = 16
    """[candidates per step] scored on the validation runs at each step."""
    max_effects: int = 3
    """[terms] the most terms one diagnosis adds to a sensor."""


LOOP_POLICY = LoopPolicy()
"""The product's policy."""
