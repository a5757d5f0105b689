"""Offline work on bags: the virtual rig, fitting, evaluation, replay and plots."""
