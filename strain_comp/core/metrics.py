"""Error metrics, in % strain: RMSE ([Electrolycra] eq. (5)), MAE, max error, R^2,
and the normalised hysteresis area ([ReducedPL] eq. (5))."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class ErrorStats:
    """Errors of an estimate against a reference over n finite sample pairs."""

    rmse: float
    mae: float
    max_abs: float
    r2: float
    n: int

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def error_stats(estimate: npt.ArrayLike, reference: npt.ArrayLike) -> ErrorStats:
    """RMSE = sqrt(mean((S_hat - S)^2)) (eq. (5)), MAE, max |e|, R^2 over finite pairs."""
    s_hat = np.asarray(estimate, dtype=np.float64)
    s = np.asarray(reference, dtype=np.float64)
    ok = np.isfinite(s_hat) & np.isfinite(s)
    if not ok.any():
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, 0)
    e = s_hat[ok] - s[ok]
    ss_tot = float(np.sum((s[ok] - s[ok].mean()) ** 2))
    r2 = 1.0 - float(np.sum(e**2)) / ss_tot if ss_tot > 0 else float("nan")
    return ErrorStats(rmse=float(np.sqrt(np.mean(e**2))), mae=float(np.mean(np.abs(e))),
                      max_abs=float(np.max(np.abs(e))), r2=r2, n=int(ok.sum()))


def hysteresis_area(x: npt.ArrayLike, y: npt.ArrayLike, n_periods: int) -> float:
    """Normalised hysteresis area, [ReducedPL] eq. (5).

    A = (1/n) * integral of y_hat d x_hat over the n periods, with x_hat and y_hat
    min-max normalised to [0, 1]. A closed loop travelled counter-clockwise gives a
    positive area, clockwise a negative one; a single-valued curve gives ~0.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x_hat = (x - x.min()) / (x.max() - x.min())
    y_hat = (y - y.min()) / (y.max() - y.min())
    # trapezoidal rule for the line integral of y dx along the sampled path
    integral = float(np.sum(0.5 * (y_hat[1:] + y_hat[:-1]) * np.diff(x_hat)))
    return -integral / n_periods
