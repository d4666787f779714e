#!/usr/bin/env bash
# The prepared device-machine command (docs/training-speed.md): one call of under
# 9 minutes that trains grid cells with their learners on the GPU, the seeds of a method trained
# together in one process (SEEDS_PER_PROCESS, default 3: one batched update on the GPU serves
# them all; rollouts on the CPU cores, one process a stack), and brings back each method's resume
# points in $OUT. From the repository root, on the device machine:
#
#   cp -r checkpoints/GRID runs/GRID && GRID_OUT=runs/GRID SEEDS_PER_PROCESS=2 \
#       scripts/device-grid.sh 8 RECIPE --seeds 1,2
#   scripts/device-grid.sh 8 recipes/comparison/*.toml --seeds 1-3
#
# (the cp where the grid has committed resume points: scripts/keep-cells.py; seeds trained
# together resume from one step, so the stacks are those the resume points were trained in).
# The committed resume points travel with the tree (checkpoints/<grid>; replay buffers are
# not committed, so a resumed cell refills its buffer outside the schedule first). The runtime's
# packages that the device image lacks travel as wheels (.whl, carried; scripts/device-wheels.sh
# says how to make them). Then the cells run as `python -m training grid RECIPE...
# --seeds ... --out $GRID_OUT --processes $PROCESSES --stop-after MINUTES` (GRID_OUT: default
# runs/comparison; PROCESSES: default every core), which stops them with whole checkpoints when
# the minutes are up, and the cells that this call trained (their folders and logs; finished
# cells that it did not touch stay behind, so that the archives keep under the 16 MiB a file
# that comes back) are packed, without replay buffers (best/ and kept snapshots' networks stay),
# one archive a method: $OUT/<method>.tar.gz. Unpack with `tar xzf METHOD.tar.gz -C runs/comparison`.
# The tests marked cuda run first (pytest -m cuda; .whl carries pytest and onnx). First lent on
# 2026-11-27: 6 cells on an H100 machine's 16 cores, 8 minutes, reached 60-116 k steps each from
# scratch (docs/training-speed.md). On an H200 on 2026-11-30 one stack's update ran 36 a
# second for 1, 2 or 3 seeds (docs/training-speed.md, "GPU"): stacks of three pay there. The working
# tree travels only under 64 MiB with what is carried: move aside what the call does not read.
set -euo pipefail
minutes=$1
shift
grid_out=${GRID_OUT:-runs/comparison}
source scripts/device-wheels.sh
if [ "${DEVICE:-cuda}" != cpu ]; then  # the learner on the GPU: its tests first (a minute), or nothing trains
    python3 -m pytest -q -p no:cacheprovider -m cuda tests/training/test_seeds_together.py
fi
mkdir -p "$grid_out"
started=$(mktemp)
status=0
python3 -m training grid "$@" --out "$grid_out" --processes "${PROCESSES:-$(nproc)}" --stop-after "$minutes" \
    --seeds-per-process "${SEEDS_PER_PROCESS:-3}" --device "${DEVICE:-cuda}" || status=$?
for folder in "$grid_out"/*/; do
    method=$(basename "$folder")
    cells=()
    for log in "$folder"seed-*.log "$folder"seeds-*.log; do  # a cell's log, or a stack's (seeds-1-2-3.log)
        if [ -e "$log" ] && [ "$log" -nt "$started" ]; then
            cells+=("$method/$(basename "$log")")
            name=$(basename "$log" .log)
            name=${name#seeds-}
            for seed in $(echo "${name#seed-}" | tr '-' ' '); do
                if [ -d "$grid_out/$method/seed-$seed" ]; then cells+=("$method/seed-$seed"); fi
            done
        fi
    done
    if [ ${#cells[@]} -gt 0 ]; then
        tar czf "$OUT/$method.tar.gz" --exclude=replay.npz --exclude=.run-lock -C "$grid_out" "${cells[@]}"
    fi
done
ls -l "$OUT"
exit "$status"
