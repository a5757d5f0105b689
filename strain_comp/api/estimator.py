"""``StrainEstimator``: fit, predict and score under scikit-learn's names by the API's functions
(docs/api.md). ``Calibration`` (core, below the engine) has no such methods: the engine imports
it, so it cannot call the engine."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.api._inputs import as_calibration, checked
from strain_comp.api.estimation import estimate
from strain_comp.api.evaluation import evaluate
from strain_comp.api.fitting import fit
from strain_comp.api.inputs import CalibrationLike, Data
from strain_comp.core.calibration import Calibration
from strain_comp.errors import InputError


class StrainEstimator:
    """A model fitted to runs with a reference, then predicting strain from resistance and
    scored on other runs: ``StrainEstimator("apl").fit(train).score(test)``.

    ``calibration_`` is the calibration fitted (or given: ``from_calibration``); save it
    with ``save_calibration``.
    """

    def __init__(self, model: str = "cubic", **options: Any) -> None:
        """Args:
            model: As ``fit``'s ``model``.
            **options: ``fit``'s keyword arguments (``strain_unit``, ``pool``, the model's
                options), used by ``fit``.

        Raises:
            InputError: ``model`` is not text.

        """
        self.model = checked(model, "text", "model", optional=False)
        self.options = options
        self.calibration_: Calibration | None = None

    @classmethod
    def from_calibration(cls, calibration: CalibrationLike) -> StrainEstimator:
        """An estimator that predicts and scores with a calibration made before.

        Args:
            calibration: A ``Calibration`` or the path of a calibration file.

        Returns:
            The estimator, already fitted.

        Raises:
            InputError: ``calibration`` is neither, or the path cannot be read.
            CalibrationError: The file cannot be read.

        """
        cal = as_calibration(calibration)
        out = cls(next(iter(cal.sensors.values())).model if cal.sensors else "cubic")
        out.calibration_ = cal
        return out

    def __repr__(self) -> str:
        """The model, and the calibration once fitted."""
        return f"StrainEstimator({self.model!r}, calibration_={self.calibration_!r})"

    def fit(self, data: Data) -> StrainEstimator:
        """Fit the model (``fit(data, model, **options)``).

        Args:
            data: Bags, recordings or a list of runs, as ``fit`` takes them.

        Returns:
            This estimator, ``calibration_`` set.

        Raises:
            InputError: As ``fit``.
            BagError: A bag cannot be read.
            FitError: The model cannot be fitted.

        """
        self.calibration_ = fit(data, self.model, **self.options)
        return self

    def _fitted(self) -> Calibration:
        if self.calibration_ is None:
            raise InputError("StrainEstimator: call fit(data) first (or make it with "
                             "StrainEstimator.from_calibration)")
        return self.calibration_

    def predict(self, t: npt.ArrayLike, r: npt.ArrayLike, *, sensor: str | None = None,
                **options: Any) -> np.ndarray:
        """Strain per sample (``estimate(calibration_, t, r).strain``; NaN where a sample
        is not valid).

        Args:
            t: Time stamps [s], increasing.
            r: Resistance [ohm], one per time stamp.
            sensor: The sensor (default: the calibration's only one).
            **options: ``estimate``'s other keyword arguments (``tare``, ...).

        Returns:
            The strain in the calibration's unit.

        Raises:
            InputError: Not fitted, or as ``estimate``.

        """
        return estimate(self._fitted(), t, r, sensor=sensor, **options).strain

    def score(self, data: Data, **options: Any) -> dict[str, dict[str, Any]]:
        """The scores on a run with a reference (``evaluate(calibration_, data).scores``).

        Args:
            data: A bag or recordings.
            **options: ``evaluate``'s other keyword arguments (``tare``, ...).

        Returns:
            Sensor -> {model, n, rmse, mae, max_abs, r2, unit}.

        Raises:
            InputError: Not fitted, or as ``evaluate``.
            BagError: The bag cannot be read.

        """
        return evaluate(self._fitted(), data, **options).scores
