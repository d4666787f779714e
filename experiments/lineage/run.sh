#!/usr/bin/env bash
# The lineage of the shipped policy after 300 k (F, H, S2, V1's recipe) under one chain's
# configs, each segment resuming the previous one's last checkpoint (one torch thread; about
# 60 min on one core beside another run):
#   bash experiments/lineage/run.sh L1 runs/L1            # all four segments
#   bash experiments/lineage/run.sh L1 runs/L1 S2-small   # from S2-small, on runs/L1/H-large
set -euo pipefail
chain=$1
out=$2
first=${3:-F-medium}
segments=(F-medium H-large S2-small V1-mix)
start=checkpoints/compare-200k/A-continuations/published-300k
running=false
for segment in "${segments[@]}"; do
    [[ $segment == "$first" ]] && running=true
    if $running; then
        python -m training train --resume "$start" --config "experiments/lineage/$chain-$segment-team-penalty-0.json" \
            --out "$out/$segment" --threads 1 --quiet
    fi
    start=$out/$segment
done
$running || { echo "no segment $first (one of: ${segments[*]})" >&2; exit 2; }
