#!/usr/bin/env bash
# The paper-scale reproduction (issue 11), in the order its results become useful. Every step is resumable:
# run this script again after an interruption and finished teachers and cells are skipped.
#
# Run it from a git worktree pinned to one commit, writing into the main checkout, e.g.
#   git worktree add /tmp/paper HEAD
#   PYTHONPATH=/tmp/paper/src VENV=$PWD/.venv MIKT_REGISTRY=$PWD/registry \
#     MIKT_RESULTS=$PWD/benchmarks/results nohup /tmp/paper/benchmarks/run_paper_study.sh &
# With Ray installed (pip install 'mikt[ray]'), WORKERS=16 runs 16 cells at once (or ADDRESS=auto on a cluster).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
export PATH="${VENV:-$ROOT/.venv}/bin:$PATH"
export MIKT_REGISTRY="${MIKT_REGISTRY:-$ROOT/registry}"
RESULTS="${MIKT_RESULTS:-$ROOT/benchmarks/results}/paper-2m"
PARALLEL=()
[ -n "${WORKERS:-}" ] && PARALLEL=(--workers "$WORKERS")
[ -n "${ADDRESS:-}" ] && PARALLEL=(--address "$ADDRESS")

python "$ROOT/benchmarks/train_teachers.py"          # the v2 teachers (skipped when done)
# Finished runs live in the registry, which git ignores: copy each into its study's results folder every
# 10 minutes, so a session that ends abruptly loses at most the cells in flight (commit those snapshots).
snapshot_all() {
  for grid in paper-2m paper-2m-controls paper-2m-ablations paper-2m-similarity; do
    [ -f "$RESULTS/$grid/state.json" ] && python "$ROOT/benchmarks/snapshot_study.py" "$RESULTS/$grid" \
      --registry "$MIKT_REGISTRY" > /dev/null
  done
  return 0
}
( while sleep "${SNAPSHOT_EVERY:-600}"; do snapshot_all; done ) &
SNAPSHOTS=$!
trap 'kill $SNAPSHOTS 2>/dev/null' EXIT
for grid in paper-2m paper-2m-controls paper-2m-ablations paper-2m-similarity; do
  mikt study "$ROOT/benchmarks/grids/$grid.toml" --out "$RESULTS/$grid" "${PARALLEL[@]}"
done
# The evidence to commit: each finished run's card and metrics beside its study's report, the
# teacher-similarity figures and the controls/ablations report (both read those snapshots).
snapshot_all
python "$ROOT/benchmarks/similarity_report.py" "$RESULTS"
python "$ROOT/benchmarks/controls_report.py" "$RESULTS"
