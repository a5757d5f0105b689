"""Several training runs of one sensor put into one input space (``strain-comp fit --pool``).

As ``recalibrate --input`` zeroes and spans a run: R' = R_0,ref + k (R - R_0,run), each
run's zero and sensitivity fitted jointly with one cubic through all mapped runs and
anchored on the run of median sensitivity (``pooled_input``), where that lowers the cubic's
error to at most ``POOL_GAIN`` of its error on the runs as recorded. Runs of one thread
differ in sensitivity by up to 2x; pooled raw, the model fits their average and carries to
none (docs/generalisation.md). The calibration's rest resistance and range are those of the
spanned runs, so a session start (``recalibrate --input``) on a new run maps it into the
same space. ``pool="raw"``: the runs as recorded. The provenance records the choice
(``pooling``) and each run's map (``pooled_runs``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.samples import good_mask
from strain_comp.errors import InputError

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

POOLS = ("spanned", "raw")
"""How ``fit_sensor`` pools several runs: each run's input zero and span put onto a reference
run's first (default, module docstring), or the resistance as recorded."""
POOL_GAIN = 0.7
"""The per-run maps are kept where they lower the pooled cubic's RMSE to at most this share
of its RMSE on the runs as recorded (``pooled_input``; docs/generalisation.md: 0.31-0.62 on
the thread and the fibre, where pooling in one space helps, 0.82-1.25 on the carbon black
and the rig, where it does not)."""
POOL_DEGREE = 3
"""Degree of the pooled curve of strain on mapped resistance the input maps are fitted
through (``pooled_input``): the cubic model's."""
POOL_SAMPLES = 4000
"""Samples of each run (evenly thinned) the input maps are fitted on."""


def run_line(rec: Recording) -> tuple[float, float] | None:
    """(R_0, g): the least-squares line R = R_0 + g S of a run's good, referenced samples, in
    closed form (no LAPACK call to fail on a reference near 1e-300 or 1e300).

    Args:
        rec: The run.

    Returns:
        Its input zero R_0 [ohm] and sensitivity g [ohm per strain unit]; None without a
        range of strain or a finite line.

    """
    if rec.s is None:
        return None
    ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
    s, r = np.asarray(rec.s, dtype=np.float64)[ok], np.asarray(rec.r, dtype=np.float64)[ok]
    if s.size < 2 or not np.ptp(s) > 0:
        return None
    with np.errstate(all="ignore"):
        ds, r_mean = s - s.mean(), r.mean()
        g = float(np.dot(ds, r - r_mean) / np.dot(ds, ds))
        r0 = float(r_mean - g * s.mean())
    return (r0, g) if np.isfinite(r0) and np.isfinite(g) and g != 0 else None


def pooled_input(recordings: Sequence[Recording], pool: str = "spanned",
                 ) -> tuple[list[Recording], list[dict[str, float]], dict[str, Any]]:
    """The runs put into one input space for a pooled fit (module docstring, Pooling runs).

    The maps are a per-run affine nuisance fitted jointly with a pooled cubic of strain on
    mapped resistance (least squares over the maps, the cubic solved for at each step),
    started from each run's line of resistance on strain (``run_line``) and anchored on the
    run of median sensitivity (its map stays the identity), then dropped: the model is fitted
    on the mapped runs, where the maps lower the pooled cubic's RMSE to at most ``POOL_GAIN``
    of its RMSE on the runs as recorded (runs that differ in zero and sensitivity, not in
    rate or memory). The runs as recorded (no maps) otherwise, for ``pool="raw"``, a single
    run, or runs whose lines disagree in sign.

    Args:
        recordings: The sensor's runs.
        pool: ``spanned`` or ``raw``.

    Returns:
        The runs as fitted, each run's map (``rest``, ``rest_calibrated``, ``span_gain``:
        R' = rest_calibrated + span_gain (R - rest), the form of ``recalibrate --input``),
        and which was chosen with both RMSEs (the provenance's ``pooling``).

    Raises:
        InputError: An unknown ``pool``.

    """
    from scipy.optimize import least_squares

    if pool not in POOLS:
        raise InputError(f"--pool {pool!r}: expected one of {', '.join(POOLS)}")
    as_recorded: dict[str, Any] = {"pool": "raw"}
    if pool == "raw" or len(recordings) < 2:
        return list(recordings), [], as_recorded
    lines = [run_line(rec) for rec in recordings]
    if any(line is None for line in lines):
        return list(recordings), [], as_recorded
    found = [line for line in lines if line is not None]
    if len({np.sign(g) for _, g in found}) > 1:
        return list(recordings), [], {"pool": "raw", "why": "the runs' lines disagree in sign"}
    anchor = int(np.argsort([abs(g) for _, g in found])[(len(found) - 1) // 2])
    r0_ref, g_ref = found[anchor]
    data = []
    for rec in recordings:
        assert rec.s is not None  # run_line found a line
        ok = good_mask(rec.t, rec.r) & np.isfinite(rec.s)
        step = max(1, int(ok.sum()) // POOL_SAMPLES)
        data.append((np.asarray(rec.r, dtype=np.float64)[ok][::step],
                     np.asarray(rec.s, dtype=np.float64)[ok][::step]))
    # map of run i: R' = r0_ref + k_i (R - z_i); started on the lines: z = R_0, k = g_ref / g
    start = np.array([v for i, (r0, g) in enumerate(found) if i != anchor
                      for v in (r0, g_ref / g)])
    scale = float(np.median(np.concatenate([np.abs(r) for r, _ in data])))
    s_all = np.concatenate([s for _, s in data])

    def unpack(x: np.ndarray) -> list[tuple[float, float]]:
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
    rmse = {"raw": float(np.sqrt(np.mean(residual(np.tile([r0_ref, 1.0], gains.size)) ** 2))),
            "spanned": float(np.sqrt(np.mean(residual(x) ** 2)))}
    reading = {"curve_rmse": {k: round(v, 6) for k, v in rmse.items()}}
    if not rmse["spanned"] <= POOL_GAIN * rmse["raw"]:
        return list(recordings), [], {"pool": "raw", **reading}
    maps = unpack(x)
    out = [replace(rec, r=r0_ref + k * (np.asarray(rec.r, dtype=np.float64) - z))
           for rec, (z, k) in zip(recordings, maps, strict=True)]
    return out, [{"rest": z, "rest_calibrated": r0_ref, "span_gain": k} for z, k in maps], {
        "pool": "spanned", **reading}
