"""Per-pursuer rewards (world.md section 9): two named variants, `paper` and `published`.

Both are evaluated after the move, the collision check and the encirclement test of
a step, and both go to the pursuers active at the start of the step (the recipients).

`paper`, the paper's formulas: "active teammates" and the pursuers counted around an
evader are those still active after the collision check; "active evaders" are those
active at the start of the step (an evader encircled in this step still guides and
counts in it).

`published`, what the published trainer optimised (its `MarineEnv.step` and
`global_reward`): guidance, crowding and the emergency test look at every robot,
collided pursuers and encircled evaders included, at their current positions; the
emergency test's obstacle is the lowest-index obstacle the pursuer perceived before
the move, at its distance then; completion divides 2 pi by the helpers only (one
less than the ring) and is not paid in a step the pursuer collides.
"""

from __future__ import annotations

import numpy as np

from terl_rt.sim.encirclement import Encirclement
from terl_rt.sim.geometry import Geometry, not_self, not_self_columns, per_entity
from terl_rt.sim.params import WorldParams
from terl_rt.sim.perception import perceived

REWARD_TERMS = ("time", "collision", "emergency", "guidance", "cooperation", "boundary", "completion")
"""Names of the reward terms, in the order of the last axis of the reward functions' output."""
REWARD_VARIANTS = ("paper", "published")
"""The reward variants a scenario or training config can name (world.md section 9)."""


def paper_reward_terms(
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
) -> tuple[np.ndarray, np.ndarray]:
    """The `paper` variant: reward terms [B, N, 7] in REWARD_TERMS order, zero for non-recipients,
    and the team-wide share of each world's cooperation term [B] (the imbalance penalty, paid
    to every recipient alike and included in the terms).

    pursuer_xy [B, N, 2] m after the move; recipients [B, N] bool (active at the step
    start); pursuer_active [B, N] bool after collisions; collided [B, N] bool this step;
    evader_active [B, M] bool at the step start; obstacle_r [B, O] m.
    """
    p = params
    num_pursuers = recipients.shape[1]
    terms = np.empty(recipients.shape + (len(REWARD_TERMS),))
    _common_terms(terms, pursuer_xy, collided, p, arena)

    # emergency: an active teammate, active evader or perceived obstacle closer than
    # d_safe; one pass over every entity column with each column's own bound.
    bound = per_entity(
        np.where(pursuer_active, p.d_safe, 0.0),
        np.where(evader_active, p.d_safe, 0.0),
        np.full(obstacle_r.shape, p.d_safe),
    )  # [B, T + 1] m; 0 never holds (distance < 0)
    near = (geometry.distance[:, :num_pursuers] < bound[:, None, :]) & not_self_columns(0, num_pursuers, bound.shape[1])
    near[:, :, num_pursuers + geometry.num_evaders : -1] &= perceived(geometry.pursuer_obstacle, obstacle_r[:, None, :], p)
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
    team = imbalance * p.reward_imbalance  # [B]
    terms[..., 4] = cooperation + team[:, None]

    # completion: 120 * (2 pi / n_k) * exp(-sigma) for each pursuer that encircled.
    ring = encirclement.ring_size
    terms[..., 6] = np.where(
        ring > 0, p.reward_completion * (2 * np.pi / np.maximum(ring, 1)) * np.exp(-encirclement.gap_std), 0.0
    )
    return _for_recipients(terms, recipients), team


def published_reward_terms(
    pursuer_xy: np.ndarray,
    recipients: np.ndarray,
    collided: np.ndarray,
    obstacle_distance_before: np.ndarray,
    geometry: Geometry,
    encirclement: Encirclement,
    params: WorldParams,
    arena: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """The `published` variant: reward terms [B, N, 7] in REWARD_TERMS order, zero for
    non-recipients, and the team-wide share of each world's cooperation term [B] (the crowding
    penalty, paid to every recipient alike whenever any evader is crowded; in the terms).

    pursuer_xy [B, N, 2] m after the move; recipients [B, N] bool (active at the step
    start); collided [B, N] bool this step; obstacle_distance_before [B, N] m: centre
    distance, before the move, to the lowest-index obstacle each pursuer perceived then
    (inf for none; `first_perceived_obstacle_distance`). Every pursuer and evader counts
    in guidance, crowding and the emergency test, collided and encircled ones included.
    """
    p = params
    terms = np.empty(recipients.shape + (len(REWARD_TERMS),))
    _common_terms(terms, pursuer_xy, collided, p, arena)
    d_e = geometry.pursuer_evader  # [B, N, M] m, every evader
    nearest = d_e.min(-1, initial=np.inf)  # [B, N]

    # emergency: the nearest evader, the nearest other pursuer, or the obstacle seen
    # before the move, closer than d_safe.
    others = np.where(not_self(recipients.shape[1]), geometry.pursuer_pursuer, np.inf).min(-1, initial=np.inf)
    near = (nearest < p.d_safe) | (others < p.d_safe) | (obstacle_distance_before < p.d_safe)
    terms[..., 2] = near * p.reward_emergency

    # guidance: per evader, full within d_encircle, else decaying with the distance to
    # the *nearest* evader.
    decayed = p.reward_guidance * np.exp(-p.guidance_decay * (nearest - p.d_encircle))
    terms[..., 3] = np.where(d_e <= p.d_encircle, p.reward_guidance, decayed[..., None]).sum(-1)

    # cooperation: P pursuers within related_distance of each evader; 3 <= P pays the
    # slope (never negative), and any P >= 5 costs every pursuer.
    around = d_e <= p.related_distance  # [B, N, M]
    count = around.sum(1)  # [B, M]
    per_evader = np.where(count >= 3, p.reward_cooperation * np.maximum(0.0, 1.0 - p.cooperation_slope * (count - 3)), 0.0)
    team = (count >= 5).any(-1) * p.reward_crowding  # [B]
    terms[..., 4] = (around @ per_evader[:, :, None])[..., 0] + team[:, None]

    # completion: 120 * (2 pi / helpers) * exp(-sigma), not in a step the pursuer collides.
    helpers = encirclement.ring_size - 1
    terms[..., 6] = np.where(
        (helpers > 0) & ~collided,
        p.reward_completion * (2 * np.pi / np.maximum(helpers, 1)) * np.exp(-encirclement.gap_std),
        0.0,
    )
    return _for_recipients(terms, recipients), team


def first_perceived_obstacle_distance(geometry: Geometry, obstacle_r: np.ndarray, params: WorldParams) -> np.ndarray:
    """[B, N] m: each pursuer's centre distance to the lowest-index obstacle it perceives
    (within R + r), inf for none. The published emergency test reads this from the
    observation before the move."""
    distance = geometry.pursuer_obstacle  # [B, N, O]
    seen = perceived(distance, obstacle_r[:, None, :], params)
    if distance.shape[-1] == 0:
        return np.full(distance.shape[:2], np.inf)
    first = seen.argmax(-1)[..., None]
    return np.where(seen.any(-1), np.take_along_axis(distance, first, -1)[..., 0], np.inf)


def _common_terms(terms: np.ndarray, pursuer_xy: np.ndarray, collided: np.ndarray, p: WorldParams, arena) -> None:
    """Fill the terms both variants share: time, collision and boundary (outside the arena)."""
    terms[..., 0] = p.reward_time
    terms[..., 1] = collided * p.reward_collision
    outside = ((pursuer_xy < 0.0) | (pursuer_xy > arena)).any(-1)
    terms[..., 5] = outside * p.reward_boundary


def _for_recipients(terms: np.ndarray, recipients: np.ndarray) -> np.ndarray:
    terms *= recipients[..., None]
    terms += 0.0  # -0.0 (a penalty times false) becomes 0.0
    return terms


def taught_reward(
    terms: np.ndarray,
    collided: np.ndarray,
    terminal: np.ndarray,
    previous_potential: np.ndarray,
    gamma: float,
    scale: float = 1.0,
    shaping: float = 0.0,
    collision_value: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The reward a learner is taught for one step of R pursuers, from the terms the world paid.

    terms [R, len(REWARD_TERMS)] as paid; collided [R] bool (the pursuer collided in the step);
    terminal [R] bool (its transition ends: no bootstrap, Phi(s') = 0); previous_potential [R]:
    Phi(s) of the state its last step ended in (0 at an episode's start); gamma the discount per
    0.5 s decision step.

    - `shaping` k > 0 pays the income, guidance + max(cooperation, 0), as a potential difference
      gamma * Phi(s') - Phi(s) with Phi = k * income (Ng, Harada and Russell 1999): holding a ring
      open earns nothing a step, the approach still pays, the best policy of the other terms is
      unchanged. k = 0 teaches the terms as paid.
    - `collision_value` V_c <= 0: a collided pursuer's transition ends on V_c, so its reward gains
      gamma * V_c (0: ends on nothing, the published setting).
    - `scale` c > 0 multiplies everything, so returns are in units of 1 / c.

    Returns the rewards [R] and Phi(s') [R] (k * income; 0 without shaping); the caller keeps
    Phi(s') as the next step's previous_potential (0 where the episode stops).
    """
    guidance, cooperation = terms[:, REWARD_TERMS.index("guidance")], terms[:, REWARD_TERMS.index("cooperation")]
    rewards = terms.sum(-1)
    potential = np.zeros(len(terms))
    if shaping:
        income = guidance + np.maximum(cooperation, 0.0)
        potential = shaping * income
        rewards = rewards - income + gamma * np.where(terminal, 0.0, potential) - previous_potential
    rewards = rewards + np.where(collided, gamma * collision_value, 0.0)
    return scale * rewards, potential
