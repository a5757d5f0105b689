"""Offline work on bags: the virtual rig, fitting, evaluation, replay and plots."""

# every offline command reads or writes calibrations: the model families register here
from strain_comp import models  # noqa: F401
