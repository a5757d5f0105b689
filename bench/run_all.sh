#!/usr/bin/env bash
# Run every strain_comp benchmark in turn (on demand; not part of the test suite) and
# regenerate docs/results.md's table from their ROW lines (bench/perf_table.py).
#   bash bench/run_all.sh [--quick]
# --quick: smaller sizes (a smoke run of the scripts; the table is not rewritten).
# Each script prints its own figures and the ratio against its baseline. The full run takes
# a while (the 1e7-message replay alone a few minutes); the log is kept in $TMPDIR.
set -euo pipefail
cd "$(dirname "$0")/.."
quick=0
[[ "${1:-}" == "--quick" ]] && quick=1
log="${TMPDIR:-/tmp}/strain_comp_run_all.log"
: > "$log"
run() { echo; echo "\$ python $*"; python "$@"; }
{
if (( quick )); then
  run bench/bench_kernels.py --samples 200000 --no-fit
  run bench/bench_models.py --samples 200000 --reference-samples 2000
  run bench/bench_array.py --seconds 5 --baseline-ticks 200
  run bench/bench_array.py --sensors 16 --seconds 5 --baseline-ticks 200
  run bench/bench_array.py --model creep_pi --seconds 5 --baseline-ticks 200
  run bench/bench_replay.py --messages 100000 --repeat 1
  run bench/bench_replay_memory.py --messages 100000,1000000
  run bench/bench_fit.py --samples 5000 --models apl,mpi,cubic,rational \
    --rational-sizes 20000,200000
  run bench/bench_auto.py --seconds 40 --candidates cubic,mpi --repeat 1
  run bench/bench_startup.py --warm-runs 1 --no-node
  run bench/bench_batch.py --bags 3 --duration 200
  run bench/bench_latency.py --messages 2000 --round-trips 200
  run bench/bench_node_throughput.py --seconds 2 --rates 250,1000
else
  run bench/bench_kernels.py --no-fit
  run bench/bench_models.py
  run bench/bench_array.py
  run bench/bench_array.py --sensors 16
  run bench/bench_array.py --model creep_pi
  run bench/bench_replay.py
  run bench/bench_replay_memory.py
  run bench/bench_fit.py
  run bench/bench_auto.py
  run bench/bench_startup.py
  run bench/bench_batch.py
  run bench/bench_latency.py
  run bench/bench_node_throughput.py
fi
} 2>&1 | tee "$log"
if (( ! quick )); then
  python bench/perf_table.py "$log"
fi
