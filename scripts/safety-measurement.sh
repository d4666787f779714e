#!/usr/bin/env bash
# The paired measurement of docs/safety.md ("Measured"): the same seeds with and without the
# shield, with and without risk-aware acting at three ALPHA, and both; the shipped default and
# seed 1 of each comparison method; the paper suite at 100 episodes and 160 / 240 / 400
# pursuers at 10; then the CPU cost per step. From the repository root:
#
#   scripts/safety-measurement.sh [OUT]        # OUT default runs/safety; WORKERS default every core
#
# Each run is a `terl-rt sweep` into OUT/<policy>/<rule>/<worlds> (sweep.md, sweep.csv and
# sweep.json, every episode). A run whose sweep.json is there is skipped, so the script run again
# (in a later session, OUT copied back) goes on where it was cut off. Rules: plain, shield, cvar-A
# and shield-cvar-A for A in 0.25 0.5 0.75 (risk only where the file has quantiles). The default
# runs first: greedy and shielded, then both on held-out episodes (seed 20000, into
# OUT/held-out/), then the risk-aware rules; the comparison methods after it. Last, OUT/safety-table.md: docs/safety.md's
# tables (scripts/safety-table.py, which also reads a measurement still going).
set -euo pipefail
out=${1:-runs/safety}
workers=${WORKERS:-$(nproc)}
HELD_OUT_SEED=20000  # episodes 20000-20099: no report, selection or probe uses them
mkdir -p "$out"
python3 -c "
from terl_rt.evaluation.speed import scaling_scenario
for n in (160, 240, 400):
    scaling_scenario(n).to_file(f'$out/scale-{n}.json')
"
rules=("plain:" "shield:--shield")
for alpha in 0.75 0.5 0.25; do  # the boldest first: at 0.25 the default encircles nothing (docs/safety.md)
    rules+=("cvar-$alpha:--risk cvar:$alpha" "shield-cvar-$alpha:--shield --risk cvar:$alpha")
done
has_quantiles() {
    python3 -c "import sys; from terl_rt.policy.onnx_policy import OnnxPolicy; sys.exit(not OnnxPolicy('$1').has_quantiles)"
}
sweep() {  # sweep FOLDER OPTIONS...: one run, unless it finished before
    local folder=$1
    shift
    if [[ -f $folder/sweep.json ]]; then
        echo "skipped (done): $folder"
        return
    fi
    python3 -m terl_rt sweep --seed 0 "$@" --workers "$workers" --threads 1 --out "$folder" --force
}
held_out() {  # the default greedy and shielded on episodes no report uses: OUT/held-out/terl/<rule>/paper
    local rule options  # the caller's loop goes on with its own
    for rule in "${rules[@]:0:2}"; do  # plain and shield
        read -r -a options <<< "${rule#*:}"
        sweep "$out/held-out/terl/${rule%%:*}/paper" --policy exported/terl.onnx --suite paper --episodes 100 \
            --seed "$HELD_OUT_SEED" "${options[@]}"
    done
}
for policy in exported/terl.onnx exported/comparison/{terl,terl-authors,terl-no-re,terl-no-ts,iqn,mean,dqn}-seed-1.onnx; do
    name=$(basename "$policy" .onnx)
    for rule in "${rules[@]}"; do
        label=${rule%%:*}
        if [[ $name == terl && $label == cvar-0.75 ]]; then
            held_out  # the goals' check before the risk-aware rules
        fi
        read -r -a options <<< "${rule#*:}"
        if [[ $label == *cvar* ]] && ! has_quantiles "$policy"; then
            continue
        fi
        sweep "$out/$name/$label/paper" --policy "$policy" --suite paper --episodes 100 "${options[@]}"
        for n in 160 240 400; do
            sweep "$out/$name/$label/scale-$n" --policy "$policy" --scenario-file "$out/scale-$n.json" \
                --episodes 10 "${options[@]}"
        done
    done
done
python3 -m terl_rt bench shield --scenario large-80 --steps 200 --repeat 3 --risk cvar:0.25 --risk cvar:0.5 \
    --risk cvar:0.75 --json > "$out/bench-shield.json"
python3 scripts/safety-table.py "$out" > "$out/safety-table.md"
python3 scripts/safety-table.py "$out/held-out" > "$out/held-out/safety-table.md"
