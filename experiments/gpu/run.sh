#!/usr/bin/env bash
# The G sweep: 14 fine-tunes side by side on one GPU machine (the device tool), each with its
# learner on the GPU and its rollouts on one CPU core, stopped after LIMIT seconds; their
# snapshots and metrics are packed into OUT (a tar file for every two runs, and summary.txt).
# Without CONFIGS it runs G01-G14.
# CONFIGS='GLOB ...' runs experiments/gpu/GLOB.json for each glob alone: CONFIGS='G2?-*' is the
# team-penalty sweep (G20-G27, eight runs; docs/training.md, third session of 2026-11-26).
# CONFIGS='G3?-* G4[0-3]-*': V1's recipe with CUDA seeds 5-16 and w_t = 2 with seeds 1-2
# (G30-G43); CONFIGS='G4[4-9]-* G5?-*': w_t = 2 with seeds 3-10 and V1's recipe with seeds
# 17-22 (G44-G57); 14 runs a command (the fifth session of 2026-11-26).
#   bash experiments/gpu/run.sh OUT [LIMIT_S] [DEVICE]
set -u
out=${1:?usage: run.sh OUT [LIMIT_S] [DEVICE]}; limit=${2:-450}; device=${3:-cuda}
python=${PYTHON:-python3}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1
work=$(mktemp -d)
start=$(date +%s)
$python -m training shift checkpoints/shaping/S2-shaped-small-415k --by -300 -o "$work/S2-shifted-300" || exit 1
$python -m training shift checkpoints/shaping/V1-falling-step-size-440k --by -300 -o "$work/V1-shifted-300" || exit 1
read -ra globs <<<"${CONFIGS:-G[01]?-*}"
for config in $(printf 'experiments/gpu/%s.json ' "${globs[@]}"); do
    name=$(basename "$config" .json)
    case $name in
        *from-V1-440k) resume=$work/V1-shifted-300 ;;
        *-V1-*) resume=checkpoints/shaping/S2-shaped-small-415k ;;
        *) resume=$work/S2-shifted-300 ;;
    esac
    timeout "$limit" $python -m training train --resume "$resume" --config "$config" \
        --out "$work/runs/$name" --threads 1 --device "$device" --quiet >"$work/$name.log" 2>&1 &
done
wait
{
    echo "wall: $(( $(date +%s) - start )) s"
    nvidia-smi --query-gpu=name,memory.used --format=csv 2>/dev/null
    for log in "$work"/G*.log; do echo "== $log"; tail -n 5 "$log"; done
    for run in "$work"/runs/G*; do
        echo "== $(basename "$run")"
        $python -m training snapshots "$run"
        tail -n 1 "$run/metrics.jsonl" | cut -c1-300
    done
} >"$out/summary.txt" 2>&1
cd "$work/runs" || exit 1
# Snapshots and metrics only, two runs a file (each file under the device tool's 16 MiB).
rm -rf G*/best G*/model.safetensors G*/target.safetensors G*/optimizer.pt G*/replay.npz
runs=(G*)
for ((i = 0; i < ${#runs[@]}; i += 2)); do
    tar -cf "$out/${runs[i]%%-*}.tar" "${runs[@]:i:2}"
done
ls -la "$out" >>"$out/summary.txt"
