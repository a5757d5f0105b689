"""strain_comp: calibrated strain from the resistance of soft strain sensors.

The core (models, fitting, direction detection, bag I/O, evaluation, diagnosis) imports no
ROS module; ``strain_comp.ros.node`` is a thin rclpy layer over ``strain_comp.core.engine``.
Contracts (layout, topics, units, files, command line): docs/design.md; the papers the
docstrings cite by key and equation number: docs/references.md.
"""

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
    """The public names (``__all__``) with the module's own, for ``dir()``, tab completion
    and ``help()``, without importing ``strain_comp.api``."""
    return sorted({*__all__, *globals()} - {"Any", "TYPE_CHECKING"})


def __getattr__(name: str) -> Any:
    """``strain_comp.fit`` and the rest of ``strain_comp.api``, imported on first use, so
    ``strain-comp --version`` and ``--help`` do not load numpy."""
    if name in __all__:
        from strain_comp import api

        return getattr(api, name)
    raise AttributeError(f"module 'strain_comp' has no attribute {name!r}")
