#!/usr/bin/env bash
# The value-remedy screen (docs/training.md, "Values that track the returns"): each ARM x SEED
# trains experiments/value-screen/ARM.json with that seed into OUT/ARM-seed-SEED, JOBS at a
# time, one torch thread each; a run already there is resumed (it refills its replay buffer
# when that was not kept).
#   bash experiments/value-screen/run.sh OUT JOBS 'control scaled' '1 2 3'
set -u
out=${1:?usage: run.sh OUT JOBS ARMS SEEDS}; jobs=${2:?}; arms=${3:?}; seeds=${4:?}
python=${PYTHON:-python3}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
for seed in $seeds; do for arm in $arms; do echo "$arm $seed"; done; done |
    xargs -P "$jobs" -L 1 bash -c '
        run=$0/$1-seed-$2
        if [ -f "$run/state.json" ]; then
            exec '"$python"' -m training train --resume "$run" --quiet >>"$run.log" 2>&1
        fi
        exec '"$python"' -m training train --config experiments/value-screen/$1.json --seed "$2" \
            --out "$run" --quiet >"$run.log" 2>&1' "$out"
