#!/usr/bin/env bash
# Run every strain_comp benchmark in turn (on demand; not part of the test suite).
#   bash bench/run_all.sh [--quick]
# --quick: smaller sizes (a smoke run of the scripts, not the README figures).
# Each script prints its own figures and the ratio against its baseline.
set -euo pipefail
cd "$(dirname "$0")/.."
quick=0
[[ "${1:-}" == "--quick" ]] && quick=1
run() { echo; echo "\$ python $*"; python "$@"; }
if (( quick )); then
  run bench/bench_kernels.py --samples 200000 --no-fit
  run bench/bench_models.py --samples 200000 --reference-samples 2000
  run bench/bench_array.py --seconds 5 --baseline-ticks 200
  run bench/bench_replay.py --messages 100000 --repeat 1
  run bench/bench_fit.py --samples 5000 --models apl,mpi,cubic,rational --naive-seconds 5
  run bench/bench_startup.py --warm-runs 1 --no-node
  run bench/bench_latency.py --messages 2000 --round-trips 200
  run bench/bench_node_throughput.py --seconds 2 --rates 250,1000
else
  run bench/bench_kernels.py
  run bench/bench_models.py
  run bench/bench_array.py
  run bench/bench_replay.py
  run bench/bench_fit.py
  run bench/bench_startup.py
  run bench/bench_latency.py
  run bench/bench_node_throughput.py
fi
