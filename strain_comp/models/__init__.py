"""The compensators. Importing this package registers every model family (and its array
form) in ``strain_comp.base.registry``, where the calibration reader and the engine look
them up; ``MODEL_NAMES`` are the registered names."""

from __future__ import annotations

from strain_comp.base.compensator import Compensator, Normalisation, Segment
from strain_comp.base.registry import model_class, model_names

# imported to register their families, in the order of MODEL_NAMES
# isort: off
from strain_comp.models import apl, cubic, sinh_pl  # noqa: F401
from strain_comp.models import rational, spike_decay, creep_pi  # noqa: F401
# isort: on

MODEL_NAMES: tuple[str, ...] = model_names()

__all__ = ["MODEL_NAMES", "Compensator", "Normalisation", "Segment", "model_class"]
