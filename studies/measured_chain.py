#!/usr/bin/env python3
# Study: What does the input corrector find on each measured run? (docs/results.md)
"""The spike and baseline-step corrector on every measured recording.

    python studies/measured_chain.py --data ../shared/data/measured

Per file (carbon black: R_outer and |stage position|; fibre: resistance and extension),
through ``strain_comp.core.chain.correct`` at the default thresholds, as the engine feeds a
calibration with ``input: {despike: true, baseline_step: true}`` (pair means first where the
excitation alternates):

* what it finds: spikes, samples held, and each baseline step with the stage's movement
  over the samples that confirmed it (a step where the stage moves would be a strain
  change taken for a contact);
* how far it changes the input on the ramps (stage faster than 0.05 mm/s) with the
  baseline step off: samples held, and the RMS change relative to the run's span;
* what it can detect: a step of 2, 5 and 10 % of the run's median R injected at 9 times
  evenly spread over the middle 80 % of the run, counted as found when a step is confirmed
  within 60 s after it and its size is within 15 %.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
SIZES = (0.02, 0.05, 0.10)
TIMES = 9


def load(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], R [ohm], |position| or extension [mm], position glitches repaired)."""
    from strain_comp.io.csv_import import repair_position_glitches

    rows = np.loadtxt(path, delimiter=",")
    if path.parent.name == "conductive_fiber":
        return rows[:, 0], rows[:, 3], rows[:, 1]
    return rows[:, 2], rows[:, 0], np.abs(repair_position_glitches(rows[:, 3])[0])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = parser.parse_args(argv)

    from strain_comp.core.chain import HELD, STEP_K, STEP_SAMPLES, alternation, correct, pair_means

    files = sorted(args.data.glob("*/*.csv"))
    if not files:
        print(f"no measured CSV files under {args.data}", file=sys.stderr)
        return 1
    print("| file | samples | spikes | held | baseline steps found (stage movement meanwhile) "
          "| ramps: held, RMS change / span | injected steps found: "
          + ", ".join(f"{100 * s:g} % of R" for s in SIZES) + " |")
    print("|---|---:|---:|---:|---|---|---|")
    for path in files:
        t, r, position = load(path)
        wobble = alternation(r).present
        seen = pair_means(r) if wobble else r
        _, events, corrector = correct(t, r, step_k=STEP_K, alternating=wobble)
        dt = float(np.median(np.diff(t)))
        steps = []
        for step in corrector.steps:
            watch = (t > step.t - 2.0 * STEP_SAMPLES * dt) & (t <= step.t)
            steps.append(f"{step.reading()} ({np.ptp(position[watch]):.3g} mm)")
        out, held, _ = correct(t, r, alternating=wobble)
        moving = np.abs(np.gradient(position, t)) > 0.05
        change = (out - seen)[moving]
        ramps = (f"{np.count_nonzero(held[moving] == HELD) / max(1, moving.sum()):.1%}, "
                 f"{np.sqrt(np.mean(change ** 2)) / np.ptp(seen):.2%}")
        found = []
        for fraction in SIZES:
            size = fraction * float(np.median(r))
            hits = 0
            for at in np.linspace(t[0] + 0.1 * np.ptp(t), t[-1] - 0.1 * np.ptp(t), TIMES):
                _, _, c = correct(t, r + size * (t >= at), step_k=STEP_K, alternating=wobble)
                near = [s for s in c.steps if 0.0 <= s.t - at < 60.0]
                hits += bool(near) and abs(near[0].size / size - 1.0) < 0.15
            found.append(f"{hits}/{TIMES}")
        print(f"| {path.stem} | {t.size} | {corrector.n_spikes} | "
              f"{np.count_nonzero(events == HELD)} | {'; '.join(steps) or 'none'} | {ramps} | "
              f"{', '.join(found)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
