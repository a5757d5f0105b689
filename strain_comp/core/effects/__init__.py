"""Effect terms: online corrections a static or hysteretic inverse model lacks,
S_corrected = S_hat - sum_j c_j g_j (the regressors' contract and signals:
docs/architecture.md, "Inside the modules").
"""

from __future__ import annotations

from strain_comp.core.effects.history import (
    STRETCH_FORMS,
    Baseline,
    Direction,
    Elapsed,
    Mullins,
    Stretch,
)
from strain_comp.core.effects.memory import (
    Rate,
    Relaxation,
    ResistanceMemory,
)
from strain_comp.core.effects.regressor import (
    Batch,
    Regressor,
    Sample,
    choice_param,
    ffill,
    number_param,
    positive_param,
    run_segments,
)
from strain_comp.core.effects.static import (
    TEMPERATURE_RANGE,
    Crosstalk,
    Offset,
    StrainLevel,
    Temperature,
    valid_temperature,
)
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
    "Baseline",
    "Batch",
    "Crosstalk",
    "Direction",
    "EffectTerms",
    "Elapsed",
    "Mullins",
    "Offset",
    "Rate",
    "Regressor",
    "Relaxation",
    "ResistanceMemory",
    "Sample",
    "StrainLevel",
    "Stretch",
    "Temperature",
    "choice_param",
    "effect_dict",
    "ffill",
    "number_param",
    "positive_param",
    "regressor_from_dict",
    "run_segments",
    "valid_temperature",
    "validate_effect_dict",
]
