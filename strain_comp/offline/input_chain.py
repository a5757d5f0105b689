"""The measurement chain read from the training runs: with an alternation of the excitation
(``core.chain``) the models read a pair statistic of R[i], R[i-1] (mean, upper or lower side);
options ``alternation`` and ``pair`` override."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from strain_comp.core.chain import Alternation, alternation, pair_branch
from strain_comp.errors import FitError

if TYPE_CHECKING:
    from strain_comp.io.recording import Recording

STILL_FRACTION = 0.001
"""The reference is still where it moves at most this share of its span in 1 s."""
# half the slowest ramp in the measured data (the fibre moves 0.2 % of its span per s)


def input_chain(recordings: Sequence[Recording], name: str, options: Mapping[str, Any],
                ) -> tuple[Alternation, bool, str]:
    """The measurement chain of ``name``'s training runs, options over the detection."""
    r_raw = np.concatenate([np.asarray(rec.r) for rec in recordings])
    chain = alternation(r_raw)
    alternating = bool(options.get("alternation", chain.present))
    pair = str(options.get("pair", pair_side(recordings) if alternating else "mean"))
    if pair != "mean" and not alternating:
        raise FitError(f"sensor {name!r}: option pair={pair} needs an alternating input "
                       "(found none; set alternation=true)")
    return chain, alternating, pair


def pair_side(recordings: Sequence[Recording]) -> str:
    """``pair_branch`` over the training runs, still where ``STILL_FRACTION`` says."""
    r_all, still_all = [], []
    for rec in recordings:
        if rec.s is None:
            continue
        s = np.asarray(rec.s, dtype=np.float64)
        span = float(np.nanmax(s) - np.nanmin(s)) if np.any(np.isfinite(s)) else 0.0
        t = np.asarray(rec.t, dtype=np.float64)
        lo = np.searchsorted(t, t - 0.5)
        hi = np.clip(np.searchsorted(t, t + 0.5, side="right") - 1, 0, t.size - 1)
        moved = np.abs(s[hi] - s[lo])  # the change over the second around each sample
        r_all.append(np.asarray(rec.r, dtype=np.float64))
        still_all.append(np.isfinite(moved) & (moved <= STILL_FRACTION * span))
    if not r_all:
        return "mean"
    return pair_branch(np.concatenate(r_all), np.concatenate(still_all))
