# Study: Which model has the lowest held-out RMSE on the bundled bags? (docs/results.md)
"""Held-out RMSE of every model on the bundled rig bags: a Markdown table, model x bag.

Each model is fitted on the training bags (bags/train_random.mcap, bags/train_patterns.mcap)
and evaluated on bags it never saw (bags/demo_rates.mcap: a rate sweep; bags/steps.mcap:
steps with holds), through the same fit and evaluate code as the command line.

    python studies/compare_models.py [--models apl,mpi,rational:mode=split] [--bags DIR]

A model may carry fit options after a colon, as ``--option`` gives them on the command line.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from strain_comp.errors import StrainCompError
from strain_comp.io.recording import load_recordings
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_bags, parse_options

TRAIN = ("train_random.mcap", "train_patterns.mcap")
HELD_OUT = ("demo_rates.mcap", "steps.mcap")
SENSOR = "s1"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=",".join([*MODEL_NAMES, "rational:mode=split"]))
    parser.add_argument("--bags", default=str(Path(__file__).resolve().parent.parent / "bags"))
    args = parser.parse_args()
    bags = Path(args.bags)
    held_out = {name: load_recordings(bags / name)[0] for name in HELD_OUT}
    print(f"fit on {', '.join(TRAIN)}; RMSE in % strain on held-out bags\n")
    print("| model | fit time [s] | " + " | ".join(HELD_OUT) + " |")
    print("|---|---:|" + "---:|" * len(HELD_OUT))
    for entry in args.models.split(","):
        model, _, option_text = entry.partition(":")
        options = parse_options(option_text.split(";")) if option_text else {}
        start = time.perf_counter()
        try:
            calibration = fit_bags([bags / name for name in TRAIN], model, [SENSOR], options)
        except StrainCompError as err:
            print(f"| {entry} | fit failed: {err} |" + " |" * len(HELD_OUT))
            continue
        seconds = time.perf_counter() - start
        cells = []
        for name in HELD_OUT:
            stats = evaluate_recordings(held_out[name], calibration).sensors[SENSOR].stats
            cells.append(f"{stats.rmse:.3f}")
        print(f"| {entry} | {seconds:.1f} | " + " | ".join(cells) + " |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
