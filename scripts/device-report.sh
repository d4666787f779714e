#!/usr/bin/env bash
# The device-machine command for the comparison's report (docs/comparison.md): one call of under
# 9 minutes that evaluates on every core and brings back what it finished in $OUT/report.tar.gz.
# From the repository root, on the device machine, with the same options as the report here:
#
#   scripts/device-report.sh 8 --policy exported/comparison --beyond --episodes 50 --beyond-episodes 10
#
# carrying .whl (the packages the device image lacks: scripts/device-wheels.sh) and
# docs/.report-progress (what earlier runs finished, read back there instead of run again). The
# report runs as `python3 -m terl_rt report ARGS --workers $WORKERS --threads 1 --out $REPORT_OUT
# --force --keep-progress` (WORKERS: default every core; REPORT_OUT: default docs), interrupted
# when the minutes are up: each policy's result on each scenario is kept in
# REPORT_OUT/.report-progress the moment it finishes (the one under way is lost). The archive
# holds that folder, and the comparison's files when the report finished. Here, `tar xzf
# report.tar.gz -C docs` and the same report command read the device's results back: an
# evaluation does not depend on the workers that ran it (terl_rt/paper/saved_results.py).
# Exits 0 when the time ran out.
set -euo pipefail
minutes=$1
shift
out_dir=${REPORT_OUT:-docs}
source scripts/device-wheels.sh
mkdir -p "$out_dir"
started=$(mktemp)
status=0
timeout -s INT -k 60 "${minutes}m" python3 -m terl_rt report "$@" --workers "${WORKERS:-$(nproc)}" --threads 1 \
    --out "$out_dir" --force --keep-progress || status=$?
if [ "$status" -eq 124 ]; then
    echo "stopped after $minutes minutes: the same command goes on from $out_dir/.report-progress" >&2
    status=0
fi
names=()
for name in .report-progress comparison.md comparison.png comparison.json comparison-marl-eval.json; do
    if [ -e "$out_dir/$name" ] && [ "$out_dir/$name" -nt "$started" ]; then names+=("$name"); fi
done
if [ ${#names[@]} -gt 0 ]; then
    tar czf "$OUT/report.tar.gz" -C "$out_dir" "${names[@]}"
fi
ls -l "$OUT"
exit "$status"
