"""What a robot perceives (world.md section 5): an entity whose centre lies within the
perception radius R plus the entity's own radius, the bound itself included.

Every rule that depends on perception (observations, the evader's potential field,
the teammates an encirclement counts, the rewards' perceived obstacles) asks here.
Distances and radii in m.
"""

from __future__ import annotations

import numpy as np

from terl_rt.sim.geometry import Geometry, not_self
from terl_rt.sim.params import WorldParams


def perception_reach(radius: np.ndarray | float, params: WorldParams) -> np.ndarray | float:
    """m: the largest centre distance at which an entity of `radius` (m, any shape) is
    perceived, R + radius; as a limit of `geometry.candidate_key`, inclusive as here."""
    return params.perception_radius + radius


def perceived(distance: np.ndarray, radius: np.ndarray | float, params: WorldParams) -> np.ndarray:
    """bool, the broadcast shape of `distance` and `radius` (m): an entity of that radius
    at that centre distance is perceived, distance <= R + radius."""
    return distance <= perception_reach(radius, params)


def perceived_pursuers(geometry: Geometry, present: np.ndarray, params: WorldParams) -> np.ndarray:
    """[B, N, N] bool: [b, i, j] when pursuers i and j are both present ([B, N] bool),
    i != j and i perceives j."""
    return (
        perceived(geometry.pursuer_pursuer, params.robot_radius, params)
        & present[:, None, :] & present[:, :, None]
        & not_self(present.shape[1])
    )
