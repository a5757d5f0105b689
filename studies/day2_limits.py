#!/usr/bin/env python3
# Study: What limits the thread's day-2 ratio to its in-run bound? (docs/results.md, "Another day")
"""What limits the thread's day-2 ratio (docs/results.md, "What limits the day-2
ratio"), on the calibrations and bags of a ``--schemes day2`` run of generalisation.py:

    python scripts/generalisation.py --sensors nylon --schemes day2 --models cubic mpi apl \\
        creep_pi --bound-models cubic mpi apl --jobs 2 --out /tmp/day2_base
    python studies/day2_limits.py --out /tmp/day2_base [--models apl creep_pi]

Per session-2 run and model: the session-1 calibration started on it (``start_or_keep``, as
the benchmark's ``warmup``), its RMSE over all of the run, the first 600 s and the rest;
the RMSE after the best output gain and offset over the whole run in hindsight
(``numpy.polyfit(estimate, reference, 1)``) and refitted per 300 s block, each as a ratio
to the run's best in-run bound (read from OUT/generalisation.json); the gain per 300 s
block; the median ratios per model. And per run, the slope of R/R0 on the position per
100 s of the CSV (``--data``).
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RUNS = ("sin_20", "sin_40", "tri_20", "tri_30", "mixed_20_30")
TRAIN = "nylon_sin_20+sin_30+sin_40+tri_50+mixed_10_20+mixed_15_25+mixed_20_30"


def hindsight(t: np.ndarray, est: np.ndarray, s: np.ndarray, block: float | None
              ) -> tuple[float, list[float]]:
    """RMSE after the best affine map of ``est`` onto ``s`` (per ``block`` seconds, or over
    all), and the gains."""
    fitted = np.full(t.size, np.nan)
    gains = []
    edges = [0.0, np.inf] if block is None else list(np.arange(0.0, t[-1] + block, block))
    for a, b in itertools.pairwise(edges):
        m = (t >= a) & (t < b)
        if m.sum() > 10:
            gain, offset = np.polyfit(est[m], s[m], 1)
            fitted[m] = gain * est[m] + offset
            gains.append(float(gain))
    return float(np.sqrt(np.nanmean((fitted - s) ** 2))), gains


def main() -> None:
    from strain_comp.core.calibration_file import load_calibration
    from strain_comp.io.recording import load_recordings
    from strain_comp.offline.evaluate import evaluate_recordings
    from strain_comp.offline.session_start import start_or_keep

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "measured")
    parser.add_argument("--models", nargs="+", default=["cubic", "mpi", "apl", "creep_pi"])
    args = parser.parse_args()
    cases = json.loads((args.out / "generalisation.json").read_text())["cases"]
    bound = {c["test"].removeprefix("day2_"): c["best_in_run_rmse"] for c in cases}
    for run in RUNS:
        csv = np.genfromtxt(args.data / "nylon_silver" / "session2_10Hz" / f"{run}.csv",
                            delimiter=",", names=True)
        t, r, p = csv["time_s"], csv["r_over_r0"], 100.0 * csv["position"]
        slopes = [np.polyfit(p[m], r[m], 1)[0] * 1000.0 for a in np.arange(0.0, t[-1], 100.0)
                  if (m := (t >= a) & (t < a + 100.0)).sum() > 10]
        print(f"{run}: R/R0 per 1 % position x 1000, per 100 s: "
              + " ".join(f"{x:.2f}" for x in slopes))
    for model in args.models:
        found = sorted((args.out / "cache").glob(f"{TRAIN}_{model}_*.yaml"))
        cal = load_calibration(found[-1])
        ratios: dict[str, list[float]] = {"whole": [], "block": []}
        for run in RUNS:
            rec = load_recordings(args.out / "bags" / "nylon" / f"day2_{run}.mcap")[0]["nylon"]
            started = start_or_keep(cal, {"nylon": rec})
            ev = evaluate_recordings({"nylon": rec}, started.calibration, tare="calibration",
                                     out_of_range="extend").sensors["nylon"]
            assert rec.s is not None
            t, est, s = ev.t - ev.t[0], ev.estimate, rec.s
            ok = np.isfinite(est) & np.isfinite(s)
            t, est, s, e = t[ok], est[ok], s[ok], est[ok] - s[ok]
            rmse = [float(np.sqrt(np.mean(e[m] ** 2))) for m in
                    (np.ones(t.size, bool), t < 600.0, t >= 600.0)]
            whole, gain = hindsight(t, est, s, None)
            block, gains = hindsight(t, est, s, 300.0)
            ratios["whole"].append(whole / bound[run])
            ratios["block"].append(block / bound[run])
            print(f"{model} {run}: stretch {started.window}; RMSE {rmse[0]:.2f} (first 600 s "
                  f"{rmse[1]:.2f}, after {rmse[2]:.2f}), ratio {rmse[0] / bound[run]:.2f}; "
                  f"hindsight gain {gain[0]:.2f}: {whole:.2f} ({whole / bound[run]:.2f}); "
                  f"per 300 s: {block:.2f} ({block / bound[run]:.2f}), gains "
                  + " ".join(f"{g:.2f}" for g in gains))
        print(f"{model}: median ratio, hindsight over the run {np.median(ratios['whole']):.2f}"
              f", per 300 s {np.median(ratios['block']):.2f}")


if __name__ == "__main__":
    main()
