"""A run's input zero and sensitivity read on its calibration stretch: the least-squares line
R = R_0 + g S of its resistance on the reference strain there (``fit --pool stretch``).

A fit pooled with the ``stretch`` session start (``strain_comp.offline.pool``) keeps the line
its training runs' stretches share in its input space (``InputSettings.stretch_line``).
The session start (``recalibrate --input``) puts a new run there by R' = R_0,space +
(g_space / g_run) (R - R_0,run), the line of the stretch it reads put onto that line. A new
run is then placed where the training runs' stretches lay, with what moves after the
stretch (the thread's sensitivity) as it moved on them, not read from the stretch alone
(docs/generalisation.md, "Pooling runs in one input space").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from strain_comp.base.samples import good_mask

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

Line = tuple[float, float]
"""(R_0 [ohm], g [ohm per strain unit]) of R = R_0 + g S."""


def run_line(rec: Recording) -> Line | None:
    """(R_0, g): the least-squares line R = R_0 + g S of a run's good, referenced samples, in
    closed form (no LAPACK call to fail on a reference near 1e-300 or 1e300)."""
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


def onto(own: Line, space: Line) -> tuple[float, float, float]:
    """The input zero and span (``InputSettings.zero_span``: rest, rest_calibrated, gain) that
    puts a run whose stretch has the line ``own`` onto the line ``space``."""
    return own[0], space[0], space[1] / own[1]
