"""The model registry: name -> compensator class (``register``) and the array forms
(``register_array``), filled when ``strain_comp.models`` is imported."""

from __future__ import annotations

from typing import TypeVar

from strain_comp.base.compensator import Compensator
from strain_comp.base.lift import LiftedArray
from strain_comp.errors import ParameterError

_Model = TypeVar("_Model", bound=type[Compensator])
_Array = TypeVar("_Array", bound=type[LiftedArray])
_MODELS: dict[str, type[Compensator]] = {}
_ARRAYS: list[type[LiftedArray]] = []


def register(cls: _Model) -> _Model:
    """Class decorator: ``cls`` is the model named ``cls.name``."""
    if _MODELS.setdefault(cls.name, cls) is not cls:
        raise TypeError(f"two models named {cls.name!r}: {_MODELS[cls.name]!r} and {cls!r}")
    return cls


def register_array(cls: _Array) -> _Array:
    """Class decorator: ``cls`` is the array form of its family (the engine's fused tick)."""
    _ARRAYS.append(cls)
    return cls


def model_names() -> tuple[str, ...]:
    """The registered models' names, in the order they registered."""
    return tuple(_MODELS)


def model_class(name: str) -> type[Compensator]:
    if name not in _MODELS:
        known = ", ".join(_MODELS) or "none registered"
        raise ParameterError("name", f"unknown model {name!r}; known: {known}")
    return _MODELS[name]


def array_families() -> tuple[type[LiftedArray], ...]:
    """The registered array forms, in the order a tick runs them."""
    return tuple(_ARRAYS)
