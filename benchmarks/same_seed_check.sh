#!/usr/bin/env bash
# Same seeds, same metrics: a short teacher and four short transfers (mikt, mlpp, vpg, projection + w/o MI),
# their metrics (timings dropped) and results dumped as JSON, to compare the code before and after a refactor:
#   benchmarks/same_seed_check.sh before.json   (old checkout)   ...   benchmarks/same_seed_check.sh after.json
# benchmarks/results/same-seed/ holds the comparison made for the layered library (identical).
set -eu
OUT=$1; REG=$(mktemp -d); export MIKT_REGISTRY=$REG
mikt teacher train hopper --steps 4096 --name tiny > /dev/null 2>&1
mikt transfer --from tiny --to centipede-four --steps 4096 --eval-episodes 1 > /dev/null 2>&1
mikt transfer --from tiny --to centipede-four --steps 4096 --method mlpp --eval-episodes 1 > /dev/null 2>&1
mikt transfer --to centipede-four --steps 4096 --method vpg --eval-episodes 1 > /dev/null 2>&1
mikt transfer --from tiny --to centipede-four --steps 4096 --lateral projection --no-mi --eval-episodes 1 > /dev/null 2>&1
python3 - "$REG" "$OUT" <<'PY'
import json, sys, pathlib
reg, out = pathlib.Path(sys.argv[1]), sys.argv[2]
drop = {"steps_per_sec", "time_env", "time_inference", "time_rollout", "time_update"}
data = {}
for run in sorted((reg / "runs").iterdir()):
    rows = [json.loads(l) for l in (run / "metrics.jsonl").read_text().splitlines()]
    card = json.loads((run / "run.json").read_text())
    data[run.name] = {"metrics": [{k: v for k, v in r.items() if k not in drop} for r in rows],
                      "result": {k: v for k, v in card["result"].items()}}
json.dump(data, open(out, "w"), indent=1, sort_keys=True)
PY
