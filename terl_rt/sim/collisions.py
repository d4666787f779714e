"""Collisions (world.md section 6): discs that touch after the move."""

from __future__ import annotations

import numpy as np

from terl_rt.sim.geometry import Geometry, not_self_columns, per_entity
from terl_rt.sim.params import WorldParams
from terl_rt.sim.state import WorldState


def collisions(state: WorldState, geometry: Geometry, params: WorldParams) -> np.ndarray:
    """[B, N] bool: active pursuers whose disc touches an active pursuer, an active
    evader or an obstacle (centre distance minus both radii <= 0), after the move."""
    num_pursuers = state.pursuer_active.shape[1]
    r = params.robot_radius
    contact = per_entity(
        np.where(state.pursuer_active, 2 * r, -1.0),
        np.where(state.evader_active, 2 * r, -1.0),
        r + state.obstacle_r,
        blank=-1.0,
    )  # [B, T + 1] m: the centre distance of a contact with each entity column (-1: none)
    touching = (geometry.distance[:, :num_pursuers] <= contact[:, None, :]) & not_self_columns(0, num_pursuers, contact.shape[1])
    return state.pursuer_active & touching.any(-1)
