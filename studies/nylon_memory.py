#!/usr/bin/env python3
# Study: Do memory models lower the silver-nylon thread's error? (docs/results.md)
"""In-run error of the memory models on the silver-nylon thread sensor, with the cell
weights' sign chosen from the data (the default) and held to the paper's leading loop.

    python studies/nylon_memory.py --data ../shared/data/measured [--runs sin_20 tri_50]

Each run of ``nylon_silver/session1_100Hz`` is imported as ``strain-comp import-csv
--format generic --columns time=time_s,resistance=r_over_r0,strain=position --scales
strain=100`` does, then the cubic, MPI, PL and APL are fitted on the run itself with the
code of ``strain-comp fit`` (their training RMSE is the in-run bound ``evaluate
--in-run-bound`` gives), MPI, PL and APL once with the default ``cell_weights=signed``
and once with ``cell_weights=lead`` (the fit before the loop's sign was read from the
data). Prints a Markdown table with the ratio of MPI and APL to the cubic, and per fit the
loop its cells were held to and whether it ended up memoryless. docs/results.md
explains the numbers.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
RUNS = ("sin_20", "sin_30", "sin_40", "tri_50", "mixed_10_20", "mixed_15_25", "mixed_20_30")
MEMORY = ("mpi", "pl", "apl")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help=f"measured data directory (default {DEFAULT_DATA})")
    parser.add_argument("--runs", nargs="+", default=list(RUNS))
    args = parser.parse_args()
    from strain_comp.io.csv_import import import_csv
    from strain_comp.io.recording import write_recordings
    from strain_comp.offline.fit import fit_bags

    folder = args.data / "nylon_silver" / "session1_100Hz"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in args.runs:
            csv = folder / f"{run}.csv"
            if not csv.is_file():
                print(f"no such run: {csv}", file=sys.stderr)
                return 2
            result = import_csv(csv, fmt="generic", sensor="s0",
                                columns={"time": "time_s", "resistance": "r_over_r0",
                                         "strain": "position"}, scales={"strain": 100.0})
            bag = Path(tmp) / f"{run}.mcap"
            write_recordings({result.recording.name: result.recording}, bag, inputs=[csv])
            row: dict[str, str] = {}
            errors: dict[str, float] = {}
            for model in ("cubic", *MEMORY):
                for weights in (("signed", "lead") if model in MEMORY else ("",)):
                    options = {"cell_weights": weights, "progress": False} if weights else {}
                    cal = fit_bags([bag], model, options=options).sensors["s0"]
                    rmse = float(cal.provenance["fit_rmse"])
                    memory = cal.provenance.get("memory")
                    key = f"{model} {weights}".strip()
                    errors[key] = rmse
                    row[key] = (f"{rmse:.3f}" if memory is None else
                                f"{rmse:.3f} ({memory['loop']}"
                                f"{', memoryless' if memory['memoryless'] else ''})")
                    print(f"{run} {key}: {row[key]}", file=sys.stderr, flush=True)
            rows.append((run, row, errors))
    keys = ["cubic", *(f"{m} {w}" for m in MEMORY for w in ("lead", "signed"))]
    print("in-run RMSE [% strain], fitted on the run itself; lead: cells held to the paper's "
          "leading loop (the fit as it was), signed: the loop read from the data (default)\n")
    print("| run | " + " | ".join(keys) + " | MPI / cubic | APL / cubic |")
    print("|---|" + "---:|" * (len(keys) + 2))
    for run, row, errors in rows:
        ratios = [errors[f"{m} signed"] / errors["cubic"] for m in ("mpi", "apl")]
        print(f"| {run} | " + " | ".join(row[k] for k in keys)
              + f" | {ratios[0]:.2f} | {ratios[1]:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
