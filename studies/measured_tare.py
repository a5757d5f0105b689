#!/usr/bin/env python3
# Study: Is the tare multiplicative or additive on carbon black? (docs/results.md)
"""Multiplicative or additive tare? The evidence of the carbon-black runs.

    python studies/measured_tare.py --data ../shared/data/measured

Per run of ``cb_pdms_7p5wt``: the rest resistance at its start (the automatic tare,
``strain_comp.core.tare.rest_resistance_at_start``; the first good sample when the run
does not start at rest), the resistance span above it (99th percentile minus rest) in ohm
and relative to the rest, and the RMSE of one static map fitted on v16 (a cubic S(R),
fitted with numpy, range-clamped as the engine does) applied to each run without tare,
with a multiplicative tare R x R_cal / R_rest and with an additive one R + R_cal - R_rest.
If the run-to-run change is a gain (the conducting cross-section), the relative span
stays put while the absolute one scales with the rest level, and the multiplicative tare
wins on the runs far from the calibration's level.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
RUNS = {"v16": "2_7-5_E4pin_20mm_v16_0.3Strain.csv",
        "v19": "2_7-5_E4pin_20mm_v19_0.3Strain.csv",
        "v10": "2_7-5_E4pin_20mm_v10_0.3Strain.csv",
        "rand_sawtooth": "2_7-5_4Epin_rand_sawtooth.csv",
        "v9": "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args(argv)

    from strain_comp.base.direction import DirectionSettings
    from strain_comp.core.tare import rest_resistance_at_start, rest_resistance_from_reference
    from strain_comp.errors import InputError
    from strain_comp.io.csv_import import import_csv
    from strain_comp.offline.deadzone import direction_settings
    from strain_comp.offline.fit import split_segments

    recs = {k: import_csv(args.data / "cb_pdms_7p5wt" / v, fmt="cb_pdms", sensor="cb").recording
            for k, v in RUNS.items()}
    train = recs["v16"]
    ok = np.isfinite(train.r) & np.isfinite(train.s)
    coef = np.polyfit(train.r[ok], train.s[ok], 3)
    r_lo, r_hi = float(train.r[ok].min()), float(train.r[ok].max())
    s_lo, s_hi = float(train.s[ok].min()), float(train.s[ok].max())
    r_cal = rest_resistance_from_reference(train.t, train.r, train.s)
    detector: DirectionSettings = direction_settings(
        split_segments(train.t[ok], train.r[ok], train.s[ok]), {})[0]
    print(f"calibration (v16): rest {r_cal:.0f} ohm, cubic S(R) on {ok.sum()} samples\n")
    print("| run | rest R [ohm] | span above rest [ohm] | span / rest | RMSE no tare | "
          "multiplicative | additive |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, rec in recs.items():
        good = np.isfinite(rec.r) & np.isfinite(rec.s)
        try:
            rest = rest_resistance_at_start(rec.t, rec.r, detector)
        except InputError:
            rest = float(rec.r[good][0])
        span = float(np.percentile(rec.r[good], 99)) - rest
        cells = []
        for r in (rec.r, rec.r * r_cal / rest, rec.r + r_cal - rest):
            s = np.clip(np.polyval(coef, np.clip(r[good], r_lo, r_hi)), s_lo, s_hi)
            cells.append(float(np.sqrt(np.mean((s - rec.s[good]) ** 2))))
        print(f"| {name} | {rest:.0f} | {span:.0f} | {span / rest:.2f} | "
              + " | ".join(f"{c:.2f} %" for c in cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
