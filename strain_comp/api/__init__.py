"""strain_comp from Python: fit, estimate, evaluate, recalibrate and diagnose on arrays,
tables or bags (docs/api.md walks through it).

The functions here are what the ``strain-comp`` commands call, so a notebook gets the
command line's numbers: ``estimate`` runs ``strain_comp.core.engine.Engine`` (the node's and
``replay``'s engine), ``evaluate`` the ``evaluate`` command's streamed scoring, ``fit`` its
fits. Input is numpy arrays (``Recording.from_arrays``), a table (``Recording.from_frame``:
a pandas DataFrame or a mapping of columns), or bags (paths: MCAP, rosbag2 directories,
``.db3``). pandas is optional: ``to_frame`` methods need it, nothing else does.

Errors: every bad input raises a ``StrainCompError`` (``strain_comp.errors``) whose message is
the line ``strain-comp`` prints after ``strain-comp: error:``. Nothing here writes a file
unless a path to write is given (``save_calibration``, ``csv=``, ``out=``, ``plots=``).
"""

from strain_comp.api.diagnosis import Diagnosis, diagnose
from strain_comp.api.estimation import Estimate, estimate, replay
from strain_comp.api.estimator import StrainEstimator
from strain_comp.api.evaluation import Evaluation, evaluate
from strain_comp.api.fitting import fit
from strain_comp.api.inputs import (
    CalibrationLike,
    Data,
    PathLike,
    load_calibration,
    read_recordings,
    save_calibration,
)
from strain_comp.api.recalibration import Recalibration, recalibrate, session_start
from strain_comp.core.calibration import Calibration
from strain_comp.errors import StrainCompError
from strain_comp.io.recording import Recording

__all__ = ["Calibration", "CalibrationLike", "Data", "Diagnosis", "Estimate", "Evaluation",
           "PathLike", "Recalibration", "Recording", "StrainCompError", "StrainEstimator",
           "diagnose", "estimate", "evaluate", "fit", "load_calibration", "read_recordings",
           "recalibrate", "replay", "save_calibration", "session_start"]
