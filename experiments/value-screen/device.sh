#!/usr/bin/env bash
# The value-remedy screen's extra seeds on the device machine (16 cores): each ARM x SEED of
# experiments/value-screen/ARM.json side by side, one process and one CPU thread each (the
# learner on the CPU: 16 learners sharing one GPU update slower than one core each), stopped
# after LIMIT seconds; metrics, snapshots and the last checkpoint (no replay buffer, no best/) of
# two runs a file into OUT (about 7 MB a file: the device tool brings back at most 8 files of
# 16 MiB), with summary.txt. The working tree sent must stay under 64 MiB: checkpoints/ does not
# fit (see docs/training.md, "Values that track the returns").
#   bash experiments/value-screen/device.sh OUT [LIMIT_S] [SEEDS] [ARMS]
set -u
out=${1:?usage: device.sh OUT [LIMIT_S] [SEEDS] [ARMS]}; limit=${2:-480}
seeds=${3:-4 5 6 7 8 9 10 11}; arms=${4:-control scaled}
python=${PYTHON:-python3}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
work=$(mktemp -d)
start=$(date +%s)
for seed in $seeds; do
    for arm in $arms; do
        timeout "$limit" $python -m training train --config "experiments/value-screen/$arm.json" --seed "$seed" \
            --out "$work/runs/$arm-seed-$seed" --quiet >"$work/$arm-seed-$seed.log" 2>&1 &
    done
done
wait
{
    echo "wall: $(( $(date +%s) - start )) s"
    for log in "$work"/*.log; do echo "== $log"; tail -n 3 "$log"; done
    for run in "$work"/runs/*; do
        echo "== $(basename "$run")"
        $python -m training snapshots "$run"
        tail -n 1 "$run/metrics.jsonl" | cut -c1-300
    done
} >"$out/summary.txt" 2>&1
cd "$work/runs" || exit 1
rm -rf ./*/replay.npz ./*/best
runs=(*)
for ((i = 0; i < ${#runs[@]}; i += 2)); do
    tar -czf "$out/runs-$((i / 2)).tar.gz" "${runs[@]:i:2}"
done
ls -la "$out" >>"$out/summary.txt"
