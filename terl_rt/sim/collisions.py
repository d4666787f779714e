"""Collisions (world.md section 6): discs that touch after the move, and what each touched."""

from __future__ import annotations

import numpy as np

from terl_rt.sim.geometry import Geometry, not_self_columns, per_entity
from terl_rt.sim.params import WorldParams
from terl_rt.sim.state import WorldState

TOUCHED_TEAMMATE, TOUCHED_EVADER, TOUCHED_OBSTACLE = 1, 2, 4
"""Bits of WorldState.pursuer_touched: what a collided pursuer's disc touched in its collision."""


def collisions(state: WorldState, geometry: Geometry, params: WorldParams) -> tuple[np.ndarray, np.ndarray]:
    """Who collides after the move and what each touched: collided [B, N] bool, the active
    pursuers whose disc touches an active pursuer (not itself), an active evader or an obstacle
    (centre distance minus both radii <= 0); touched [B, N] uint8, the TOUCHED_* bits of
    what a collided pursuer's disc touches (0 for the others)."""
    num_pursuers, num_evaders = state.pursuer_active.shape[1], state.evader_active.shape[1]
    r = params.robot_radius
    contact = per_entity(
        np.where(state.pursuer_active, 2 * r, -1.0),
        np.where(state.evader_active, 2 * r, -1.0),
        r + state.obstacle_r,
        blank=-1.0,
    )  # [B, T + 1] m: the centre distance of a contact with each entity column (-1: none)
    touching = (geometry.distance[:, :num_pursuers] <= contact[:, None, :]) & not_self_columns(0, num_pursuers, contact.shape[1])
    collided = state.pursuer_active & touching.any(-1)
    kinds = np.zeros(collided.shape, np.uint8)
    if collided.any():  # rare: most steps have none
        kinds = (touching[..., :num_pursuers].any(-1) * TOUCHED_TEAMMATE
                 | touching[..., num_pursuers:num_pursuers + num_evaders].any(-1) * TOUCHED_EVADER
                 | touching[..., num_pursuers + num_evaders:].any(-1) * TOUCHED_OBSTACLE).astype(np.uint8) * collided
    return collided, kinds
