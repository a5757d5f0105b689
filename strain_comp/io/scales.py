"""The factors a table's columns are scaled by (``import-csv --scales``,
``Recording.from_frame``), checked and applied one way."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from strain_comp.errors import InputError

SCALE_KEYS = ("time", "resistance", "strain")
"""The columns a table's ``scales`` (``import-csv --scales``) multiply."""


def check_scales(scales: Mapping[str, float] | None, where: str,
                 keys: Sequence[str] = SCALE_KEYS) -> None:
    """Check factors per column (``import-csv --scales``, ``Recording.from_frame``)."""
    for key, factor in (scales or {}).items():
        if key not in keys:
            raise InputError(f"{where}: unknown scale key {key!r} (one of {', '.join(keys)})")
        sign_ok = isinstance(factor, (int, float)) and not isinstance(factor, bool) and (
            factor != 0 if key == "strain" else factor > 0)
        if not (sign_ok and np.isfinite(factor)):
            need = "a number other than 0" if key == "strain" else "a number > 0"
            raise InputError(f"{where}: scale {key}={factor!r} must be {need}")


def scaled(where: str, key: str, raw: np.ndarray, factor: float) -> np.ndarray:
    """``raw`` times its scale ``factor``."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = raw * factor
    if np.any(np.isfinite(raw) & ~np.isfinite(out)):
        raise InputError(f"{where}: --scales {key}={factor:g}: the scaled values "
                         "overflow (beyond 1.8e308); check the factor")
    return out
