#!/usr/bin/env bash
# The prepared device-machine command (docs/training.md, "On a device machine"): one call of under
# 9 minutes that trains grid cells on every core, one process a cell, and brings back each
# method's resume points in $OUT. From the repository root, on the device machine:
#
#   cp -r checkpoints/comparison runs/comparison && scripts/device-grid.sh 8 recipes/comparison/*.toml --seeds 1-3
#
# (the cp where the grid has committed resume points: scripts/keep-cells.py). The committed
# resume points travel with the tree (checkpoints/comparison; replay buffers are
# not committed, so a resumed cell refills its buffer outside the schedule first). The runtime's
# packages that the device image lacks travel as wheels (.whl, carried; scripts/device-wheels.sh
# says how to make them). Then the cells run as `python -m training grid RECIPE...
# --seeds ... --out $GRID_OUT --processes $PROCESSES --stop-after MINUTES` (GRID_OUT: default
# runs/comparison; PROCESSES: default every core), which stops them with whole checkpoints when
# the minutes are up, and the cells that this call trained (their folders and logs; finished
# cells that it did not touch stay behind, so that the archives keep under the 16 MiB a file
# that comes back) are packed, without replay buffers and snapshots (best/ stays), one archive a
# method: $OUT/<method>.tar.gz. Unpack with `tar xzf METHOD.tar.gz -C runs/comparison`.
# First lent on 2026-11-27: 6 cells on an H100 machine's 16 cores, 8 minutes, reached 60-116 k
# steps each from scratch (docs/training.md, "Speed").
set -euo pipefail
minutes=$1
shift
grid_out=${GRID_OUT:-runs/comparison}
source scripts/device-wheels.sh
mkdir -p "$grid_out"
started=$(mktemp)
status=0
python3 -m training grid "$@" --out "$grid_out" --processes "${PROCESSES:-$(nproc)}" --stop-after "$minutes" || status=$?
for folder in "$grid_out"/*/; do
    method=$(basename "$folder")
    cells=()
    for log in "$folder"seed-*.log; do
        if [ -e "$log" ] && [ "$log" -nt "$started" ]; then
            cells+=("$method/$(basename "$log")")
            cell="$method/$(basename "$log" .log)"
            if [ -d "$grid_out/$cell" ]; then cells+=("$cell"); fi
        fi
    done
    if [ ${#cells[@]} -gt 0 ]; then
        tar czf "$OUT/$method.tar.gz" --exclude=replay.npz --exclude=snapshots --exclude=.run-lock -C "$grid_out" "${cells[@]}"
    fi
done
ls -l "$OUT"
exit "$status"
