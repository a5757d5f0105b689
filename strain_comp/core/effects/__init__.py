"""Effect terms: online corrections a static or hysteretic inverse model lacks.

The residual loop (docs/design.md, "The residual loop"; ``strain_comp.diagnosis``) finds which
physical effect explains the residual e = S_hat - S of a calibrated model and adds it as
an explicit term. Each effect is a *regressor* g_j computed causally, sample by sample,
from what a running model knows: time t [s], resistance R [ohm], the model's own estimate
S_hat [%], the direction detector's output d (+1 loading, 0 hold, -1 unloading), an
optional temperature T and the estimates of array neighbours. The corrected strain is

    S_corrected = S_hat - sum_j c_j g_j

with coefficients c_j fitted by least squares on the residual. A constant term is an
ordinary effect of kind ``offset`` (g = 1): the residual loop fits it together with every
other effect, so the correction never shifts the output by an offset it did not test.

Regressors use S_hat (not R) as their signal wherever a signal is needed: S_hat is in
strain units (coefficients are then dimensionless or in seconds) and monotone in strain
even where R is not (carbon-black sensors). The one exception, ``resistance_memory``
(``ResistanceMemory``), reads 100 ln R on purpose: what R still shows where S_hat has lost
it. R is what the model reads (converted, times the tare gain, after the input corrections).

Calibration-file form (one entry of a sensor's ``effects:`` list)::

    {name: relaxation_loading_tau10, kind: relaxation,
     params: {tau: 10.0, branch: loading}, coef: 0.031}

Every parameter has a default, so ``params: {}`` is valid. Each regressor has ``reset()``,
``step(sample) -> float`` and a batch ``run(batch) -> array`` that continues from the
current state and leaves it where repeated ``step`` calls would. The engine resets the
state wherever it resets the model (start, ``reset()``, a gap reset), so a ``baseline``
(``Baseline``) is captured again at the start of every run; a tare during a run
(``Engine.set_input_gain``) carries the state of R-reading terms over (``rescale``).

The kinds by family: ``static`` (no memory), ``memory`` (fading memories), ``history``
(the run's history), on the contract of ``regressor``; ``terms`` runs a sensor's terms.
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
