"""strain_comp: calibrated strain from the resistance of soft strain sensors. Only
``strain_comp.ros`` imports ROS; contracts: docs/design.md; the papers the docstrings cite
by key and equation number: docs/references.md."""

from typing import TYPE_CHECKING, Any

from strain_comp.version import __version__

__all__ = ["Calibration", "Diagnosis", "Estimate", "Evaluation", "Recalibration", "Recording",
           "StrainCompError", "StrainEstimator", "__version__", "diagnose", "estimate",
           "evaluate", "fit", "load_calibration", "read_recordings", "recalibrate", "replay",
           "save_calibration", "session_start"]

if TYPE_CHECKING:
    from strain_comp.api import (
        Calibration,
        Diagnosis,
        Estimate,
        Evaluation,
        Recalibration,
        Recording,
        StrainCompError,
        StrainEstimator,
        diagnose,
        estimate,
        evaluate,
        fit,
        load_calibration,
        read_recordings,
        recalibrate,
        replay,
        save_calibration,
        session_start,
    )


def __dir__() -> list[str]:
    """The public names and the module's own, without importing ``strain_comp.api``."""
    return sorted({*__all__, *globals()} - {"Any", "TYPE_CHECKING"})


def __getattr__(name: str) -> Any:
    """``strain_comp.api``'s names, imported on first use (``--help`` loads no numpy)."""
    if name in __all__:
        from strain_comp import api

        return getattr(api, name)
    raise AttributeError(f"module 'strain_comp' has no attribute {name!r}")
