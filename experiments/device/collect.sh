#!/usr/bin/env bash
# Pack the runs' checkpoints (no replay buffers) into $OUT, in parts of at most 15 MiB.
# The full-size run brings back its online network, best/ and metrics only.
set -euo pipefail
runs=${1:-/tmp/runs}
cd "$runs"
small=$(ls -d */ | tr -d / | grep -v full-size || true)
tar czf /tmp/small.tgz --exclude=replay.npz $small *.log
split -b 15M -d /tmp/small.tgz "$OUT/small.tgz.part"
for full in $(ls -d */ | tr -d / | grep full-size || true); do
    tar czf /tmp/full.tgz "$full/model.safetensors" "$full/config.json" "$full/state.json" "$full/metrics.jsonl" "$full/best" 2>/dev/null || true
    split -b 15M -d /tmp/full.tgz "$OUT/full.tgz.part"
done
ls -la "$OUT"
