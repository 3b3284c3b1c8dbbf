#!/usr/bin/env bash
# The committed study, in the order it was run. Every step is resumable: run this script again after an
# interruption and finished teachers and cells are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$PWD/.venv/bin:$PATH"
python benchmarks/train_teachers.py hopper centipede-four centipede-six
mikt study benchmarks/grids/four-to-eight.toml --registry registry
mikt study benchmarks/grids/six-to-ant.toml --registry registry
mikt study benchmarks/grids/ablations-four-to-eight.toml --registry registry
python benchmarks/train_teachers.py ant
