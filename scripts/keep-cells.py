#!/usr/bin/env python3
"""Copy a grid's cells into the tree, to commit what a later session resumes or ships from.

    python scripts/keep-cells.py runs/comparison checkpoints/comparison [METHOD/seed-S ...]

Every cell of GRID_OUT (or those named) replaces its copy under KEPT, with its log:
- a finished cell (its <method>.onnx is there): each segment's config, state and metrics, the
  model, config and state of its best/ snapshot, and the exported file (`python -m training
  grid --ship` ships from these);
- a cell cut off: all of that and the weights and optimizer of its last segment that has them,
  its resume point (a segment just begun has none yet; the segments before are done: their
  weights are no longer read);
- either: the networks of its kept snapshots (snapshots/<step>/, `keep_snapshots`: half a MB
  each), which a learning curve evaluates after the run.
Replay buffers (hundreds of MB; a resumed cell refills its buffer first) and run locks stay
behind. Resume everything with `cp -r checkpoints/comparison runs/comparison` and the same
`python -m training grid` command (docs/training.md).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

LEFT_BEHIND = {"replay.npz", ".run-lock"}
WEIGHTS = {"model.safetensors", "target.safetensors", "optimizer.pt"}
"""A segment's resume point, kept for a cell cut off only (best/ keeps its own model)."""


def keep_cell(cell: Path, kept: Path) -> str:
    finished = any(cell.glob("*.onnx"))
    segments = sorted((p for p in cell.iterdir() if p.is_dir() and p.name.split("-")[0].isdigit()),
                      key=lambda p: int(p.name.split("-")[0]))
    # the resume point: the last segment with weights (one just begun has its log alone)
    with_weights = [p for p in segments if (p / "model.safetensors").is_file()]
    resumed = None if finished or not with_weights else with_weights[-1].name

    def left_behind(folder: str, names: list[str]) -> set[str]:
        dropped = LEFT_BEHIND & set(names)
        if Path(folder).parent == cell and Path(folder).name != resumed:  # a segment's own files
            dropped |= WEIGHTS & set(names)
        elif finished and Path(folder).name == "best":  # its model is what ships
            dropped |= (WEIGHTS - {"model.safetensors"}) & set(names)
        return dropped

    shutil.rmtree(kept, ignore_errors=True)
    shutil.copytree(cell, kept, ignore=left_behind)
    log = cell.with_suffix(".log")
    if log.exists():
        shutil.copy2(log, kept.with_suffix(".log"))
    return "finished" if finished else "cut off"


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    grid_out, kept = Path(argv[0]), Path(argv[1])
    names = argv[2:] or sorted(str(p.relative_to(grid_out)) for p in grid_out.glob("*/seed-*") if p.is_dir())
    for name in names:
        cell = grid_out / name
        if not cell.is_dir():
            print(f"Error: no cell {cell}", file=sys.stderr)
            return 1
        print(f"{name}: {keep_cell(cell, kept / name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
