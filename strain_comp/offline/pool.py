"""Several training runs of one sensor put into one input space (``strain-comp fit --pool``;
docs/design.md, docs/results.md "Pooling and the session start").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.base.samples import good_mask
from strain_comp.errors import InputError
from strain_comp.offline.session_start import Line, calibration_stretch, cut, run_line

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

POOLS = ("spanned", "joint", "stretch", "raw")
"""How ``fit_sensor`` pools several runs (``fit --pool``)."""
POOL_GAIN = 0.7
"""The maps are kept where they lower the pooled cubic's RMSE to this share (``gate``)."""
POOL_DEGREE = 3
"""Degree of the pooled curve of strain on mapped resistance (``joint_maps``): a cubic."""
POOL_SAMPLES = 4000
"""Samples of each run (evenly thinned) the input maps are fitted on."""

Map = tuple[float, float]
"""(z, k) of a run's map R' = R_0,ref + k (R - z)."""
Joint = tuple[list[Map], float]
"""The joint space: each run's map and R_0,ref (``joint_maps``)."""


@dataclass
class Pooled:
    """Training runs as a pooled fit reads them."""

    runs: list[Recording]
    """The runs, mapped (or as recorded)."""
    maps: list[dict[str, float]]
    """Each run's map (``rest``, ``rest_calibrated``, ``span_gain``); empty as recorded."""
    record: dict[str, Any]
    """The provenance's ``pooling``."""
    stretch_line: Line | None = None
    """The line the stretches share (``InputSettings.stretch_line``), for ``stretch``."""


def _lines(recordings: Sequence[Recording]) -> list[Line] | None:
    """Each run's line (``run_line``), or None where one has none or their signs differ."""
    lines = [run_line(rec) for rec in recordings]
    found = [line for line in lines if line is not None]
    if len(found) < len(lines) or len({np.sign(g) for _, g in found}) > 1:
        return None
    return found


def _anchor(lines: Sequence[Line]) -> int:
    """The run of median sensitivity (the lower middle one of an even count)."""
    return int(np.argsort([abs(g) for _, g in lines])[(len(lines) - 1) // 2])


def _thinned(recordings: Sequence[Recording]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each run's good, referenced (R, S), evenly thinned to about ``POOL_SAMPLES``."""
    data = []
    for rec in recordings:
        assert rec.s is not None  # the runs have lines
        ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
        step = max(1, int(ok.sum()) // POOL_SAMPLES)
        data.append((np.asarray(rec.r, dtype=np.float64)[ok][::step],
                     np.asarray(rec.s, dtype=np.float64)[ok][::step]))
    return data


def curve_rmse(recordings: Sequence[Recording], maps: Sequence[Map], r_ref: float) -> float:
    """RMSE of the pooled cubic of strain on mapped resistance through the mapped runs."""
    data = _thinned(recordings)
    mapped = np.concatenate([r_ref + k * (r - z) for (r, _), (z, k) in zip(data, maps,
                                                                          strict=True)])
    s_all = np.concatenate([s for _, s in data])
    mapped = mapped / float(np.median(np.abs(mapped)))
    fitted = np.polyval(np.polyfit(mapped, s_all, POOL_DEGREE), mapped)
    return float(np.sqrt(np.mean((fitted - s_all) ** 2)))


def joint_maps(recordings: Sequence[Recording]) -> Joint | None:
    """Each run's affine map onto the median-sensitivity run, fitted jointly with a cubic."""
    from scipy.optimize import least_squares

    found = _lines(recordings)
    if found is None:
        return None
    anchor = _anchor(found)
    r0_ref, g_ref = found[anchor]
    data = _thinned(recordings)
    # map of run i: R' = r0_ref + k_i (R - z_i); started on the lines: z = R_0, k = g_ref / g
    start = np.array([v for i, (r0, g) in enumerate(found) if i != anchor
                      for v in (r0, g_ref / g)])
    scale = float(np.median(np.concatenate([np.abs(r) for r, _ in data])))
    s_all = np.concatenate([s for _, s in data])

    def unpack(x: np.ndarray) -> list[Map]:
        pairs = iter(zip(x[::2], x[1::2], strict=True))
        return [(r0_ref, 1.0) if i == anchor else next(pairs) for i in range(len(data))]

    def residual(x: np.ndarray) -> np.ndarray:  # the cubic solved for, given the maps
        mapped = np.concatenate([(r0_ref + k * (r - z)) / scale
                                 for (r, _), (z, k) in zip(data, unpack(x), strict=True)])
        fitted: np.ndarray = np.polyval(np.polyfit(mapped, s_all, POOL_DEGREE), mapped)
        return np.asarray(fitted - s_all, dtype=np.float64)

    gains = start[1::2]
    lower = np.ravel([(-np.inf, 0.2 * k) for k in gains])
    upper = np.ravel([(np.inf, 5.0 * k) for k in gains])
    fitted = least_squares(residual, start, x_scale=np.ravel([(scale, 1.0)] * gains.size),
                           bounds=(lower, upper), xtol=1e-10)
    x = fitted.x if fitted.success and np.all(np.isfinite(fitted.x)) else start
    return unpack(x), r0_ref


def stretch_space(recordings: Sequence[Recording], maps: Sequence[Map], r_ref: float
                  ) -> Line | None:
    """The line the runs' calibration stretches share once mapped."""
    parts = []
    for rec, (z, k) in zip(recordings, maps, strict=True):
        stretch = None if rec.s is None else calibration_stretch(rec.t, rec.s)
        if stretch is None:
            return None
        part = cut(rec, *stretch)
        parts.append(replace(part, r=r_ref + k * (np.asarray(part.r, dtype=np.float64) - z)))
    assert parts[0].s is not None  # every run has a stretch
    pooled = replace(parts[0], t=np.arange(sum(p.t.size for p in parts), dtype=np.float64),
                     r=np.concatenate([p.r for p in parts]),
                     s=np.concatenate([p.s for p in parts if p.s is not None]),
                     temperature=None)
    line = run_line(pooled)
    return line if line is not None and line[0] > 0 else None


def gate(recordings: Sequence[Recording]) -> tuple[dict[str, Any], Joint | None]:
    """The ``joint`` maps where they lower the pooled cubic's RMSE to ``POOL_GAIN`` of it."""
    joint = joint_maps(recordings)
    if joint is None:
        return {"why": "a run has no line, or the runs' lines disagree in sign"}, None
    maps, r_ref = joint
    rmse = {"raw": curve_rmse(recordings, [(r_ref, 1.0)] * len(maps), r_ref),
            "spanned": curve_rmse(recordings, maps, r_ref)}
    reading = {"curve_rmse": {k: round(v, 6) for k, v in rmse.items()}}
    return reading, joint if rmse["spanned"] <= POOL_GAIN * rmse["raw"] else None


def pooled_input(recordings: Sequence[Recording], pool: str, joint: Joint | None = None
                 ) -> Pooled:
    """The runs in one input space (``joint``, ``stretch``) or as recorded (``raw``)."""
    if pool not in POOLS or pool == "spanned":
        raise InputError(f"--pool {pool!r}: expected one of {', '.join(POOLS)}")
    as_recorded = Pooled(list(recordings), [], {"pool": "raw"})
    if pool == "raw" or not recordings or (pool == "joint" and len(recordings) < 2):
        return as_recorded
    if len(recordings) < 2:  # stretch: the run's own stretch line, the run as recorded
        own = stretch_space(recordings, [(0.0, 1.0)], 0.0)
        return replace(as_recorded, record={"pool": "stretch"}, stretch_line=own) \
            if own is not None else as_recorded
    joint = joint if joint is not None else joint_maps(recordings)
    if joint is None:
        return replace(as_recorded, record={"pool": "raw", "why": "no line of resistance on "
                                            "strain, or lines that disagree in sign"})
    maps, r_ref = joint
    line = None if pool == "joint" else stretch_space(recordings, maps, r_ref)
    if pool == "stretch" and line is None:
        return replace(as_recorded, record={"pool": "raw", "why": "a run with no stretch"})
    out = [replace(rec, r=r_ref + k * (np.asarray(rec.r, dtype=np.float64) - z))
           for rec, (z, k) in zip(recordings, maps, strict=True)]
    return Pooled(out, [{"rest": z, "rest_calibrated": r_ref, "span_gain": k}
                        for z, k in maps], {"pool": pool}, line)
