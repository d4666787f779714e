"""Pursuer observations in the layout of the ONNX policy contract (world.md section 5).

Each observation has four token groups plus a mask, in the observer's ego frame:
ego [4], teammates [P=5, 7], evaders [E, 7], obstacles [O=5, 5], mask [1+P+E+O].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EGO_FEATURES = 4
"""ego token: [vx, vy (m/s, ego frame), d_nearest (m), pursuit_status (0/1)]."""
TEAMMATE_FEATURES = 7
"""teammate token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), pursuit_status]."""
EVADER_FEATURES = 7
"""evader token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), heading (rad, [0, 2pi))]."""
OBSTACLE_FEATURES = 5
"""obstacle token: [px, py (m), r (m), d (m), bearing (rad)]."""
TEAMMATE_SLOTS = 5
"""P: teammate slots, nearest perceived active pursuers first."""
OBSTACLE_SLOTS = 5
"""O: obstacle slots, nearest perceived obstacles first."""
ENTITY_TYPES = {"ego": 0, "teammate": 1, "evader": 2, "obstacle": 3}
"""Entity type ids, in mask order."""


@dataclass(frozen=True)
class Observation:
    """Pursuer observations, float32, with any leading shape `...` (rows of pursuers).

    `Simulator` returns one row per active pursuer (`...` = [n]); the batched world
    returns every pursuer of every environment (`...` = [B, N]).
    """

    ego: np.ndarray
    """[..., 4] float32."""
    teammates: np.ndarray
    """[..., P, 7] float32, P = 5."""
    evaders: np.ndarray
    """[..., E, 7] float32, E the scenario's evader slots."""
    obstacles: np.ndarray
    """[..., O, 5] float32, O = 5."""
    mask: np.ndarray
    """[..., 1 + P + E + O] bool: ego (always true), teammates, evaders, obstacles."""
    pursuer_index: np.ndarray
    """[...] int64: the pursuer each row belongs to."""

    def as_inputs(self) -> dict[str, np.ndarray]:
        """The ONNX contract inputs, by name: ego, teammates, evaders, obstacles, mask."""
        return {
            "ego": self.ego,
            "teammates": self.teammates,
            "evaders": self.evaders,
            "obstacles": self.obstacles,
            "mask": self.mask,
        }
