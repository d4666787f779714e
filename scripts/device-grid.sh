#!/usr/bin/env bash
# The prepared device-machine command (docs/training.md, "On a device machine"): one call of under
# 9 minutes that trains grid cells on every core, one process a cell, and brings back each
# method's resume points in $OUT. From the repository root, on the device machine:
#
#   cp -r checkpoints/comparison runs/comparison && scripts/device-grid.sh 7 recipes/comparison/*.toml --seeds 1-3
#
# The committed resume points travel with the tree (checkpoints/comparison; replay buffers are
# not committed, so a resumed cell refills its buffer outside the schedule first). The runtime's
# packages that the device image lacks (mcap and what it needs, the Foxglove schemas) travel as
# wheels, 6.8 MB: here, before the call,
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#     -d .whl mcap mcap-protobuf-support foxglove-schemas-protobuf lz4 zstandard
# and name .whl in the call's carry. Then the cells run as `python -m training grid RECIPE...
# --seeds ... --out $GRID_OUT --processes $PROCESSES --stop-after MINUTES` (GRID_OUT: default
# runs/comparison; PROCESSES: default every core), which stops them with whole checkpoints when
# the minutes are up, and each method's folder is packed, without replay buffers and snapshots
# (best/ stays), into $OUT/<method>.tar.gz. Unpack with `tar xzf METHOD.tar.gz -C runs/comparison`.
set -euo pipefail
minutes=$1
shift
grid_out=${GRID_OUT:-runs/comparison}
if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
status=0
python3 -m training grid "$@" --out "$grid_out" --processes "${PROCESSES:-$(nproc)}" --stop-after "$minutes" || status=$?
for folder in "$grid_out"/*/; do
    method=$(basename "$folder")
    tar czf "$OUT/$method.tar.gz" --exclude=replay.npz --exclude=snapshots --exclude=.run-lock -C "$grid_out" "$method"
done
ls -l "$OUT"
exit "$status"
