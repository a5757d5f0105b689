"""Effect terms, online corrections S_corrected = S_hat - sum_j c_j g_j (docs/design.md,
"Effect terms"). The kinds by family: ``static`` (no memory), ``memory`` (fading memories),
``history`` (the run's history), on the contract of ``regressor``; ``terms`` runs them."""

from __future__ import annotations

from strain_comp.core.effects.history import STRETCH_FORMS
from strain_comp.core.effects.regressor import Batch, run_segments
from strain_comp.core.effects.static import TEMPERATURE_RANGE
from strain_comp.core.effects.terms import (
    KINDS,
    EffectTerms,
    effect_dict,
    regressor_from_dict,
    validate_effect_dict,
)

__all__ = [
    "KINDS",
    "STRETCH_FORMS",
    "TEMPERATURE_RANGE",
    "Batch",
    "EffectTerms",
    "effect_dict",
    "regressor_from_dict",
    "run_segments",
    "validate_effect_dict",
]
