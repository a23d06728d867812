#!/bin/bash
# CPU seconds of `siva diagnose` before/after a change, side by side in one run:
# each case is diagnosed by BASE (a git ref, exported to a temporary folder) and by this
# tree, alternately, one process at a time, single-threaded (CPU time is then close to an
# idle machine's single-core wall time and barely depends on the other jobs' load).
#
#   benchmarks/diagnose_before_after.sh BASE OUTDIR case1 [case2 ...]
#   benchmarks/diagnose_before_after.sh f717bff /tmp/cmp cubic_damper_LO_NO chain3:null
#
# Prints one line per run (bench_diagnose.py's row: verdict, closure, gaps, wall s, CPU s)
# and leaves each run's JSON in OUTDIR/{base,new}_<case>.json.
set -euo pipefail
base=$1; out=$2; shift 2
here=$(cd "$(dirname "$0")/.." && pwd)
py=${PYTHON:-python}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
git -C "$here" archive "$base" | tar -x -C "$tmp"
mkdir -p "$out"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
export SIVA_SHARED_DATA=${SIVA_SHARED_DATA:-$here/../shared/data}
for c in "$@"; do
  safe=$(echo "$c" | tr ':+' '__')
  for t in base new; do
    root=$here; [ "$t" = base ] && root=$tmp
    (cd "$root" && PYTHONPATH=$root nice -n 5 "$py" benchmarks/bench_diagnose.py --cases "$c" \
        --json "$out/${t}_$safe.json" > "$out/${t}_$safe.txt" 2>&1) || true
    echo "$t $(grep -F "${c:0:32}" "$out/${t}_$safe.txt" | head -1)"
  done
done
