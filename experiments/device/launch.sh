#!/usr/bin/env bash
# Start this session's training runs on the device machine, detached (setsid), in /tmp/runs.
# Run from the repository root there: bash experiments/device/launch.sh
set -euo pipefail
export PYTHONPATH=$PWD OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONUNBUFFERED=1
runs=/tmp/runs
mkdir -p "$runs"
start() {  # start NAME ARGS...: one detached training process, its output in NAME.log
    local name=$1; shift
    setsid nohup python3 -m training train --quiet "$@" >"$runs/$name.log" 2>&1 < /dev/null &
}
for config in experiments/baselines-200k/*.json; do
    name=base-$(basename "$config" .json)
    start "$name" --config "$config" --out "$runs/$name"
done
for config in experiments/compare-200k/E-*.json experiments/compare-200k/F-*.json; do
    name=$(basename "$config" .json)
    start "$name" --config "$config" --out "$runs/$name"
done
# Resumed runs: the committed checkpoint, its replay buffer not saved on this machine.
resume_copy() {  # resume_copy SOURCE NAME: copy a committed checkpoint to $runs/NAME, replay saving off
    cp -r "checkpoints/compare-200k/$1" "$runs/$2"
    python3 - "$runs/$2/config.json" <<'PY'
import json, sys
path = sys.argv[1]
config = json.load(open(path))
config["save_replay"] = False
json.dump(config, open(path, "w"), indent=2)
PY
}
resume_copy C-paper-new-learner C-paper-new-learner
start C-paper-new-learner --resume "$runs/C-paper-new-learner" --device cuda
resume_copy D-published-published-learner D-published-published-learner
start D-published-published-learner --resume "$runs/D-published-published-learner" --device cuda
resume_copy A-paper-published-learner A-extended-400k
start A-extended-400k --resume "$runs/A-extended-400k" --device cuda --total-steps 400000 --curriculum-steps 200000
sleep 2
ls "$runs"
