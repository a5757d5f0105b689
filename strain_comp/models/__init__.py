"""The model registry: model name (as in calibration files) -> compensator class.

Classes are imported on first use so that one model's import cost (numba compilation of
its kernels) is paid only by those who use it.
"""

from __future__ import annotations

import importlib

from strain_comp.base.compensator import Compensator, Normalisation, Segment
from strain_comp.errors import ParameterError

_REGISTRY: dict[str, str] = {
    "apl": "strain_comp.models.apl:APL",
    "pl": "strain_comp.models.apl:PL",
    "mpi": "strain_comp.models.apl:MPI",
    "cubic": "strain_comp.models.cubic:Cubic",
    "sinh_pl": "strain_comp.models.sinh_pl:SinhPL",
    "rational": "strain_comp.models.rational:Rational",
    "spike_decay": "strain_comp.models.spike_decay:SpikeDecay",
    "creep_pi": "strain_comp.models.creep_pi:CreepPI",
}

MODEL_NAMES: tuple[str, ...] = tuple(_REGISTRY)


def model_class(name: str) -> type[Compensator]:
    """The compensator class registered under ``name``."""
    if name not in _REGISTRY:
        raise ParameterError("name", f"unknown model {name!r}; known: {', '.join(MODEL_NAMES)}")
    module_name, class_name = _REGISTRY[name].split(":")
    found = getattr(importlib.import_module(module_name), class_name)
    if not (isinstance(found, type) and issubclass(found, Compensator)):
        raise TypeError(f"{_REGISTRY[name]} is not a Compensator")
    return found


__all__ = ["MODEL_NAMES", "Compensator", "Normalisation", "Segment", "model_class"]
