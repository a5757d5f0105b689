"""The model registry: every family the calibration file names (docs/design.md) registered
once by importing ``strain_comp.models``, an unknown name refused in one line."""

from __future__ import annotations

import pytest

from strain_comp.base.registry import array_families, model_class, model_names, register
from strain_comp.errors import ParameterError
from strain_comp.models.apl import APL, APLArray
from strain_comp.models.creep_pi import CreepPIArray

DESIGN_MODELS = ("apl", "pl", "mpi", "cubic", "sinh_pl", "rational", "spike_decay",
                 "creep_pi")
"""The models of docs/design.md's calibration file, in its order."""


def test_every_model_registered_under_its_name() -> None:
    assert model_names() == DESIGN_MODELS
    assert all(model_class(name).name == name for name in DESIGN_MODELS)


def test_array_forms_registered() -> None:
    assert array_families() == (APLArray, CreepPIArray)


def test_unknown_model_is_one_line_naming_the_known() -> None:
    with pytest.raises(ParameterError) as err:
        model_class("quintic")
    message = str(err.value)
    assert "\n" not in message and "'quintic'" in message
    assert message.endswith("known: " + ", ".join(DESIGN_MODELS))


def test_a_second_model_of_a_name_is_refused() -> None:
    class Other(APL):
        pass

    with pytest.raises(TypeError, match="two models named 'apl'"):
        register(Other)
    assert model_class("apl") is APL
