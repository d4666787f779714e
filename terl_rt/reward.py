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
from terl_rt.geometry import Geometry, not_self_columns, per_entity
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
    terms = np.empty(recipients.shape + (len(REWARD_TERMS),))
    terms[..., 0] = p.reward_time
    terms[..., 1] = collided * p.reward_collision

    # emergency: an active teammate, active evader or perceived obstacle closer than
    # d_safe; one pass over every entity column with each column's own bound
    # ("perceived" = within R + r, inclusive: below the next float up).
    perceived = np.nextafter(p.perception_radius + obstacle_r, np.inf)
    bound = per_entity(
        np.where(pursuer_active, p.d_safe, 0.0),
        np.where(evader_active, p.d_safe, 0.0),
        np.minimum(perceived, p.d_safe),
    )  # [B, T + 1] m; 0 never holds (distance < 0)
    near = (geometry.distance[:, :num_pursuers] < bound[:, None, :]) & not_self_columns(0, num_pursuers, bound.shape[1])
    terms[..., 2] = near.any(-1) * p.reward_emergency

    # guidance: summed over active evaders; full within d_encircle (exp(0) = 1).
    d_e = geometry.pursuer_evader
    guidance = np.exp(-p.guidance_decay * np.maximum(d_e - p.d_encircle, 0.0))
    terms[..., 3] = p.reward_guidance * (guidance @ evader_active[:, :, None].astype(np.float64))[..., 0]

    # cooperation: P active pursuers within related_distance of each active evader.
    around = (d_e <= p.related_distance) & pursuer_active[:, :, None] & evader_active[:, None, :]  # [B, N, M]
    count = around.sum(1)  # [B, M]
    per_evader = np.where(
        count >= 5,
        p.reward_crowding,
        np.where(count >= 3, p.reward_cooperation * np.maximum(0.0, 1.0 - p.cooperation_slope * (count - 3)), 0.0),
    )
    cooperation = (around @ per_evader[:, :, None])[..., 0]
    imbalance = ((count < 3) & evader_active).any(-1) & ((count > 5) & evader_active).any(-1)  # [B]
    terms[..., 4] = cooperation + (imbalance * p.reward_imbalance)[:, None]

    # boundary: outside the arena.
    outside = ((pursuer_xy < 0.0) | (pursuer_xy > arena)).any(-1)
    terms[..., 5] = outside * p.reward_boundary

    # completion: 120 * (2 pi / n_k) * exp(-sigma) for each pursuer that encircled.
    ring = encirclement.ring_size
    terms[..., 6] = np.where(
        ring > 0, p.reward_completion * (2 * np.pi / np.maximum(ring, 1)) * np.exp(-encirclement.gap_std), 0.0
    )
    terms *= recipients[..., None]
    terms += 0.0  # -0.0 (a penalty times false) becomes 0.0
    return terms
