#!/usr/bin/env bash
# The lineage of the shipped policy after 200 k (P: the `published` continuation to 300 k; then
# F, H, S2, V1's recipe) under one chain's configs, each segment resuming the previous one's
# last checkpoint (one torch thread). A chain runs the segments it has configs for
# (experiments/lineage/CHAIN-SEGMENT*.json), from START (default: the shipped lineage's 300 k):
#   bash experiments/lineage/run.sh L1 runs/L1            # F .. V1 from A's published-300k
#   bash experiments/lineage/run.sh L1 runs/L1 S2-small   # from S2-small, on runs/L1/H-large
#   START=checkpoints/curriculum/Z14-episode-limit-1000-seed-3-200k \
#       bash experiments/lineage/run.sh Q1 runs/Q1        # P .. V1 from Z14 200 k
set -euo pipefail
chain=$1
out=$2
segments=()
for segment in P-published F-medium H-large S2-small V1-mix; do
    compgen -G "experiments/lineage/$chain-$segment*.json" > /dev/null && segments+=("$segment")
done
(( ${#segments[@]} )) || { echo "no configs experiments/lineage/$chain-SEGMENT*.json" >&2; exit 2; }
first=${3:-${segments[0]}}
start=${START:-checkpoints/compare-200k/A-continuations/published-300k}
running=false
for segment in "${segments[@]}"; do
    [[ $segment == "$first" ]] && running=true
    if $running; then
        python -m training train --resume "$start" --config experiments/lineage/"$chain-$segment"*.json \
            --out "$out/$segment" --threads 1 --quiet
    fi
    start=$out/$segment
done
$running || { echo "no segment $first (one of: ${segments[*]})" >&2; exit 2; }
