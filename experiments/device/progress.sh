#!/usr/bin/env bash
# Print each run's latest training record and snapshots: bash experiments/device/progress.sh [RUNS_DIR]
runs=${1:-/tmp/runs}
for metrics in "$runs"/*/metrics.jsonl; do
    python3 - "$metrics" <<'PY'
import json, sys
path = sys.argv[1]
records = [json.loads(line) for line in open(path) if line.strip()]
train = [r for r in records if r.get("kind") == "train"]
snaps = [r for r in records if r.get("kind") == "snapshot"]
name = path.split("/")[-2]
if train:
    t = train[-1]
    print(f"{name}: step {t['env_step']} updates {t['updates']} eps {t['episodes']} success {t['success_rate']} "
          f"coll {t['collision_ratio']:.3f} sps {t['steps_per_second']:.1f} wall {t['wall_seconds']:.0f}")
for s in snaps[-3:]:
    print("   snap", s["env_step"], round(s["score"], 3), s["best"],
          [(e["scenario"], e["success_rate"], round(e["travel_time_s_mean"], 1), round(e["collision_ratio_mean"], 3)) for e in s["evaluations"]])
PY
done
for log in "$runs"/*.log; do
    if grep -q -i "error\|traceback" "$log"; then echo "== $log"; tail -5 "$log"; fi
done
