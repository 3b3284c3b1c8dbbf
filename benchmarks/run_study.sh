#!/usr/bin/env bash
# The committed study, in the order it was run. Every step is resumable: run this script again after an
# interruption and finished teachers and cells are skipped.
#
# It was run from a git worktree pinned to one commit (so that editing the checkout meanwhile could not
# change the code under a running study), writing into the main checkout:
#   git worktree add /tmp/studytree HEAD
#   PYTHONPATH=/tmp/studytree/src VENV=$PWD/.venv MIKT_REGISTRY=$PWD/registry \
#     MIKT_RESULTS=$PWD/benchmarks/results /tmp/studytree/benchmarks/run_study.sh
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
export PATH="${VENV:-$ROOT/.venv}/bin:$PATH"
export MIKT_REGISTRY="${MIKT_REGISTRY:-$ROOT/registry}"
RESULTS="${MIKT_RESULTS:-$ROOT/benchmarks/results}"
export MIKT_RESULTS="$RESULTS"

python "$ROOT/benchmarks/train_teachers.py" hopper centipede-four centipede-six
for grid in four-to-eight six-to-ant ablations-four-to-eight; do
  mikt study "$ROOT/benchmarks/grids/$grid.toml" --out "$RESULTS/$grid"
done
python "$ROOT/benchmarks/train_teachers.py" ant
mikt study "$ROOT/benchmarks/grids/similarity-to-eight.toml" --out "$RESULTS/similarity-to-eight"
