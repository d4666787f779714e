"""scripts/shield-collisions.py: what each collision left under the shield was (issue 75)."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np

from terl_rt.sim.collisions import TOUCHED_EVADER, TOUCHED_OBSTACLE, TOUCHED_TEAMMATE

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "shield-collisions.py"
script = runpy.run_path(str(SCRIPT))


def test_a_collision_is_sorted_by_what_the_shield_kept_and_what_was_touched():
    kind_of = script["kind_of"]
    boxed, clear = np.full(9, -0.1), np.r_[np.full(8, -0.1), 0.2]
    assert kind_of(TOUCHED_TEAMMATE | TOUCHED_EVADER, boxed, []) == "none kept: teammate"
    assert kind_of(TOUCHED_OBSTACLE, boxed, []) == "none kept: obstacle"
    assert kind_of(TOUCHED_EVADER, clear, []) == "predicted clear: evader"
    assert kind_of(TOUCHED_TEAMMATE, clear, [(False, False)]) == "predicted clear: teammate, its policy's action"
    assert kind_of(TOUCHED_TEAMMATE, clear, [(True, False)]) == "predicted clear: teammate, its shield overrode"
    assert kind_of(TOUCHED_TEAMMATE, clear, [(True, False), (False, True)]) == (
        "predicted clear: teammate, none kept by its shield")
    assert all(kind_of(bits, scores, partners) in script["KINDS"]
               for bits in (TOUCHED_TEAMMATE, TOUCHED_EVADER, TOUCHED_OBSTACLE) for scores in (boxed, clear)
               for partners in ([], [(True, True)]))


def test_the_table_has_a_row_a_scenario_whose_kinds_add_up_to_its_collided_pursuers():
    run = subprocess.run([sys.executable, str(SCRIPT), "--scenario", "small-11", "--episodes", "1"],
                         capture_output=True, text=True, check=True)
    rows = [line for line in run.stdout.splitlines() if line.startswith("| small-11 |")]
    assert len(rows) == 1
    cells = rows[0].strip("| ").split(" | ")
    counts = [int(cell) for cell in cells[1:-1]]
    assert counts[0] == sum(counts[1:])
