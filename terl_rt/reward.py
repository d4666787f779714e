"""Per-pursuer rewards (world.md section 9), following the paper's formulas.

Evaluated after the move, the collision check and the encirclement test of a step.
Recipients are the pursuers active at the start of the step. "Active teammates"
and the pursuers counted around an evader are those still active after the
collision check; "active evaders" are those active at the start of the step (an
evader encircled in this step still guides and counts in it).
"""

from __future__ import annotations

import numpy as np

from terl_rt.encirclement import Encirclement
from terl_rt.geometry import Geometry, not_self
from terl_rt.params import WorldParams

REWARD_TERMS = ("time", "collision", "emergency", "guidance", "cooperation", "boundary", "completion")
"""Names of the reward terms, in the order of the last axis of `reward_terms`."""


def reward_terms(
    pursuer_xy: np.ndarray,
    recipients: np.ndarray,
    pursuer_active: np.ndarray,
    collided: np.ndarray,
    evader_active: np.ndarray,
    obstacle_r: np.ndarray,
    geometry: Geometry,
    encirclement: Encirclement,
    params: WorldParams,
    arena: tuple[float, float],
) -> np.ndarray:
    """Reward terms [B, N, 7] in REWARD_TERMS order; zero for non-recipients.

    pursuer_xy [B, N, 2] m after the move; recipients [B, N] bool (active at the step
    start); pursuer_active [B, N] bool after collisions; collided [B, N] bool this step;
    evader_active [B, M] bool at the step start; obstacle_r [B, O] m.
    """
    p = params
    num_pursuers = recipients.shape[1]
    terms = np.zeros(recipients.shape + (len(REWARD_TERMS),))
    terms[..., 0] = p.reward_time
    terms[..., 1] = np.where(collided, p.reward_collision, 0.0)

    # emergency: an active teammate, active evader or perceived obstacle closer than d_safe.
    teammate_near = (
        (geometry.pursuer_pursuer < p.d_safe) & pursuer_active[:, None, :] & not_self(num_pursuers)
    ).any(-1)
    evader_near = ((geometry.pursuer_evader < p.d_safe) & evader_active[:, None, :]).any(-1)
    obstacle_near = (
        (geometry.pursuer_obstacle < p.d_safe)
        & (geometry.pursuer_obstacle <= p.perception_radius + obstacle_r[:, None, :])
    ).any(-1)
    terms[..., 2] = np.where(teammate_near | evader_near | obstacle_near, p.reward_emergency, 0.0)

    # guidance: summed over active evaders.
    d_e = geometry.pursuer_evader
    guidance = np.where(d_e <= p.d_encircle, p.reward_guidance, p.reward_guidance * np.exp(-p.guidance_decay * (d_e - p.d_encircle)))
    terms[..., 3] = (guidance * evader_active[:, None, :]).sum(-1)

    # cooperation: P active pursuers within related_distance of each active evader.
    around = (d_e <= p.related_distance) & pursuer_active[:, :, None] & evader_active[:, None, :]  # [B, N, M]
    count = around.sum(1)  # [B, M]
    per_evader = np.where(
        count >= 5,
        p.reward_crowding,
        np.where(count >= 3, p.reward_cooperation * np.maximum(0.0, 1.0 - p.cooperation_slope * (count - 3)), 0.0),
    )
    cooperation = (around * per_evader[:, None, :]).sum(-1)
    imbalance = ((count < 3) & evader_active).any(-1) & ((count > 5) & evader_active).any(-1)  # [B]
    terms[..., 4] = cooperation + np.where(imbalance, p.reward_imbalance, 0.0)[:, None]

    # boundary: outside the arena.
    width, height = arena
    x, y = pursuer_xy[..., 0], pursuer_xy[..., 1]
    outside = (x < 0) | (x > width) | (y < 0) | (y > height)
    terms[..., 5] = np.where(outside, p.reward_boundary, 0.0)

    # completion: 120 * (2 pi / n_k) * exp(-sigma) for each pursuer that encircled.
    ring = encirclement.ring_size
    terms[..., 6] = np.where(
        ring > 0, p.reward_completion * (2 * np.pi / np.maximum(ring, 1)) * np.exp(-encirclement.gap_std), 0.0
    )
    return terms * recipients[..., None]
